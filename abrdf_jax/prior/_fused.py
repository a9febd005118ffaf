"""The fused model: a Gaussian process with the prior as its mean and low-rank covariance, plus a
stationary kernel on the residual and noise (regression kriging with a learned mean).

In the prior's mapped (log-relative) space, one channel's values ``f`` at direction pairs are

``f ~ GP(μ, σ_p² Q Qᵀ + σ_k² k(x, x'))``,  samples ``ŷ = f(x_s) + ε``,  ``ε ~ N(0, σ_n² I)``

with ``μ``, ``Q`` the prior's mean and scaled components (:class:`~abrdf_jax.prior.Prior`) and
``k`` a stationary kernel in :mod:`~abrdf_jax.prior._covariance`'s coordinates. With
``A = σ_k² K_ss + σ_n² I`` and ``U = σ_p Q_s`` the sample covariance is ``C = A + U Uᵀ`` and,
by the Woodbury identity, ``C⁻¹ = A⁻¹ − A⁻¹ U (I + Uᵀ A⁻¹ U)⁻¹ Uᵀ A⁻¹``: one ``n × n``
Cholesky factor of ``A`` and one ``K × K`` factor. The posterior mean at the grid is

``m = μ_g + (σ_p² Q_g Q_sᵀ + σ_k² K_gs) C⁻¹ (ŷ − μ_s)``

(linear in the mapped samples ``ŷ``: for a fixed layout and fixed hyper-parameters it is one
matrix), the latent variance ``v = σ_p² ‖Q_g‖² + σ_k² − diag(k_gsᵀ C⁻¹ k_gs)``, and the log
marginal likelihood ``−½ rᵀ C⁻¹ r − ½ log|C| − ½ n log 2π`` with ``log|C| = log|A| +
log|I + Uᵀ A⁻¹ U|``. Limits: ``σ_k → 0`` is the prior's ridge projection with ``λ = σ_n² / σ_p²``
(:func:`~abrdf_jax.prior.reconstruct_prior`); ``σ_p → 0`` a kernel (GP / RBF) interpolant of the
residual with smoothing ``σ_n² / σ_k²``.

Channels: ``"shared"`` priors fit R, G, B as three right-hand sides of one covariance;
``"joint"`` priors carry the colour correlations in ``Q`` and the kernel is ``k ⊗ I₃``.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import jax.scipy.linalg as jsl

from .._errors import InputError
from .._grid import ubo_target_vectors
from .._measurements import Measurements
from .._slices import slice_directions
from ._covariance import FusedHyper, covariance, features
from ._fused_settings import fused_settings
from ._mapping import below_ceiling, inverse_log_relative, log_relative
from ._model import Prior, SampleBasis
from ._reconstruct import _alpha, _rows, sample_basis


def each(fn, meas: Measurements, alpha, dtype, *batched):
    """``fn(measurement, α, *members)`` for every member of a stack, one after the other.

    ``lax.map``, not ``vmap``: a batched Cholesky solve runs LAPACK's triangular solves on the
    CPU thread pool (``ParallelBatchMap``), which deadlocks in jaxlib 0.10.2 when the pool is
    already busy (docs/prior.md, "Fused model"). ``batched`` are pytrees with a leading member
    axis (e.g. one :class:`FusedHyper` per material).
    """
    alphas = jnp.broadcast_to(_alpha(alpha, dtype), meas.t.shape[:1])
    return jax.lax.map(lambda args: fn(*args), (meas, alphas, *batched))


class FusedSolve(eqx.Module):
    """The factored sample covariance of one layout (everything but the sample values).

    Attributes:
        chol_a: ``(N, N)`` Cholesky factor of ``A`` (padding rows: identity).
        u: ``(N, K)`` ``σ_p W Q_s``; ``ainv_u``: ``A⁻¹ U``; ``chol_m``: factor of ``I + Uᵀ A⁻¹ U``.
        k_gs: ``(G, N)`` ``σ_k² k(x_g, x_s)`` (padding columns zero), in the layout of a row.
        weight: ``(N,)`` 1 at a sample, 0 at padding.
    """

    chol_a: jax.Array
    u: jax.Array
    ainv_u: jax.Array
    chol_m: jax.Array
    k_gs: jax.Array | None
    weight: jax.Array

    def solve(self, r):
        """``C⁻¹ r`` for ``r`` ``(N, ...)`` (Woodbury)."""
        a_r = jsl.cho_solve((self.chol_a, True), r)
        inner = jsl.cho_solve((self.chol_m, True), self.u.T @ a_r)
        return a_r - self.ainv_u @ inner

    def logdet(self):
        return 2 * (
            jnp.sum(jnp.log(jnp.diag(self.chol_a))) + jnp.sum(jnp.log(jnp.diag(self.chol_m)))
        )


def _kron_eye(k, width: int):
    """``k ⊗ I_width``: the kernel for rows of ``width`` channels (joint priors)."""
    return k if width == 1 else jnp.kron(k, jnp.eye(width, dtype=k.dtype))


def sample_features(hyper: FusedHyper, meas: Measurements, alpha):
    """Scaled features ``(S·nmax, F)`` of one measurement's slice positions."""
    wi, wv = slice_directions(meas.t, meas.pairs, alpha)
    return features(hyper, wi.reshape(-1, 3), wv.reshape(-1, 3))


