"""A plain numpy/scipy implementation of Filip (ICPR 2012): the test oracle of the JAX pipeline.

Written independently of the package's JAX code, the way a careful researcher would write it with
scipy: the slices are grouped from the sample list, each toroidal subspace is rebuilt on the UBO
grid pairs of its two rings (eq. 5 for the isotropic budget, eq. 2–4 with the min–max stretch for
the anisotropic one, slices interpolated periodically and linearly, averaged over the two torus
preimages), and ``scipy.interpolate.RBFInterpolator`` fills the other elevations in onion
coordinates ``[αi, βi, αv, βv]`` (with ``parameterization="onion-hd"`` also two half-vector
angles) scaled by the kernel widths. It imports nothing from
``abrdf_jax``: the measurement layout (PROTOCOL.md's elevation pairs, the UBO rings) is written out
here on purpose, so that a change to the package's constants shows up as a disagreement.

Used by ``tests/test_scipy_peer.py`` (agreement to 1e-7 in float64) and
``tests/test_merl_accuracy.py``; the benchmarks' scipy peer (``benchmarks/scipy_baseline.py``)
imports this file, so there is one copy.
"""

from __future__ import annotations

import numpy as np
from scipy.interpolate import RBFInterpolator

PAIRS = ((30.0, 30.0), (30.0, 75.0), (75.0, 30.0), (75.0, 75.0))
MIN_DEGREE = {
    "gaussian": -1,
    "inverse_multiquadric": -1,
    "inverse_quadratic": -1,
    "multiquadric": 0,
    "linear": 0,
    "thin_plate_spline": 1,
    "cubic": 1,
}
RINGS = {0.0: 1, 15.0: 6, 30.0: 12, 45.0: 18, 60.0: 20, 75.0: 24}


def ubo():
    th = np.concatenate([np.full(n, t) for t, n in RINGS.items()])
    ph = np.concatenate([np.arange(n) * 360.0 / n for n in RINGS.values()])
    return th, ph


def vec(theta_deg, phi_deg):
    t, p = np.deg2rad(theta_deg), np.deg2rad(phi_deg)
    return np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], -1)


def onion(w):
    return np.stack([np.arctan2(w[..., 1], w[..., 2]), np.arcsin(np.clip(w[..., 0], -1, 1))], -1)


def coords(wi, wv, parameterization):
    """``[αi, βi, αv, βv]``, and for ``"onion-hd"`` also ``√(θh π/2)`` and ``θd``: the half
    vector's angle to the normal and its angle to the light (``h = (wi + wv) / |wi + wv|``)."""
    x = np.concatenate([onion(wi), onion(wv)], -1)
    if parameterization == "onion":
        return x
    assert parameterization == "onion-hd", parameterization
    h = wi + wv
    h = h / np.linalg.norm(h, axis=-1, keepdims=True)
    th = np.arctan2(np.hypot(h[..., 0], h[..., 1]), h[..., 2])
    td = np.arctan2(np.linalg.norm(np.cross(wi, h), axis=-1), np.sum(wi * h, -1))
    return np.concatenate([x, np.sqrt(th * np.pi / 2)[..., None], td[..., None]], -1)


def scaled(x, widths):
    """Coordinates over their widths; the fifth and sixth coordinates (``"onion-hd"``) take
    the geometric mean of the four widths."""
    w = np.ravel(np.asarray(widths, float))
    w = np.repeat(w, 4) if w.size == 1 else w
    if x.shape[-1] > w.size:
        w = np.concatenate([w, np.full(x.shape[-1] - w.size, np.exp(np.mean(np.log(w))))])
    return x / w


def periodic_linear(angle_deg, values, query_deg):
    """Periodic linear interpolation of one slice (numpy.interp with a wrapped copy)."""
    o = np.argsort(angle_deg)
    a, v = angle_deg[o], values[o]
    a_ext = np.concatenate([a - 360.0, a, a + 360.0])
    v_ext = np.concatenate([v, v, v])
    q = np.mod(query_deg, 360.0)
    return np.stack([np.interp(q, a_ext, v_ext[:, c]) for c in range(v.shape[1])], -1)


def split_slices(ti, pi_, tv, pv, rgb, alpha=15.0, tol=0.5):
    """Group samples into {(pair, kind): (angle, rgb)}; kind 'A' axial (φi), 'D' diagonal (φv)."""
    out = {}

    def near(x):
        return np.abs((x + 180.0) % 360.0 - 180.0) <= tol

    for pair in PAIRS:
        on = (np.abs(ti - pair[0]) <= tol) & (np.abs(tv - pair[1]) <= tol)
        a = on & near(pi_ - pv - alpha)
        d = on & near(pi_ + pv - alpha)
        if np.count_nonzero(a & ~d) >= 3:
            out[pair, "A"] = (pi_[a] % 360.0, rgb[a])
        out[pair, "D"] = (pv[d] % 360.0, rgb[d])
    return out


