"""The discrete configuration of a reconstruction and its default parameters, without JAX.

:class:`Config` is a frozen dataclass of static choices: hashable, so that it is a compile-time
constant of every jitted function (``abrdf_jax._params`` registers it as a static pytree node).
The defaults chosen on the train split (:data:`TUNED_DEFAULTS`), the named presets and the
default parameter *values* (:func:`default_values`) live here too, so that the command line can
key a cached operator and write a model record without importing JAX (issue 13);
:class:`abrdf_jax.Params` turns the values into arrays.
"""

from __future__ import annotations

import dataclasses
from typing import NamedTuple

import numpy as np

from ._errors import InputError
from ._names import (
    BUDGETS,
    INTERP_METHODS,
    KERNEL_MIN_DEGREE,
    KERNELS,
    LINEAR_RULES,
    LOG_SUBSPACE,
    PARAMETERIZATIONS,
    PRESETS as PRESET_NAMES,
    RULES,
    VALUE_SPACES,
)
from ._names import check_registry
from ._protocol import PROTOCOL_ALPHA_DEG, PROTOCOL_PAIRS, protocol_counts


def resolve_degree(kernel: str, degree: int | None) -> int:
    """The polynomial degree to use: ``None`` means the kernel's minimum."""
    if kernel not in KERNEL_MIN_DEGREE:
        raise ValueError(f"kernel must be one of {KERNELS}, got {kernel!r}")
    lo = KERNEL_MIN_DEGREE[kernel]
    if degree is None:
        return lo
    if degree < lo:
        raise ValueError(
            f"kernel {kernel!r} needs a polynomial tail of degree >= {lo}, got {degree}"
        )
    return degree


