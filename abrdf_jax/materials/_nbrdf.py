"""Neural BRDF ground truth: the merl-nbrdf networks of the shared data folder.

Data: ``<data_dir>/merl-nbrdf/`` (see its ``SOURCE.md`` and ``EVALUATION.md``): 108 small networks
(Sztrajman, Rainer, Ritschel & Weyrich, "Neural BRDF Representation and Importance Sampling",
CGF 40(6), 2021) fitted to the MERL (Matusik et al. 2003) and Nielsen et al. (2015) measurements,
and the same networks resampled on the UBO2003 81 x 81 grid (``tables81.npz``).

Evaluation (written from the recipe of ``EVALUATION.md``):

1. ``f = 0`` where ``wi_z <= 0`` or ``wv_z <= 0``.
2. Rusinkiewicz (1998) half/difference frame: ``h = normalize(wi + wv)``,
   ``d = Rot_y(-θh) Rot_z(-φh) wi``.
3. ``φd`` folded into ``[0, π)`` (``φd mod π``), i.e. ``(d_x, d_y) -> -(d_x, d_y)`` where the
   fold moves ``φd`` (``d_y < 0``, and ``φd = π`` exactly, which becomes 0).
4. ``φd = 0`` where, after folding, ``φd > π - 1e-4`` (in-plane pairs: exactly 0 or π up to
   rounding) and where ``sqrt(h_x^2 + h_y^2) < 1e-5`` (``h`` on the normal, ``φh`` undefined).
5. ``x = [sin θh, 0, cos θh, sin θd cos φd, sin θd sin φd, cos θd]``.
6. ``a1 = relu(x W1 + b1)``, ``a2 = relu(a1 W2 + b2)``, ``f_r = max(exp(a2 W3 + b3) - 1, 0)``
   (1/sr, linear RGB, no cosine); the ABRDF is ``f_r cos θi``.

The input vector is built from vector components rather than from angles (``sin θh = |h_xy|``,
``(sin θd cos φd, sin θd sin φd) = (d_x, d_y)`` folded, ``cos θd = wi·h``), which is the same
quantity up to rounding but has finite gradients at ``h = n`` and ``θd = 0``. The two thresholds of
step 4 are applied exactly as in the recipe (on ``atan2``), so the grid values match the tables.
"""

import functools
import os
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .._errors import InputError
from ._analytic import AbstractMaterial, _as_float_array, _p, safe_sqrt

#: Environment variable that overrides the shared data folder.
DATA_ENV = "ABRDF_DATA"
#: Sub-folder of the data folder that holds the networks and tables.
NBRDF_FOLDER = "merl-nbrdf"
_WEIGHT_KEYS = ("W1", "b1", "W2", "b2", "W3", "b3")
_WEIGHT_SHAPES = ((6, 21), (21,), (21, 21), (21,), (21, 3), (3,))

# Step 4 thresholds of EVALUATION.md.
_PHI_D_PI_TOL = 1e-4
_H_POLE_TOL = 1e-5


class DataNotFoundError(InputError, FileNotFoundError):
    """The shared data folder or one of its files is missing (an :class:`InputError`)."""


def default_data_dir() -> Path:
    """The shared data folder: ``$ABRDF_DATA`` if set, else ``shared/data`` beside the repository.

    Without the variable the folder is ``<repo>/../shared/data`` (resolved from this file:
    ``abrdf_jax/materials/_nbrdf.py`` -> ``parents[3]``).

    Returns:
        The folder (it contains ``merl-nbrdf/``).

    Raises:
        DataNotFoundError: if the folder does not exist; the message names the path and the
            environment variable.
    """
    env = os.environ.get(DATA_ENV)
    path = Path(env) if env else Path(__file__).resolve().parents[3] / "shared" / "data"
    if not path.is_dir():
        how = f"from ${DATA_ENV}" if env else f"default; set ${DATA_ENV} to override"
        raise DataNotFoundError(f"{path}: shared data folder not found ({how})")
    return path


def _nbrdf_file(filename: str, data_dir=None) -> Path:
    """Path of a file of the merl-nbrdf folder; ``data_dir`` may also be that folder itself."""
    base = default_data_dir() if data_dir is None else Path(data_dir)
    for folder in (base / NBRDF_FOLDER, base):
        if (folder / filename).is_file():
            return folder / filename
    raise DataNotFoundError(
        f"{base / NBRDF_FOLDER / filename}: file not found (data folder {base}; "
        f"set ${DATA_ENV} or pass data_dir)"
    )


@functools.lru_cache(maxsize=4)
def _weights(path: str) -> dict[str, dict[str, np.ndarray]]:
    """All networks of ``weights.npz`` as ``{material: {key: array}}`` (cached per file)."""
    out: dict[str, dict[str, np.ndarray]] = {}
    with np.load(path, allow_pickle=False) as z:  # never unpickle a data file
        for key in z.files:
            name, _, part = key.rpartition("/")
            out.setdefault(name, {})[part] = np.array(z[key])
    for name, parts in out.items():
        for key, shape in zip(_WEIGHT_KEYS, _WEIGHT_SHAPES):
            if key not in parts or parts[key].shape != shape:
                raise InputError(f"{path}: network {name!r} lacks {key} of shape {shape}")
    return out