def subspace_on_grid(slices, pair, alpha=15.0):
    """Reconstruct the toroidal subspace of ``pair`` at its grid pairs (eq. 2–5)."""
    ni, nv = RINGS[pair[0]], RINGS[pair[1]]
    pi_ = np.repeat(np.arange(ni) * 360.0 / ni, nv)
    pv = np.tile(np.arange(nv) * 360.0 / nv, ni)
    d = pi_ - pv
    s = pi_ + pv
    ad, yd = slices[pair, "D"]
    q = (360.0 + alpha - d) / 2.0
    b = 0.5 * (periodic_linear(ad, yd, q) + periodic_linear(ad, yd, q + 180.0))
    if (pair, "A") not in slices:
        return pi_, pv, b  # eq. (5)
    aa, ya = slices[pair, "A"]
    q = (s + alpha) / 2.0
    a = 0.5 * (periodic_linear(aa, ya, q) + periodic_linear(aa, ya, q + 180.0))
    lo = ya.min(0) + yd.min(0)
    hi = ya.max(0) + yd.max(0)
    m = np.minimum(ya.min(0), yd.min(0))
    big_m = np.maximum(ya.max(0), yd.max(0))
    span = np.where(hi > lo, hi - lo, 1.0)
    return pi_, pv, m + (a + b - lo) / span * (big_m - m)  # eq. (2)-(4), min-max stretched


def reconstruct_scipy(
    ti,
    pi_,
    tv,
    pv,
    rgb,
    kernel="gaussian",
    widths=(0.6,) * 4,
    smoothing=1e-3,
    degree=None,
    value_space="linear",
    alpha=15.0,
    log_eps=0.01,
    spike_cap=(0.93, 0.5),
    parameterization="onion",
):
    """Full reconstruction to an (81, 81, 3) table with scipy's RBFInterpolator.

    ``spike_cap=(q, margin)`` (``Config.spike_cap``; log-sample value space only): the RBF fits
    the subspaces of the log samples capped at their quantile ``q`` (all slices' samples, per
    channel) plus ``margin``; the uncapped subspaces are kept where they were measured."""
    slices = split_slices(ti, pi_, tv, pv, rgb, alpha)
    # ε from the slice samples (a sample where two slices cross counts for both)
    eps = log_eps * np.mean(np.abs(np.concatenate([v for _, v in slices.values()])), 0) + 1e-19
    capped = None
    if value_space == "logsamples":  # the log of the samples, before slice interpolation
        slices = {k: (a, np.log(np.maximum(v, 0) + eps)) for k, (a, v) in slices.items()}
        if spike_cap is not None:
            logs = np.concatenate([v for _, v in slices.values()])
            level = np.quantile(logs, spike_cap[0], axis=0) + spike_cap[1]
            capped = {k: (a, np.minimum(v, level)) for k, (a, v) in slices.items()}
    xs, ys, ycs, idx = [], [], [], []
    th, ph = ubo()
    for pair in PAIRS:
        a, b, val = subspace_on_grid(slices, pair, alpha)
        wi, wv = vec(np.full_like(a, pair[0]), a), vec(np.full_like(b, pair[1]), b)
        xs.append(coords(wi, wv, parameterization))
        ys.append(val)
        ycs.append(val if capped is None else subspace_on_grid(capped, pair, alpha)[2])
        ii = np.array([np.nonzero((th == pair[0]) & np.isclose(ph, x))[0][0] for x in a])
        vv = np.array([np.nonzero((th == pair[1]) & np.isclose(ph, x))[0][0] for x in b])
        idx.append(ii * 81 + vv)
    x = scaled(np.concatenate(xs), widths)
    y = np.concatenate(ys)
    idx = np.concatenate(idx)
    y_fit = np.log(np.maximum(y, 0) + eps) if value_space == "log" else np.concatenate(ycs)
    wi = vec(np.repeat(th, 81), np.repeat(ph, 81))
    wv = vec(np.tile(th, 81), np.tile(ph, 81))
    xq = scaled(coords(wi, wv, parameterization), widths)
    if degree is None:  # the kernel's minimum degree (scipy's own default would add a linear tail)
        degree = MIN_DEGREE[kernel]
    out = RBFInterpolator(x, y_fit, kernel=kernel, epsilon=1.0, smoothing=smoothing, degree=degree)(
        xq
    )
    if value_space == "logsamples":
        out[idx] = y  # the reconstructed subspaces where they were measured (log values)
        out = np.exp(out) - eps
    elif value_space == "log":
        out = np.exp(out) - eps
        out[idx] = y
    else:
        out[idx] = y  # keep the reconstructed subspaces where they were measured
    return np.maximum(out, 0.0).reshape(81, 81, 3)
