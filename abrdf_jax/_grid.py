"""Directions and their parameterizations.

Conventions (``../shared/PROTOCOL.md``): angles given by users are in degrees; unit vectors are
``x = sin θ cos φ, y = sin θ sin φ, z = cos θ`` with ``z`` the surface normal and ``x`` the tangent.
Internally every function here works in radians.

Parameterizations of one direction:

- spherical ``(θ, φ)``;
- onion ``(α, β)`` (Havran, Filip & Myszkowski, CGF 29(1), 2010): ``β = asin(x)``,
  ``α = atan2(y, z)``; inverse ``x = sin β``, ``y = sin α cos β``, ``z = cos α cos β``. It has no
  azimuth seam and the normal maps to ``(0, 0)``.

Of a pair of directions: Rusinkiewicz (1998) half/difference angles ``(θh, φh, θd, φd)``.

The RBF centres of a reconstruction are every (φi, φv) pair of the two UBO rings of each measured
elevation pair (:func:`centre_layout`); its targets are the 6561 UBO pairs
(:func:`ubo_target_vectors`), where the reconstructed subspaces are put back (:func:`keep_centres`).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ._protocol import UBO_COUNTS as UBO_COUNTS, UBO_THETAS_DEG as UBO_THETAS_DEG
from ._xp import namespace

if TYPE_CHECKING:  # annotations only: jaxtyping's Array imports JAX
    from jaxtyping import Array, Float


def ubo_grid() -> tuple[np.ndarray, np.ndarray]:
    """The UBO2003 81-direction hemisphere grid.

    Returns:
        ``(theta_deg, phi_deg)``, two float64 numpy arrays of shape ``(81,)``, ordered by θ
        ascending then φ ascending; index 0 is the normal, 1–6 the 15° ring, …, 57–80 the 75° ring.
    """
    theta, phi = [], []
    for t, n in zip(UBO_THETAS_DEG, UBO_COUNTS):
        for k in range(n):
            theta.append(t)
            phi.append(k * 360.0 / n)
    return np.asarray(theta), np.asarray(phi)


def ring_indices(theta_deg: float) -> np.ndarray:
    """Indices into the UBO grid of the ring at elevation ``theta_deg`` (one of ``UBO_THETAS_DEG``)."""
    theta, _ = ubo_grid()
    idx = np.nonzero(np.isclose(theta, theta_deg))[0]
    if idx.size == 0:
        raise ValueError(
            f"theta={theta_deg} deg is not a ring of the UBO2003 grid; rings are {UBO_THETAS_DEG}"
        )
    return idx


def pair_grid(theta_deg: np.ndarray | None = None, phi_deg: np.ndarray | None = None):
    """All (illumination, view) pairs of a direction set, illumination-major.

    Returns:
        ``(theta_i, phi_i, theta_v, phi_v)`` in degrees, each of shape ``(n*n,)``; entry
        ``i*n + v`` is illumination ``i`` and view ``v`` (the layout of ``table[i, v]``).
    """
    if theta_deg is None:
        theta_deg, phi_deg = ubo_grid()
    n = len(theta_deg)
    ti = np.repeat(theta_deg, n)
    pi = np.repeat(phi_deg, n)
    tv = np.tile(theta_deg, n)
    pv = np.tile(phi_deg, n)
    return ti, pi, tv, pv


def to_vector(
    theta: Float[Array, "..."], phi: Float[Array, "..."], xp=None
) -> Float[Array, "... 3"]:
    """Spherical angles (radians) to unit vectors (``xp=numpy``: on the host, no JAX dispatch)."""
    xp = namespace(xp)
    st = xp.sin(theta)
    return xp.stack([st * xp.cos(phi), st * xp.sin(phi), xp.cos(theta)], axis=-1)


def mean_directions(w: np.ndarray, groups: np.ndarray, size: int) -> np.ndarray:
    """The normalised mean ``(size, 3)`` of unit vectors ``w`` ``(n, 3)`` in each group
    (``groups`` ``(n,)``, ints in ``[0, size)``); zeros where a group has none (numpy)."""
    out = np.stack([np.bincount(groups, w[:, c], size) for c in range(3)], -1)
    norm = np.linalg.norm(out, axis=-1, keepdims=True)
    return np.divide(out, norm, out=np.zeros_like(out), where=norm > 0)


def from_vector(
    w: Float[Array, "... 3"], xp=None
) -> tuple[Float[Array, "..."], Float[Array, "..."]]:
    """Unit vectors to spherical angles ``(θ, φ)`` in radians, ``φ`` in ``[0, 2π)``.

    The argument of ``arccos`` is clamped to ``[-1, 1]`` so that rounding never gives NaN.
    """
    xp = namespace(xp)
    theta = xp.arccos(xp.clip(w[..., 2], -1.0, 1.0))
    return theta, _azimuth(w[..., 0], w[..., 1], xp)


def _azimuth(x, y, xp):
    """``atan2(y, x)`` in ``[0, 2π)``: rounding noise just below 0 (``y = -1e-17``) is 0, not
    ``2π − 1e-17`` (which rounds to ``2π``): without it a direction on the seam ``φ = 0`` would
    land on either side of it by chance, and the RBF's coordinates put the sides 2π apart."""
    phi = xp.mod(xp.arctan2(y, x), 2 * np.pi)
    seam = 2 * np.pi * (1 - 100 * xp.finfo(phi.dtype).eps)
    return xp.where(phi >= seam, 0.0, phi)