def nbrdf_names(data_dir=None) -> list[str]:
    """Sorted names of the 108 networks of ``weights.npz``.

    Raises:
        DataNotFoundError: if the data are missing.
    """
    return sorted(_weights(str(_nbrdf_file("weights.npz", data_dir))))


def _pole_or_inplane(dx, dy, rxy2):
    """Masks of the two ``φd = 0`` rules and the fold, computed without gradients."""
    dx, dy, rxy2 = jax.lax.stop_gradient((dx, dy, rxy2))
    phi = jnp.arctan2(dy, dx)
    phi_folded = jnp.mod(phi, jnp.pi)
    # The fold moved the angle by ±π (φ < 0, or φ = π exactly: mod gives 0).
    flip = jnp.abs(phi_folded - phi) > 0.5 * jnp.pi
    zero = (phi_folded > jnp.pi - _PHI_D_PI_TOL) | (rxy2 < _H_POLE_TOL**2)
    return flip, zero


def nbrdf_input(wi: Float[Array, "... 3"], wv: Float[Array, "... 3"]) -> Float[Array, "... 6"]:
    """The network input ``x`` (step 5 of EVALUATION.md) for directions above the horizon.

    Args:
        wi, wv: unit vectors ``(..., 3)`` with positive z (not checked).

    Returns:
        ``(..., 6)``: ``[sin θh, 0, cos θh, sin θd cos φd, sin θd sin φd, cos θd]`` with ``φd``
        folded and the two ``φd = 0`` rules applied.
    """
    s = wi + wv
    n2 = jnp.sum(s * s, axis=-1, keepdims=True)
    h = s / jnp.sqrt(jnp.maximum(n2, 1e-30))
    hx, hy, hz = h[..., 0], h[..., 1], h[..., 2]
    rxy2 = hx * hx + hy * hy
    sin_h = safe_sqrt(rxy2)
    # Rot_z(-φh) with cos φh = hx/|h_xy|, sin φh = hy/|h_xy| (double where at h = n).
    ok = rxy2 > 1e-30
    r_safe = jnp.sqrt(jnp.where(ok, rxy2, 1.0))
    c = jnp.where(ok, hx, 1.0) / r_safe
    sn = jnp.where(ok, hy, 0.0) / r_safe
    wx, wy, wz = wi[..., 0], wi[..., 1], wi[..., 2]
    px = c * wx + sn * wy
    py = -sn * wx + c * wy
    # Rot_y(-θh): cos θh = hz, sin θh = |h_xy|.
    dx = hz * px - sin_h * wz
    dy = py
    dz = jnp.clip(jnp.sum(wi * h, axis=-1), -1.0, 1.0)  # cos θd = wi·h exactly
    flip, zero = _pole_or_inplane(dx, dy, rxy2)
    sign = jnp.where(flip, -1.0, 1.0).astype(wi.dtype)
    sin_d = safe_sqrt(1.0 - dz * dz)
    fx = jnp.where(zero, sin_d, sign * dx)
    fy = jnp.where(zero, 0.0, sign * dy)
    return jnp.stack([sin_h, jnp.zeros_like(hz), hz, fx, fy, dz], axis=-1)


class NeuralBRDF(AbstractMaterial):
    """One merl-nbrdf network: an isotropic, reciprocal measured material.

    ``material(wi, wv)`` returns the ABRDF ``f_r cos θi`` (``(..., 3)``, linear RGB);
    :meth:`brdf` returns ``f_r`` itself (1/sr, no cosine). Both follow the input dtype (the
    float32 weights are cast to it).

    A *stack* of networks (:func:`stack_nbrdf`, weights with a leading material axis) is evaluated
    with ``jax.vmap(lambda m: m(wi, wv))(stack)`` -> ``(m, ..., 3)``; calling a stack directly
    raises an error.

    Attributes:
        W1, b1, W2, b2, W3, b3: weights, shapes (6, 21) (21,) (21, 21) (21,) (21, 3) (3,).
        name: material name (static); for a stack, the names joined by ``","``.
    """

    W1: Array = eqx.field(converter=_as_float_array)
    b1: Array = eqx.field(converter=_as_float_array)
    W2: Array = eqx.field(converter=_as_float_array)
    b2: Array = eqx.field(converter=_as_float_array)
    W3: Array = eqx.field(converter=_as_float_array)
    b3: Array = eqx.field(converter=_as_float_array)
    name: str = eqx.field(static=True, default="")

    def _check(self):
        if self.W1.ndim != 2:
            raise InputError(
                f"NeuralBRDF {self.name!r} holds a stack of {self.W1.shape[0]} networks; "
                "evaluate it with jax.vmap(lambda m: m(wi, wv))(stack)"
            )

    def _brdf(self, wi, wv):
        dt = wi.dtype
        x = nbrdf_input(wi, wv)
        hi = jax.lax.Precision.HIGHEST
        a1 = jax.nn.relu(jnp.matmul(x, _p(self.W1, dt), precision=hi) + _p(self.b1, dt))
        a2 = jax.nn.relu(jnp.matmul(a1, _p(self.W2, dt), precision=hi) + _p(self.b2, dt))
        z = jnp.matmul(a2, _p(self.W3, dt), precision=hi) + _p(self.b3, dt)
        return jnp.maximum(jnp.expm1(z), 0.0)

    def _abrdf(self, wi, wv):
        return self._brdf(wi, wv) * wi[..., 2:3]

    def brdf(
        self, wi: Float[ArrayLike, "... 3"], wv: Float[ArrayLike, "... 3"]
    ) -> Float[Array, "... 3"]:
        """The BRDF ``f_r`` (1/sr, linear RGB, no cosine factor), ``(..., 3)``; 0 below the horizon.

        Raises:
            InputError: on bad shapes, or if this is a stack of networks.
        """
        return self._evaluate("_brdf", wi, wv)