def _finite(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and bool(np.isfinite(v))


def check_smoothing(value) -> None:
    """:class:`InputError` unless ``value`` is a valid ``Config.slice_smoothing``."""
    if value is None or (_finite(value) and 0 <= value <= 1):
        return
    if isinstance(value, tuple) and len(value) == 3 and all(map(_finite, value)):
        beta_max, floor, scale = value
        if 0 < beta_max <= 1 and floor >= 0 and scale > 0:
            return
    raise InputError(
        "Config.slice_smoothing must be None, a weight in [0, 1] or "
        f"(beta_max in (0, 1], floor >= 0, scale > 0), got {value!r}"
    )


@dataclasses.dataclass(frozen=True)
class Config:
    """Discrete choices of the method. Every field is static: changing one recompiles.

    Attributes:
        budget: ``"iso102"`` (the 4 diagonal slices, eq. 5) or ``"aniso204"`` (all 8 slices).
        rule: toroidal subspace rule for anisotropic data (see :mod:`abrdf_jax._subspace`); the
            isotropic budget always uses eq. (5) (``"diagonal"``).
        kernel: RBF kernel (see :data:`abrdf_jax._kernels.KERNELS`).
        degree: polynomial tail degree, ``None`` for the kernel's minimum.
        parameterization: coordinates of a direction pair for the RBF: ``"onion"``
            ``[αi, βi, αv, βv]`` (the paper's), ``"spherical"`` ``[θi, φi, θv, φv]``,
            ``"halfdiff"`` ``[θh, φh, θd, φd]`` or ``"onion-hd"``, the onion coordinates
            and two of the half-vector, ``√(θh π/2)`` and ``θd`` (:mod:`abrdf_jax._coords`).
        interp: 1D slice interpolation (``"linear"`` or ``"cubic"``).
        value_space: ``"linear"`` (the paper) or ``"log"``: the RBF interpolates
            ``ln(x + ε)`` with ``ε = log_eps · mean sample``, which keeps shiny materials'
            highlights from ringing into the body of the material. ``"logsamples"`` takes the
            log of the *samples* instead (before slice interpolation and the subspace rule) and
            exponentiates the RBF output: with a linear rule the whole reconstruction is then
            ``exp(M · ln(y + ε)) − ε`` for one fixed matrix ``M`` (see :func:`compile_operator`).
        pairs: measured elevation pairs ``(θi, θv)`` in degrees. Off the UBO rings the RBF
            centres of a pair take 24 azimuths per direction.
        slice_count: samples per slice when sampling pairs other than PROTOCOL.md's.
        spike_cap: ``(quantile, margin)``: in the value space ``"logsamples"`` the RBF fits the
            subspaces restored from log samples capped at that quantile (per material and
            channel) plus the margin, while the uncapped restoration stays at the grid pairs
            (:mod:`abrdf_jax._spikes`); ``None``: no cap. Chosen on the MERL train split.
        slice_smoothing: in the value space ``"logsamples"``, each log sample is shrunk towards
            the interpolation of its two neighbours on its slice by a weight ``β`` before the
            spike cap and the subspace rule (:mod:`abrdf_jax._smoothing`): ``None`` (off), a
            fixed ``β`` in [0, 1], or the noise-driven rule ``(β_max, floor, scale)`` that sets
            ``β`` per material and slice from the noise it estimates in the samples; default
            ``(0.6667, 0.045, 0.2)``, chosen on the MERL train split
            (``python -m benchmarks.noise_smoothing``: no cost on clean captures, 5-8 % lower
            ΔE76 at 20 % noise on train, 2-5 % on test).
    """

    budget: str = "iso102"
    rule: str = "filip2012"
    kernel: str = "gaussian"
    degree: int | None = None
    parameterization: str = "onion"
    interp: str = "linear"
    value_space: str = "linear"
    log_eps: float = 0.01
    pairs: tuple = PROTOCOL_PAIRS
    slice_count: int = 24
    spike_cap: tuple | None = (0.93, 0.5)
    slice_smoothing: float | tuple | None = (0.6667, 0.045, 0.2)

    def __post_init__(self):
        for name, value, allowed in (
            ("budget", self.budget, BUDGETS),
            ("rule", self.rule, RULES),
            ("kernel", self.kernel, KERNELS),
            ("parameterization", self.parameterization, PARAMETERIZATIONS),
            ("interp", self.interp, INTERP_METHODS),
            ("value_space", self.value_space, VALUE_SPACES),
        ):
            if value not in allowed:
                raise InputError(f"Config.{name} must be one of {allowed}, got {value!r}")
        resolve_degree(self.kernel, self.degree)
        if not self.pairs or any(
            len(p) != 2 or not all(0 <= float(t) < 90 for t in p) for p in self.pairs
        ):
            raise InputError(
                f"Config.pairs must be (theta_i, theta_v) pairs in [0, 90) degrees, got {self.pairs!r}"
            )
        if not (isinstance(self.slice_count, int) and self.slice_count >= 2):
            raise InputError(f"Config.slice_count must be an int >= 2, got {self.slice_count!r}")
        cap = self.spike_cap
        if cap is not None and not (
            isinstance(cap, tuple)
            and len(cap) == 2
            and all(isinstance(v, (int, float)) and np.isfinite(v) for v in cap)
            and 0 < cap[0] <= 1
            and cap[1] >= 0
        ):
            raise InputError(
                f"Config.spike_cap must be None or (quantile in (0, 1], margin >= 0), got {cap!r}"
            )
        check_smoothing(self.slice_smoothing)
        if not (isinstance(self.log_eps, float) and self.log_eps > 0):
            raise InputError(f"Config.log_eps must be a positive float, got {self.log_eps!r}")

    @classmethod
    def recommended(cls, budget: str = "iso102", **overrides) -> "Config":
        """The settings that won on the MERL train split (log values): ``preset("recommended")``.

        ``Config()`` is the paper's method (linear values); this is the package's
        recommendation, measured side by side in ``benchmarks/merl_accuracy.py``.
        """
        return preset("recommended", budget, **overrides)

    @property
    def subspace_rule(self) -> str:
        return "diagonal" if self.budget == "iso102" else self.rule

    @property
    def linear(self) -> bool:
        """Whether the reconstruction is linear in the (log of the) samples: a linear subspace
        rule and no log after it, so that it is one matrix (:func:`abrdf_jax.compile_operator`)."""
        return self.subspace_rule in LINEAR_RULES and self.value_space not in LOG_SUBSPACE

    @property
    def counts(self) -> tuple[int, ...]:
        """Samples per slice (axial, diagonal per pair) when sampling this configuration.

        The PROTOCOL pairs use PROTOCOL.md's counts (25, 25, 26, 26); other elevation pairs take
        ``slice_count`` samples per measured slice.
        """
        if tuple(map(tuple, self.pairs)) == PROTOCOL_PAIRS:
            return protocol_counts(self.budget)
        axial = self.slice_count if self.budget == "aniso204" else 0
        return tuple(c for _ in self.pairs for c in (axial, self.slice_count))


# Defaults chosen on the MERL *train* split, iso102, by mean ΔE76 with
# `python -m benchmarks.merl_accuracy` (its JSON keeps the whole grid); see docs/notes.md.
# Widths are radians of the onion coordinates. Other settings fall back to the
# parameterization's width (abrdf_jax._coords) and FALLBACK_REG.
TUNED_DEFAULTS = {
    # (kernel, value_space, degree): (width, reg)     train mean ΔE76 (iso102)
    ("gaussian", "linear", None): (0.45, 1e-2),  # 11.67, the paper's method
    ("inverse_multiquadric", "linear", None): (0.3, 1e-2),  # 14.62
    ("multiquadric", "linear", None): (0.6, 1e-2),  # 15.04
    ("thin_plate_spline", "linear", None): (1.0, 1e-3),  # 15.64
    ("thin_plate_spline", "logsamples", None): (1.0, 1e-3),  # 3.14, recommended
    ("multiquadric", "logsamples", None): (0.3, 1e-3),  # 3.26
    ("inverse_multiquadric", "logsamples", 0): (0.3, 1e-3),  # 3.53
    ("gaussian", "logsamples", 0): (0.45, 1e-2),  # 4.29
    ("thin_plate_spline", "log", None): (1.0, 1e-3),  # 3.68, recommended until 2026-12-02
    ("multiquadric", "log", None): (0.3, 1e-3),  # 3.82
    ("inverse_multiquadric", "log", 0): (0.3, 1e-3),  # 4.05
    ("gaussian", "log", 0): (0.45, 1e-2),  # 4.53
}
FALLBACK_REG = 1e-2
#: The parameterizations of the train grid (``python -m benchmarks.merl_accuracy``): the widths
#: and λ of :data:`TUNED_DEFAULTS` (the onion rows' best; for the recommended thin-plate spline
#: on log samples the onion-hd rows' best is the same, and its width only sets the scale of λ)
#: are their defaults; the others take their fallback width and :data:`FALLBACK_REG`.
TUNED_PARAMETERIZATIONS = ("onion", "onion-hd")
#: The train grid's best (``python -m benchmarks.merl_accuracy``): the thin-plate spline on the log
#: of the samples, taken before slice interpolation. Until 2026-12-02 the grid had no
#: ``"logsamples"`` and this was ``value_space="log"`` (the log after interpolation: train 3.68,
#: test 4.69 ΔE76, against 3.14 and 4.05 now). Interpolating log samples also keeps an aliased
#: specular spike from spreading linearly over the 27.7° between a sparse slice's samples (the
#: extra-pairs capture of issue 12, docs/captures.md). Since 2026-12-06 the RBF's coordinates are
#: ``"onion-hd"``, the onion coordinates with two of the half vector (:mod:`abrdf_jax._coords`),
#: the grid's best once it had them (train 2.92 → 2.69 mean ΔE76).
RECOMMENDED = dict(
    kernel="thin_plate_spline", value_space="logsamples", degree=None, parameterization="onion-hd"
)

#: Every named configuration, in one place: ``preset(name, budget)`` is the same ``Config`` in
#: ``reconstruct --preset``, ``fit --preset``, ``btf reconstruct --preset`` and the Python API.
PRESETS: dict[str, dict] = {
    # The package's recommendation: chosen on the MERL train split (iso102, mean ΔE76).
    "recommended": RECOMMENDED,
    # Filip 2012 as published: Gaussian kernel on linear values, eq. (2-4) for anisotropic data.
    "paper": {},
    # The recommended settings with the linear rule "average" of the two slices, so that the
    # whole reconstruction is one matrix for anisotropic data too (compile_operator; for iso102
    # it equals "recommended"): the BTF default, most accurate of the candidates on procedural
    # BTF texels (docs/btf.md).
    "operator": dict(RECOMMENDED, rule="average"),
}
check_registry("PRESETS", PRESETS)


def preset(name: str, budget: str = "iso102", **overrides) -> Config:
    """The named configuration ``name`` (see :data:`PRESETS`) for ``budget``.

    Raises:
        InputError: for an unknown name (the message lists the presets).
    """
    if name not in PRESETS:
        raise InputError(f"unknown preset {name!r}; choose one of {PRESET_NAMES}")
    return Config(budget=budget, **{**PRESETS[name], **overrides})


class ParamValues(NamedTuple):
    """Parameter values as numpy arrays (no JAX): what :class:`abrdf_jax.Params` holds.

    The command line keys cached operators and writes model records with these;
    ``Params(*values)`` makes the traced parameters of them.
    """

    alpha: np.ndarray
    widths: np.ndarray
    reg: np.ndarray

    @property
    def alpha_deg(self) -> float:
        return float(np.rad2deg(np.asarray(self.alpha)))


def default_values(
    config: Config | None = None, alpha_deg: float = PROTOCOL_ALPHA_DEG, dtype="float32"
) -> ParamValues:
    """The package's default parameters for ``config``: α (radians, from degrees), the widths
    and λ chosen on the train split (:data:`TUNED_DEFAULTS`) or the fallbacks, in ``dtype``."""
    config = config or Config()
    key = (config.kernel, config.value_space, config.degree)
    if config.parameterization in TUNED_PARAMETERIZATIONS and key in TUNED_DEFAULTS:
        width, reg = TUNED_DEFAULTS[key]
    else:
        from ._coords import parameterization  # the parameterization's own width (JAX module)

        width, reg = parameterization(config.parameterization).fallback_width, FALLBACK_REG
    dt = np.dtype(dtype)
    return ParamValues(
        np.asarray(np.deg2rad(alpha_deg), dt), np.full((4,), width, dt), np.asarray(reg, dt)
    )