def onion_from_vector(w: Float[Array, "... 3"], xp=None) -> Float[Array, "... 2"]:
    """Unit vectors to onion coordinates ``(α, β)`` in radians (Havran et al. 2010)."""
    xp = namespace(xp)
    beta = xp.arcsin(xp.clip(w[..., 0], -1.0, 1.0))
    alpha = xp.arctan2(w[..., 1], w[..., 2])
    return xp.stack([alpha, beta], axis=-1)


def vector_from_onion(ab: Float[Array, "... 2"]) -> Float[Array, "... 3"]:
    """Onion coordinates ``(α, β)`` (radians) to unit vectors."""
    import jax.numpy as jnp

    a, b = ab[..., 0], ab[..., 1]
    cb = jnp.cos(b)
    return jnp.stack([jnp.sin(b), jnp.sin(a) * cb, jnp.cos(a) * cb], axis=-1)


def onion(theta: Float[Array, "..."], phi: Float[Array, "..."]) -> Float[Array, "... 2"]:
    """Spherical angles (radians) to onion coordinates ``(α, β)`` (radians)."""
    return onion_from_vector(to_vector(theta, phi))


def _rot_z(w, a, xp):
    c, s = xp.cos(a), xp.sin(a)
    return xp.stack([c * w[..., 0] - s * w[..., 1], s * w[..., 0] + c * w[..., 1], w[..., 2]], -1)


def _rot_y(w, a, xp):
    c, s = xp.cos(a), xp.sin(a)
    return xp.stack([c * w[..., 0] + s * w[..., 2], w[..., 1], -s * w[..., 0] + c * w[..., 2]], -1)


def half_diff(
    wi: Float[Array, "... 3"], wv: Float[Array, "... 3"], xp=None
) -> Float[Array, "... 4"]:
    """Rusinkiewicz (1998) half/difference angles ``(θh, φh, θd, φd)`` in radians.

    ``h = normalize(wi + wv)``; ``d`` is ``wi`` rotated by ``-φh`` about z, then by ``-θh`` about y.
    ``φh, φd`` are in ``[0, 2π)``. Where ``wi = -wv`` the half vector is undefined; the sum's
    norm is floored so that the result stays finite. Where ``h`` (or ``d``) is the pole
    (``θh = 0``: mirror pairs about the normal; ``θd = 0``: ``wi = wv``) its azimuth is
    undefined and would be ``atan2`` of rounding noise, different in every implementation and
    dtype: it is 0 there (within ``1000 ε`` of the pole; ``atan2(0, 1)``, not ``atan2(0, 0)``).
    """
    xp = namespace(xp)
    hs = wi + wv
    n2 = xp.sum(hs * hs, axis=-1, keepdims=True)
    safe = xp.where(n2 > 1e-30, n2, 1.0)
    h = xp.where(n2 > 1e-30, hs / xp.sqrt(safe), xp.asarray([0.0, 0.0, 1.0], dtype=wi.dtype))
    pole = (1000 * xp.finfo(wi.dtype).eps) ** 2
    th, ph = _polar_angles(h, pole, xp)
    d = _rot_y(_rot_z(wi, -ph, xp), -th, xp)
    td, pd = _polar_angles(d, pole, xp)
    return xp.stack([th, ph, td, pd], axis=-1)


def _polar_angles(w, pole, xp):
    """:func:`from_vector` with the azimuth 0 within ``sqrt(pole)`` of the pole (double where:
    ``atan2(0, 1)``, so the azimuth adds no NaN gradient there), and the elevation by
    ``atan2(|(x, y)|, z)``: accurate near the pole, where ``arccos(z)`` is not (in float32 it
    puts a mirror pair's ``θh`` at about 3e-4 instead of 0), with a zero gradient at it."""
    r2 = w[..., 0] ** 2 + w[..., 1] ** 2
    at_pole = r2 <= pole
    x = xp.where(at_pole, 1.0, w[..., 0])
    y = xp.where(at_pole, 0.0, w[..., 1])
    r = xp.where(r2 > 0, xp.sqrt(xp.where(r2 > 0, r2, 1.0)), 0.0)
    return xp.arctan2(r, w[..., 2]), _azimuth(x, y, xp)