def load_nbrdf(name: str, data_dir=None) -> NeuralBRDF:
    """Load one network by material name (e.g. ``"gold-paint"``).

    Args:
        name: a name of :func:`nbrdf_names`.
        data_dir: the shared data folder (default :func:`default_data_dir`) or its
            ``merl-nbrdf`` sub-folder.

    Returns:
        A :class:`NeuralBRDF` with float32 weights (as stored).

    Raises:
        DataNotFoundError: if the data are missing.
        InputError: if ``name`` is unknown (the message suggests close names).
    """
    path = _nbrdf_file("weights.npz", data_dir)
    nets = _weights(str(path))
    if name not in nets:
        import difflib

        close = difflib.get_close_matches(name, sorted(nets), n=5, cutoff=0.5)
        hint = f"; did you mean {', '.join(close)}?" if close else ""
        raise InputError(f"{path}: no network named {name!r} ({len(nets)} materials){hint}")
    p = nets[name]
    return NeuralBRDF(*(p[k] for k in _WEIGHT_KEYS), name=name)


def load_nbrdf_all(names=None, data_dir=None) -> list[NeuralBRDF]:
    """Load several networks (all 108 in sorted order by default).

    Raises:
        DataNotFoundError, InputError: as :func:`load_nbrdf`.
    """
    if names is None:
        names = nbrdf_names(data_dir)
    return [load_nbrdf(n, data_dir) for n in names]


def stack_nbrdf(models) -> NeuralBRDF:
    """Stack single networks into one :class:`NeuralBRDF` with a leading material axis.

    Use it with ``jax.vmap``: ``jax.vmap(lambda m: m(wi, wv))(stack_nbrdf(models))`` gives
    ``(len(models), ..., 3)`` in one compiled evaluation.

    Raises:
        InputError: if the list is empty or holds something else than single networks.
    """
    models = list(models)
    if not models or not all(isinstance(m, NeuralBRDF) and m.W1.ndim == 2 for m in models):
        raise InputError("stack_nbrdf needs a non-empty list of single NeuralBRDF networks")
    arrays = [jnp.stack([getattr(m, k) for m in models]) for k in _WEIGHT_KEYS]
    return NeuralBRDF(*arrays, name=",".join(m.name for m in models))


def load_tables81(data_dir=None) -> dict[str, np.ndarray]:
    """The ready-made 81 x 81 tables of all networks (``tables81.npz``).

    Returns:
        A dict of numpy arrays: ``names`` (108,) sorted, ``group`` (108,) ``"merl"``/``"nielsen"``,
        ``abrdf`` float32 (108, 81, 81, 3) with ``abrdf[m, i, v]`` (i = illumination, v = view),
        ``split`` (108,) ``"train"``/``"test"``, ``theta_deg``, ``phi_deg`` (81,).

    Raises:
        DataNotFoundError: if the file is missing.
    """
    path = _nbrdf_file("tables81.npz", data_dir)
    with np.load(path, allow_pickle=False) as z:  # never unpickle a data file
        return {k: np.array(z[k]) for k in z.files}


def merl_split(split: str = "train", data_dir=None) -> list[str]:
    """Material names of the train or test split of ``PROTOCOL.md``.

    Names sorted; even positions are ``train``, odd positions ``test`` (checked against the
    ``split`` key of ``tables81.npz``).

    Args:
        split: ``"train"`` or ``"test"``.
        data_dir: see :func:`load_tables81`.

    Raises:
        InputError: on an unknown split name, or if the file disagrees with the protocol.
        DataNotFoundError: if the data are missing.
    """
    if split not in ("train", "test"):
        raise InputError(f"split must be 'train' or 'test', got {split!r}")
    t = load_tables81(data_dir)
    names = [str(n) for n in t["names"]]
    order = sorted(names)
    expected = ["train" if k % 2 == 0 else "test" for k in range(len(order))]
    stored = dict(zip(names, (str(s) for s in t["split"])))
    if [stored[n] for n in order] != expected:
        raise InputError(
            f"{_nbrdf_file('tables81.npz', data_dir)}: 'split' does not follow PROTOCOL.md "
            "(sorted names, even positions train, odd test)"
        )
    return [n for n, s in zip(order, expected) if s == split]
