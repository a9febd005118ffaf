"""The names of every choice the package offers, in one place that imports nothing heavy.

The command line builds its ``choices=`` and help texts from these tuples without importing JAX;
each registry that implements a choice (kernels, rules, parameterizations, value spaces, …)
checks at import that its keys are exactly the names listed here (:func:`check_registry`), so a
name cannot be added to one and forgotten in the other.
"""

from __future__ import annotations

BUDGETS = ("iso102", "aniso204")
KERNELS = (
    "gaussian",
    "inverse_multiquadric",
    "inverse_quadratic",
    "multiquadric",
    "thin_plate_spline",
    "cubic",
    "linear",
)
RULES = ("filip2012", "average", "crossing", "log", "diagonal")
PARAMETERIZATIONS = ("onion", "spherical", "halfdiff", "onion-hd")
VALUE_SPACES = ("linear", "log", "logsamples")
INTERP_METHODS = ("linear", "cubic")
#: Named configurations (``abrdf_jax.preset``); the same meaning in every command.
PRESETS = ("recommended", "paper", "operator")
#: Named models of the automatic model choice (``abrdf_jax.select.CANDIDATES``), in complexity order.
MODELS = (
    "iso",
    "iso-linear",
    "iso-gaussian",
    "paper",
    "aniso-average",
    "aniso-crossing",
    "aniso-log",
    "aniso",
    "paper-aniso",
    "prior",
    "fused",
)
#: Traits of some choices that code without JAX needs (the configuration's checks, the command
#: line's choice of the compiled operator); the registries check at import that they agree
#: (:func:`check_trait`): each kernel's lowest polynomial-tail degree (-1: none), the subspace
#: rules that are linear in the slice values, the value spaces that take the log of the
#: subspace values (after the rule: never one matrix).
KERNEL_MIN_DEGREE = {
    "gaussian": -1,
    "inverse_multiquadric": -1,
    "inverse_quadratic": -1,
    "multiquadric": 0,
    "thin_plate_spline": 1,
    "cubic": 1,
    "linear": 0,
}
LINEAR_RULES = ("average", "crossing", "diagonal")
#: The rules affine in the slice terms a, b, c once the slices' extremes are known
#: (``abrdf_jax._rules``): every rule but the multiplicative one.
AFFINE_RULES = ("filip2012", "average", "crossing", "diagonal")
LOG_SUBSPACE = ("log",)
#: Value spaces that take the log of the samples (where the spike cap and slice smoothing act).
LOG_SAMPLES = ("logsamples",)
SOLVERS = ("lm", "gn", "bfgs", "lbfgs", "lbfgsb")
FOLD_KINDS = ("pairs", "samples")
LOSSES = ("lab", "log", "lab+log")
WIDTH_MODES = ("per_dim", "shared", "fixed")
BTF_BACKENDS = ("auto", "operator", "pipeline")
#: Models outside the RBF family and the learned ones: the bivariate ``(θh, θd)`` model of
#: isotropic materials (``abrdf_jax.reconstruct_bivariate``; ``--model auto``'s choice for a
#: material the isotropy test accepts, without a prior).
DIRECT_MODELS = ("bivariate",)
#: The models that read a learned prior (``--model NAME``), in rank order.
LEARNED_MODELS = ("prior", "fused")
BTF_MODELS = ("fixed", "auto", *LEARNED_MODELS, *DIRECT_MODELS)
#: dtypes of the values in a chunked BTF store
STORE_DTYPES = ("float16", "float32")
#: storage backends of a BTF store (``abrdf_jax.btf.FORMATS``), the default first
STORE_FORMATS = ("npy", "zarr")
# learned priors (abrdf_jax.prior): channel layouts, training inputs
PRIOR_CHANNELS = ("joint", "shared")
PRIOR_INPUT_SUFFIXES = (".npz", ".exr", ".binary")
#: the learned models that are Gaussian processes with a predictive variance (``--uncertainty``,
#: ``abrdf-jax suggest``; :mod:`abrdf_jax.prior._uncertainty`)
VARIANCE_MODELS = ("prior", "fused")
#: relative tolerance of the automatic model choice (the simplest model within it of the best)
MODEL_TOL = 0.05
#: Mitsuba 3 rendering (``abrdf-jax render``, ``abrdf_jax.render.render_table``): the RGB variants
#: the ABRDF plugin runs in (scalar first, the default), the shapes and the lights of the scene
#: (``both``: one image under each light).
RENDER_VARIANTS = ("scalar_rgb", "llvm_ad_rgb", "cuda_ad_rgb")
RENDER_SHAPES = ("sphere", "cylinder")
RENDER_LIGHTS = ("env", "point")
RENDER_LIGHT_CHOICES = ("env", "point", "both")
#: The image sides and samples per pixel a render accepts (inclusive).
RENDER_SIZE_RANGE = (8, 2048)
RENDER_SPP_RANGE = (1, 65536)
#: Table files by suffix (``abrdf_jax.io.read_table``/``write_table``).
TABLE_SUFFIXES = (".npz", ".exr")
MEASUREMENT_SUFFIXES = (".csv",)
#: How a capture's image names count azimuths (``abrdf_jax.btf.read_image_pairs``): counter-
#: clockwise as PROTOCOL.md (first, the default) or clockwise (mirrored on import).
AZIMUTHS = ("ccw", "cw")


def lookup(registry: dict, name: str, what: str):
    """``registry[name]``, or an :class:`InputError` naming ``what`` and listing the valid names."""
    try:
        return registry[name]
    except (KeyError, TypeError):
        from ._errors import InputError

        raise InputError(f"unknown {what} {name!r}; choose one of {tuple(registry)}") from None


def check_trait(kind: str, value) -> None:
    """Fail at import when a registry's traits differ from those listed here for ``kind``."""
    listed = globals()[kind]
    if value != listed:
        raise AssertionError(
            f"registry traits {kind} are {value!r}, but abrdf_jax._names.{kind} lists {listed!r}"
        )


def check_registry(kind: str, keys) -> None:
    """Fail at import when a registry's keys differ from the names listed here for ``kind``."""
    names = globals()[kind]
    if tuple(keys) != names:
        raise AssertionError(
            f"registry {kind} has {tuple(keys)}, but abrdf_jax._names.{kind} lists {names}"
        )
