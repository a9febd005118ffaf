"""Where to measure next: the slice whose samples would lower the learned model's total
predictive variance over the output grid the most.

A candidate is one slice (an elevation pair and a kind, axial or diagonal, at the capture's α)
of ``n`` samples at the protocol's positions ``k · 2π / n``. For a Gaussian process the posterior
variance does not depend on the sample values, so the effect of adding a candidate ``c`` to the
measured samples ``s`` is known before it is measured: with the posterior covariances given
``s``

``Σ_gc = K_gc − K_gs C⁻¹ K_sc``,  ``Σ_cc = K_cc − K_cs C⁻¹ K_sc + σ_n² I``

the grid's variance falls by ``diag(Σ_gc Σ_cc⁻¹ Σ_cg)`` (a rank-``n`` update; ``K`` the fused
covariance ``σ_p² Q Qᵀ + σ_k² k``, ``C`` the samples' covariance,
:class:`~abrdf_jax.prior._fused.FusedSolve`). The score is that fall summed over the grid (and
channels), as a fraction of the total before; exact for the model, whatever the material.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import jax.scipy.linalg as jsl
import numpy as np

from .._errors import InputError
from .._measurements import Measurements
from .._protocol import KINDS, UBO_THETAS_DEG
from ._covariance import FusedHyper, covariance
from ._fused import (
    _kron_eye,
    factor,
    fused_basis,
    grid_features,
    grid_sample_covariance,
    posterior_variance,
    sample_features,
)
from ._model import Prior
from ._reconstruct import _alpha


def ring_pairs(thetas=UBO_THETAS_DEG) -> tuple[tuple[float, float], ...]:
    """Every elevation pair ``(θi, θv)`` of the given rings (default the UBO2003 rings)."""
    return tuple((float(a), float(b)) for a in thetas for b in thetas)


def candidate_slices(pairs, n: int, dtype=jnp.float32) -> Measurements:
    """Both slices of every pair in ``pairs``, ``n`` samples each at ``k · 2π / n`` (values 0): slice
    ``2p`` is pair ``p``'s axial slice, ``2p + 1`` its diagonal one."""
    if n < 1 or not pairs:
        raise InputError(f"candidate slices need pairs and n >= 1, got {len(pairs)} pairs, n {n}")
    t = np.broadcast_to(np.arange(n) * 2 * np.pi / n, (2 * len(pairs), n))
    return Measurements(
        jnp.asarray(t, dtype),
        jnp.zeros((2 * len(pairs), n, 3), dtype),
        jnp.full((2 * len(pairs),), n, jnp.int32),
        tuple(tuple(map(float, p)) for p in pairs),
        True,
    )


def _cov(hyper: FusedHyper, q_a, x_a, q_b, x_b, width: int):
    """The fused covariance ``σ_p² Q_a Q_bᵀ + σ_k² k(x_a, x_b) ⊗ I`` of two sets of rows."""
    dt = q_a.dtype
    k = _kron_eye(covariance(hyper, x_a, x_b), width)
    return hyper.sigma_p.astype(dt) ** 2 * q_a @ q_b.T + hyper.sigma_k.astype(dt) ** 2 * k