def grid_features(hyper: FusedHyper, dtype):
    """Scaled features ``(6561, F)`` of the 81×81 grid pairs (illumination-major)."""
    wi, wv = ubo_target_vectors(dtype)
    return features(hyper, wi, wv)


def factor(hyper: FusedHyper, basis: SampleBasis, x_s, x_g=None) -> FusedSolve:
    """Factor the covariance of the samples at ``basis``'s positions (features ``x_s``); with
    grid features ``x_g`` also the cross-covariance the prediction needs (else ``k_gs=None``)."""
    dt = basis.components.dtype
    w = basis.weight
    sk2, sn2 = hyper.sigma_k.astype(dt) ** 2, hyper.sigma_n.astype(dt) ** 2
    k_ss = _kron_eye(covariance(hyper, x_s, x_s), basis.width)
    a = sk2 * (w[:, None] * k_ss * w[None, :]) + jnp.diag(sn2 * w + (1 - w))
    chol_a = jnp.linalg.cholesky(a)
    u = hyper.sigma_p.astype(dt) * w[:, None] * basis.components
    ainv_u = jsl.cho_solve((chol_a, True), u)
    m = jnp.eye(u.shape[1], dtype=dt) + u.T @ ainv_u
    k_gs = None
    if x_g is not None:
        k_gs = sk2 * _kron_eye(covariance(hyper, x_g, x_s), basis.width) * w[None, :]
    return FusedSolve(chol_a, u, ainv_u, jnp.linalg.cholesky(m), k_gs, w)


def residuals(prior: Prior, basis: SampleBasis, y):
    """Mapped, centred, masked sample values ``(N, R)`` (``R = 3`` shared, 1 joint) of ``y``
    ``(P, 3)``."""
    z = y.reshape(-1, 1) if prior.channels == "joint" else y.T
    ref_s, cos_s, mean_s = _rows(z, basis.reference, basis.cos_v, basis.mean)
    r = (log_relative(z, ref_s, cos_s, prior.eps) - mean_s) * basis.weight
    return r.T if prior.channels != "joint" else r


def log_marginal_likelihood(fs: FusedSolve, r) -> jax.Array:
    """``log p(ŷ)`` of the residuals ``r`` ``(N, R)`` (summed over the ``R`` right-hand sides)."""
    n = jnp.sum(fs.weight)
    quad = jnp.sum(r * fs.solve(r))
    return -0.5 * (quad + r.shape[1] * (fs.logdet() + n * jnp.log(2 * jnp.pi)))


