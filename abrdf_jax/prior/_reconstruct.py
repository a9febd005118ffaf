"""Prior-only reconstruction: the ridge projection of the mapped samples (Nielsen et al. 2015).

With the prior at the sample positions (``Q_s``, ``μ_s``, ``x_ref,s``: :func:`prior_at_samples`)
and the mapped samples ``ŷ = log_relative(y, x_ref,s, cos θv, ε)``, the weights are

``c = argmin ‖W^½ (Q_s c − (ŷ − μ_s))‖² + λ‖c‖² = (Q_sᵀ W Q_s + λI)⁻¹ Q_sᵀ W (ŷ − μ_s)``

(``W`` is 1 at a sample, 0 at padding) and the table is ``inverse_log_relative(μ + Q c)``. For a
fixed layout the map ``ŷ → c`` is one ``K × n`` matrix (:func:`ridge_operator`): the
reconstruction is linear in the mapped samples, so it compiles into an operator like the RBF's.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from .._measurements import Measurements
from .._sampling import interpolate_table, table_corners
from .._slices import PROTOCOL_ALPHA_DEG
from ._exact import exact_basis, training_models
from ._mapping import below_ceiling, grid_cos_view, inverse_log_relative, log_relative
from ._model import Prior, SampleBasis


def _alpha(alpha, dtype):
    a = np.deg2rad(PROTOCOL_ALPHA_DEG) if alpha is None else alpha
    return jnp.asarray(a, dtype)


#: How :func:`prior_at_samples` interpolates the reference: linearly in value, or in the log of
#: ``x_ref cos θv + ε`` (consistent with the mapped mean and components, which are logs).
REFERENCE_INTERP = ("linear", "log")


def prior_at_samples(
    prior: Prior, meas: Measurements, alpha=None, reference: str = "linear"
) -> SampleBasis:
    """The prior at the sample positions of one measurement, interpolated from its grid tables.

    Mean and components are interpolated bilinearly over both azimuths on the UBO rings of each
    slice (:func:`abrdf_jax.sample_table`'s interpolation), at the positions ``meas.t`` for
    slice offset ``alpha`` (radians; default the protocol's 15°); the reference likewise
    (``reference="linear"``) or in the log domain (``"log"``: ``exp`` of the interpolated
    ``ln(x_ref cos θv + ε)``, so that a mapped training material at a sample is the difference
    of two interpolated logs, as its mean and components are; better on MERL, docs/prior.md
    "Fused model"). Positions are the ``S·nmax`` padded entries; padding gets weight 0.
    """
    if reference not in REFERENCE_INTERP:
        raise ValueError(f"reference must be one of {REFERENCE_INTERP}, got {reference!r}")
    dt = prior.dtype
    corners = table_corners(jnp.asarray(meas.t, dt), _alpha(alpha, dt), meas.pairs)
    c = 3 if prior.channels == "joint" else 1
    k = prior.n_components
    ref_g = prior.reference.reshape(81, 81, 3)
    if reference == "log":
        cos_g = jnp.asarray(grid_cos_view(), dt).reshape(81, 81, 1)
        log_ref = interpolate_table(jnp.log(ref_g * cos_g + prior.eps), corners)
    else:
        ref = interpolate_table(ref_g, corners)
    mean = interpolate_table(prior.mean.reshape(81, 81, c), corners)
    comps = interpolate_table(prior.components.reshape(81, 81, c, k), corners)
    s, n = meas.t.shape
    cos = jnp.broadcast_to(jnp.asarray(meas.slice_cos_view(), dt)[:, None, None], (s, n, c))
    weight = jnp.broadcast_to(meas.mask[..., None], (s, n, c)).astype(dt)
    if reference == "log":  # the slice's θv is one ring: cos θv is the same at every corner
        ref = (jnp.exp(log_ref) - prior.eps) / cos[..., :1]
    ref = ref.reshape(s * n, 3)
    ref = ref.reshape(-1) if c == 3 else ref[:, 0]
    return SampleBasis(
        mean=mean.reshape(-1),
        reference=ref,
        cos_v=cos.reshape(-1),
        components=comps.reshape(-1, k),
        weight=weight.reshape(-1),
        width=c,
    )


def sample_basis(prior: Prior, meas: Measurements, alpha=None, reference: str = "linear"):
    """The prior at one measurement's sample positions: exact where the prior's training
    materials are models (:func:`abrdf_jax.prior._exact.exact_basis`: the default prior), else
    interpolated from its grid tables (:func:`prior_at_samples`, whose ``reference`` this is).
    Every reconstruction with a prior reads its basis here."""
    models = training_models(prior)
    if models is None:
        return prior_at_samples(prior, meas, alpha, reference=reference)
    return exact_basis(prior, models, meas, _alpha(alpha, prior.dtype))


def ridge_operator(basis: SampleBasis, lam) -> jax.Array:
    """``(Q_sᵀ W Q_s + λI)⁻¹ Q_sᵀ W``: centred mapped samples → weights, ``(K, P·C)``."""
    q = basis.components
    qw = q * basis.weight[:, None]
    gram = q.T @ qw + jnp.asarray(lam, q.dtype) * jnp.eye(q.shape[1], dtype=q.dtype)
    return jnp.linalg.solve(gram, qw.T)


def _rows(x, *vectors):
    """``vectors`` (one row each) with leading axes of size 1 to match ``x`` (explicit ranks)."""
    lead = (1,) * (x.ndim - 1)
    return tuple(v.reshape(lead + v.shape) for v in vectors)


def project(prior: Prior, basis: SampleBasis, lam, y) -> jax.Array:
    """Tables ``(..., 81, 81, 3)`` from sample values ``y`` ``(..., P, 3)`` at ``basis``'s positions."""
    dt = prior.dtype
    r = ridge_operator(basis, lam)
    y = jnp.asarray(y, dt)
    lead = y.shape[:-2]
    # joint: rows of P·3 values; shared: (..., 3, P), one row per channel
    z = y.reshape(*lead, -1) if prior.channels == "joint" else jnp.swapaxes(y, -1, -2)
    ref_s, cos_s, mean_s = _rows(z, basis.reference, basis.cos_v, basis.mean)
    c = (log_relative(z, ref_s, cos_s, prior.eps) - mean_s) @ r.T
    m = c @ prior.components.T
    ref_g, cos_g, mean_g = _rows(m, *prior.grid_layout(), prior.mean)
    top = None if prior.ceiling is None else _rows(m, prior.ceiling)[0]
    out = inverse_log_relative(below_ceiling(m + mean_g, top), ref_g, cos_g, prior.eps)
    if prior.channels == "joint":
        return out.reshape(*lead, 81, 81, 3)
    return jnp.swapaxes(out, -1, -2).reshape(*lead, 81, 81, 3)


def reconstruct_prior(meas: Measurements, prior: Prior, lam=None, alpha=None) -> jax.Array:
    """Reconstruct the full table(s) from a measurement with the prior alone.

    Pure and jit-able (``eqx.filter_jit(reconstruct_prior)``), differentiable in ``lam``, α and
    the sample values; linear in the mapped samples for a fixed layout.

    Args:
        meas: one :class:`~abrdf_jax.Measurements` ``(S, nmax)``, or a stack ``(..., S, nmax)``
            (each member its own positions).
        prior: a :class:`Prior`.
        lam: ridge λ (default ``prior.lam``, the value chosen when it was trained).
        alpha: slice offset α in radians (default the protocol's 15°); scalar or one per member.

    Returns:
        ``(..., 81, 81, 3)`` non-negative tables in the prior's dtype.
    """
    lam = prior.lam if lam is None else lam
    alpha = _alpha(alpha, prior.dtype)
    if meas.t.ndim > 2:
        alphas = jnp.broadcast_to(alpha, meas.t.shape[:1])
        return jax.vmap(lambda m, a: reconstruct_prior(m, prior, lam, a))(meas, alphas)
    basis = sample_basis(prior, meas, alpha)
    s, n = meas.t.shape
    return project(prior, basis, lam, jnp.reshape(meas.y, (s * n, 3)))