def slice_scores(
    meas: Measurements,
    prior: Prior,
    hyper: FusedHyper,
    candidates: Measurements,
    alpha=None,
    reference: str = "log",
):
    """``(total, reduction)``: the grid's total latent variance given ``meas`` (summed over the
    grid's rows and the channels), and by how much each slice of ``candidates``
    (:func:`candidate_slices`) would lower it, ``(S_c,)`` (module docstring). Pure, jit-able."""
    alpha = _alpha(alpha, prior.dtype)
    dt = prior.dtype
    basis = fused_basis(prior, meas, alpha, reference)
    x_g = grid_features(hyper, dt)
    x_s = sample_features(hyper, meas, alpha).astype(dt)
    fs = factor(hyper, basis, x_s, x_g)
    channels = 1 if prior.channels == "joint" else 3  # a shared row stands for three channels
    total = channels * jnp.sum(posterior_variance(prior, hyper, fs))
    k_gs = grid_sample_covariance(prior, hyper, fs)  # (G, N)
    gain = fs.solve(k_gs.T).T  # K_gs C⁻¹
    w = basis.width
    cb = fused_basis(prior, candidates, alpha, "linear")  # components only: no reference needed
    n = candidates.t.shape[1]
    q_c = cb.components.reshape(-1, n * w, cb.components.shape[-1])
    x_c = sample_features(hyper, candidates, alpha).astype(dt)
    x_c = x_c.reshape(-1, n, x_c.shape[-1])
    q_s = basis.components * basis.weight[:, None]  # padding rows: no covariance

    def one(args):
        q, x = args
        k_sc = _cov(hyper, q_s, x_s, q, x, w) * basis.weight[:, None]
        s_gc = _cov(hyper, prior.components, x_g, q, x, w) - gain @ k_sc
        s_cc = _cov(hyper, q, x, q, x, w) - k_sc.T @ fs.solve(k_sc)
        s_cc = s_cc + hyper.sigma_n.astype(dt) ** 2 * jnp.eye(n * w, dtype=dt)
        half = jsl.solve_triangular(jnp.linalg.cholesky(s_cc), s_gc.T, lower=True)
        return channels * jnp.sum(half**2)

    return total, jax.lax.map(one, (q_c, x_c))


_scores = eqx.filter_jit(slice_scores)


def suggest_slices(
    meas: Measurements,
    prior: Prior,
    model: str = "fused",
    alpha=None,
    *,
    pairs=None,
    samples: int | None = None,
    kinds=KINDS,
) -> list[dict]:
    """The candidate slices ranked by how much they would lower the total predictive variance of
    ``--model fused`` or ``--model prior`` given ``meas`` (one measurement, the slices the model
    reads); best first.

    Args:
        meas: one :class:`~abrdf_jax.Measurements`; its slices with samples are not proposed.
        prior: a :class:`~abrdf_jax.prior.Prior`.
        model: ``"fused"`` or ``"prior"`` (:func:`~abrdf_jax.prior.learned_hyper`).
        alpha: slice offset α in radians (default the protocol's 15°).
        pairs: candidate elevation pairs in degrees (default :func:`ring_pairs`: the UBO rings).
        samples: samples per candidate slice (default the largest count of ``meas``'s slices).
        kinds: which slice kinds to propose (``"axial"``, ``"diagonal"``).

    Returns:
        One dict per candidate: ``pair`` ``(θi, θv)``, ``kind``, ``samples``, ``reduction``
        (fraction of the current total variance it removes), ``variance_after`` (the fraction
        left), ``rank`` (1 = best).
    """
    from ._uncertainty import learned_hyper

    bad = [k for k in kinds if k not in KINDS]
    if bad or not kinds:
        raise InputError(f"slice kinds must be among {', '.join(KINDS)}, got {list(kinds)}")
    pairs = ring_pairs() if pairs is None else tuple(tuple(map(float, p)) for p in pairs)
    off = [p for p in pairs if not all(np.isclose(t, UBO_THETAS_DEG).any() for t in p)]
    if off:  # the prior is known on the UBO grid's rings only
        rings = ", ".join(f"{t:g}" for t in UBO_THETAS_DEG)
        raise InputError(f"candidate elevations must be UBO rings ({rings} deg), got {off}")
    count = np.asarray(meas.count)
    n = int(samples if samples is not None else count.max())
    hyper, reference = learned_hyper(prior, model, prior.dtype)
    cands = candidate_slices(pairs, n, prior.dtype)
    total, red = _scores(meas, prior, hyper, cands, alpha, reference)
    total, red = float(total), np.asarray(red, np.float64)
    measured = {(tuple(meas.pairs[s // 2]), KINDS[s % 2]) for s in np.flatnonzero(count > 0)}
    rows = []
    for s, r in enumerate(red):
        pair, kind = pairs[s // 2], KINDS[s % 2]
        if kind in kinds and (pair, kind) not in measured:
            frac = float(r / total) if total > 0 else 0.0
            rows.append(
                dict(pair=pair, kind=kind, samples=n, reduction=frac, variance_after=1 - frac)
            )
    rows.sort(key=lambda d: -d["reduction"])
    return [d | {"rank": k + 1} for k, d in enumerate(rows)]