def posterior_mean(prior: Prior, hyper: FusedHyper, fs: FusedSolve, r):
    """Mapped posterior mean at the grid, ``(G, R)`` rows (the prior's mean added)."""
    alpha = fs.solve(r)
    dt = alpha.dtype
    m = hyper.sigma_p.astype(dt) * (prior.components @ (fs.u.T @ alpha)) + fs.k_gs @ alpha
    return m + prior.mean[:, None]


def grid_sample_covariance(prior: Prior, hyper: FusedHyper, fs: FusedSolve):
    """``cov(f(x_g), ŷ)``, ``(G, N)``: ``σ_p² Q_g Q_sᵀ W + σ_k² k(x_g, x_s) W`` (padding: 0)."""
    return hyper.sigma_p.astype(fs.u.dtype) * prior.components @ fs.u.T + fs.k_gs


def posterior_variance(prior: Prior, hyper: FusedHyper, fs: FusedSolve):
    """Latent (noise-free) posterior variance at the grid, ``(G,)`` (non-negative)."""
    dt = fs.u.dtype
    k_gs = grid_sample_covariance(prior, hyper, fs)  # (G, N)
    prior_var = hyper.sigma_p.astype(dt) ** 2 * jnp.sum(prior.components**2, -1)
    prior_var = prior_var + hyper.sigma_k.astype(dt) ** 2
    explained = jnp.sum(k_gs * fs.solve(k_gs.T).T, -1)
    return jnp.maximum(prior_var - explained, 0.0)


def fused_basis(prior: Prior, meas: Measurements, alpha=None, reference: str = "log"):
    """The prior at one measurement's positions (:func:`~abrdf_jax.prior.sample_basis`)."""
    return sample_basis(prior, meas, alpha, reference=reference)


def fused_bases(prior: Prior, meas: Measurements, alpha=None, reference: str = "log"):
    """:func:`fused_basis` of each member of a stack ``(B, S, nmax)``, stacked ``(B,)``."""
    return each(lambda m, a: fused_basis(prior, m, a, reference), meas, alpha, prior.dtype)


def _check_basis(basis: SampleBasis, meas: Measurements) -> None:
    """A precomputed basis matches ``meas``: the same leading (stack) axes, ``S·nmax`` positions."""
    lead = tuple(meas.t.shape[:-2])
    rows = meas.t.shape[-2] * meas.t.shape[-1] * basis.width
    if tuple(basis.mean.shape) != (*lead, rows):
        raise InputError(
            f"basis: mean of shape {tuple(basis.mean.shape)}, expected {(*lead, rows)} (one per "
            f"measurement of the stack {lead}, at its {meas.t.shape[-2]}x{meas.t.shape[-1]} "
            "positions: fused_basis for one, fused_bases for a stack)"
        )


def fused_mapped(
    meas: Measurements,
    prior: Prior,
    hyper: FusedHyper,
    alpha=None,
    *,
    reference: str = "log",
    return_variance: bool = False,
    basis: SampleBasis | None = None,
):
    """Mapped posterior mean ``(81, 81, 3)`` (and latent variance ``(81, 81, 3)``) of one
    measurement, plus its log marginal likelihood; ``basis``: the prior at its positions, where
    already computed (:func:`fused_basis`: it does not depend on ``hyper``)."""
    alpha = _alpha(alpha, prior.dtype)
    if basis is None:
        basis = fused_basis(prior, meas, alpha, reference)
    x_s = sample_features(hyper, meas, alpha).astype(prior.dtype)
    x_g = grid_features(hyper, prior.dtype)
    fs = factor(hyper, basis, x_s, x_g)
    s, n = meas.t.shape
    r = residuals(prior, basis, jnp.reshape(meas.y, (s * n, 3)).astype(prior.dtype))
    mean = posterior_mean(prior, hyper, fs, r).reshape(81, 81, 3)  # (G, R) rows → table
    lml = log_marginal_likelihood(fs, r)
    if not return_variance:
        return mean, None, lml
    var = posterior_variance(prior, hyper, fs)
    var = jnp.broadcast_to(var.reshape(81, 81, -1), (81, 81, 3))
    return mean, var, lml