def vectors_from_half_diff(
    hd: Float[Array, "... 4"],
) -> tuple[Float[Array, "... 3"], Float[Array, "... 3"]]:
    """Inverse of :func:`half_diff`: ``(θh, φh, θd, φd)`` to ``(wi, wv)`` unit vectors."""
    import jax.numpy as jnp

    th, ph, td, pd = hd[..., 0], hd[..., 1], hd[..., 2], hd[..., 3]
    d = to_vector(td, pd)
    wi = _rot_z(_rot_y(d, th, jnp), ph, jnp)
    h = to_vector(th, ph)
    wv = 2.0 * jnp.sum(wi * h, axis=-1, keepdims=True) * h - wi
    return wi, wv


# ------------------------------------------------------------------------------------------------
# RBF centres and targets of a reconstruction


def ring_azimuths_deg(theta_deg: float, azimuths: int | None = None) -> np.ndarray:
    """Azimuths of the RBF centres on the ring at ``theta_deg``: the UBO ring's (24 uniform
    azimuths off the grid's rings), or ``azimuths`` uniform ones where the ring has fewer (a
    dense capture resolves more than the grid: :data:`abrdf_jax._grouping.DENSE_AZIMUTHS`)."""
    n, theta = 24, float(theta_deg)
    for t, m in zip(UBO_THETAS_DEG, UBO_COUNTS):
        if abs(t - theta) <= 1e-8 + 1e-5 * abs(theta):  # numpy.isclose's test, without its cost
            n = m
    n = max(n, azimuths or 0)
    return np.arange(n) * 360.0 / n


def centre_layout(pairs, azimuths: int | None = None) -> list[tuple[np.ndarray, np.ndarray]]:
    """RBF centres: per elevation pair, every (φi, φv) of the two rings (degrees), flattened."""
    out = []
    for ti, tv in pairs:
        ai, av = ring_azimuths_deg(ti, azimuths), ring_azimuths_deg(tv, azimuths)
        out.append((np.repeat(ai, len(av)), np.tile(av, len(ai))))
    return out


def centre_count(pairs, azimuths: int | None = None) -> int:
    """How many RBF centres :func:`centre_layout` gives."""
    return sum(len(a) for a, _ in centre_layout(pairs, azimuths))


def centre_vectors(pairs, dtype, azimuths: int | None = None, xp=None):
    """Unit vectors ``(wi, wv)``, each ``(n, 3)``, of the RBF centres of ``pairs`` (:func:`centre_layout` order)."""
    xp = namespace(xp)
    wi, wv = [], []
    for (ti, tv), (pi_, pv) in zip(pairs, centre_layout(pairs, azimuths)):
        wi.append(to_vector(np.full(len(pi_), np.deg2rad(ti)), np.deg2rad(pi_), xp))
        wv.append(to_vector(np.full(len(pv), np.deg2rad(tv)), np.deg2rad(pv), xp))
    return xp.concatenate(wi).astype(dtype), xp.concatenate(wv).astype(dtype)


def ubo_target_vectors(dtype, xp=None):
    """The 6561 UBO pairs' unit vectors ``(wi, wv)``, ``(6561, 3)`` each, as ``xp`` arrays."""
    ti, pi_, tv, pv = pair_grid()
    wi = to_vector(np.deg2rad(ti), np.deg2rad(pi_), np)  # once a build: on the host
    wv = to_vector(np.deg2rad(tv), np.deg2rad(pv), np)
    xp = namespace(xp)
    return xp.asarray(wi, dtype), xp.asarray(wv, dtype)


def _centre_target_index(pairs, azimuths=None) -> tuple[np.ndarray, np.ndarray]:
    """``(centre, target)``: the centres that are UBO pairs and their flat index ``i*81 + v``."""
    theta, phi = ubo_grid()
    key = {(round(float(t), 6), round(float(f), 6)): k for k, (t, f) in enumerate(zip(theta, phi))}
    src, dst, c = [], [], 0
    for (ti, tv), (pi_, pv) in zip(pairs, centre_layout(pairs, azimuths)):
        for a, b in zip(pi_, pv):
            ii = key.get((round(float(ti), 6), round(float(a), 6)))
            vv = key.get((round(float(tv), 6), round(float(b), 6)))
            if ii is not None and vv is not None:
                src.append(c), dst.append(ii * 81 + vv)
            c += 1
    return np.asarray(src, int), np.asarray(dst, int)


def keep_centres(
    out: Float[Array, "q C"], vals: Float[Array, "n C"], pairs, azimuths: int | None = None
) -> Float[Array, "q C"]:
    """Put the reconstructed subspaces back at the centres that are UBO grid pairs (the paper's
    step 3 fills only the missing values); centres off the grid are left to the RBF."""
    src, dst = _centre_target_index(pairs, azimuths)
    if len(src) == 0:
        return out
    if isinstance(out, np.ndarray):  # the host build
        out = out.copy()
        out[dst] = vals[src]
        return out
    return out.at[dst].set(vals[src])