def _sample_solve(meas, prior, hyper, alpha, reference, basis=None):
    alpha = _alpha(alpha, prior.dtype)
    if basis is None:
        basis = fused_basis(prior, meas, alpha, reference)
    fs = factor(hyper, basis, sample_features(hyper, meas, alpha).astype(prior.dtype))
    s, n = meas.t.shape
    r = residuals(prior, basis, jnp.reshape(meas.y, (s * n, 3)).astype(prior.dtype))
    return fs, r


def evidence(
    meas: Measurements,
    prior: Prior,
    hyper: FusedHyper,
    alpha=None,
    *,
    reference="log",
    basis: SampleBasis | None = None,
):
    """``(log marginal likelihood, number of mapped values)`` of one measurement (no grid);
    ``basis`` as in :func:`fused_mapped`."""
    if basis is not None:
        _check_basis(basis, meas)
    fs, r = _sample_solve(meas, prior, hyper, alpha, reference, basis)
    return log_marginal_likelihood(fs, r), jnp.sum(fs.weight) * r.shape[1]


def rescaled(meas: Measurements, prior: Prior, hyper: FusedHyper, alpha=None, *, reference="log"):
    """``hyper`` with ``σ_p, σ_k, σ_n`` times the maximum-evidence amplitude ``s`` of this
    measurement, ``s² = rᵀC⁻¹r / n``: the posterior mean does not change (it depends on the
    ratios only), the variance is scaled to the samples (for hyper-parameters fitted on the
    mean alone, e.g. :func:`~abrdf_jax.prior.fit_population`). A stack gives stacked leaves."""
    if meas.t.ndim > 2:
        return each(
            lambda m, a: rescaled(m, prior, hyper, a, reference=reference), meas, alpha, prior.dtype
        )
    fs, r = _sample_solve(meas, prior, hyper, alpha, reference)
    log_s = 0.5 * jnp.log(jnp.sum(r * fs.solve(r)) / (jnp.sum(fs.weight) * r.shape[1]))
    return eqx.tree_at(
        lambda h: (h.log_sigma_p, h.log_sigma_k, h.log_sigma_n),
        hyper,
        (hyper.log_sigma_p + log_s, hyper.log_sigma_k + log_s, hyper.log_sigma_n + log_s),
    )


def _as_table(prior: Prior, *rows):
    """Vectors in the layout of a grid row (``(D,)``) as tables ``(81, 81, 3)``: a shared row
    holds one value per pair, the same for the three channels."""
    if prior.channels != "joint":
        rows = tuple(jnp.repeat(r[:, None], 3, 1) for r in rows)
    return tuple(r.reshape(81, 81, 3) for r in rows)


def grid_ceiling(prior: Prior):
    """The prior's ceiling as a table ``(81, 81, 3)`` (``None`` without one)."""
    return None if prior.ceiling is None else _as_table(prior, prior.ceiling)[0]


def to_linear(prior: Prior, m):
    """Mapped values ``(..., 81, 81, 3)`` → ABRDF values (the prior's inverse map)."""
    ref_g, cos_g = _as_table(prior, *prior.grid_layout())
    return inverse_log_relative(m, ref_g, cos_g, prior.eps)


def to_mapped(prior: Prior, table):
    """ABRDF tables ``(..., 81, 81, 3)`` → the prior's mapped values (its log-relative map)."""
    ref_g, cos_g = _as_table(prior, *prior.grid_layout())
    return log_relative(table, ref_g, cos_g, prior.eps)


def band(prior: Prior, table, variance, k: float = 1.0):
    """The multiplicative ``±kσ`` band in linear space of a fused reconstruction: ``(lower,
    upper)`` tables from the table and its mapped variance (:func:`reconstruct_fused` with
    ``return_variance``). The map is monotone, so a value lies in the band iff its mapped value
    is within ``kσ`` of the mapped mean."""
    m, sd = to_mapped(prior, table), k * jnp.sqrt(variance)
    return to_linear(prior, m - sd), to_linear(prior, m + sd)


def coverage(prior: Prior, table, variance, truth, k: float = 1.0):
    """The fraction of ``truth``'s values inside the ``±kσ`` band (per table: ``(...,)``)."""
    lo, hi = band(prior, table, variance, k)
    inside = (truth >= lo) & (truth <= hi)
    return jnp.mean(inside, axis=(-3, -2, -1))


def reconstruct_fused(
    meas: Measurements,
    prior: Prior,
    hyper: FusedHyper,
    alpha=None,
    *,
    reference: str = "log",
    return_variance: bool = False,
    basis: SampleBasis | None = None,
):
    """Reconstruct the full table(s) with the fused model (module docstring).

    Pure and jit-able (``eqx.filter_jit``), differentiable in ``hyper``, α and the samples; for a
    fixed layout and ``hyper`` linear in the mapped samples.

    Args:
        meas: one :class:`~abrdf_jax.Measurements` ``(S, nmax)`` or a stack ``(B, S, nmax)``.
        prior: a :class:`~abrdf_jax.prior.Prior`.
        hyper: a :class:`~abrdf_jax.prior.FusedHyper` (one for all, or stacked ``(B,)``).
        alpha: slice offset α in radians (default the protocol's 15°); scalar or ``(B,)``.
        reference: how the prior's reference is interpolated at the samples (``"log"``).
        return_variance: also return the latent predictive variance in mapped space.
        basis: the prior at the samples, where already computed (:func:`fused_bases`; it does
            not depend on ``hyper``, so a fit of ``hyper`` computes it once), stacked ``(B,)``
            for a stack.

    Returns:
        ``(..., 81, 81, 3)`` non-negative tables; with ``return_variance`` a tuple
        ``(tables, variance)`` (variance ``(..., 81, 81, 3)`` in mapped space; :func:`band` gives
        the multiplicative band in linear space).

    Raises:
        InputError: ``basis`` is not one per measurement (stacked like ``meas``) or has another
            number of positions than ``meas``.
    """
    if basis is not None:
        _check_basis(basis, meas)
    if meas.t.ndim > 2:

        def one(m, a, b, h=hyper):
            return reconstruct_fused(
                m, prior, h, a, reference=reference, return_variance=return_variance, basis=b
            )

        if jnp.ndim(hyper.log_sigma_p) > 0:  # one hyper per member
            params, static = eqx.partition(hyper, eqx.is_array)
            return each(
                lambda m, a, b, p: one(m, a, b, eqx.combine(p, static)),
                meas,
                alpha,
                prior.dtype,
                basis,
                params,
            )
        return each(one, meas, alpha, prior.dtype, basis)
    mean, var, _ = fused_mapped(
        meas,
        prior,
        hyper,
        alpha,
        reference=reference,
        return_variance=return_variance,
        basis=basis,
    )
    table = to_linear(prior, below_ceiling(mean, grid_ceiling(prior)))
    return (table, var) if return_variance else table


def prior_fused(prior: Prior, dtype=None):
    """``(FusedHyper, settings)`` of a :class:`~abrdf_jax.prior.Prior`: its metadata's
    ``"fused"`` hyper-parameters, else the package's defaults
    (:func:`~abrdf_jax.prior._fused_settings.fused_settings`)."""
    s = fused_settings(prior.metadata)
    return FusedHyper.from_settings(s, dtype or prior.dtype), s


#: Public names of this module's functions (``abrdf_jax.prior.fused_*``).
fused_evidence = evidence
fused_band = band
fused_coverage = coverage
fused_rescaled = rescaled
