"""Fitting the fused model's hyper-parameters: per material by evidence, or on a population by
held-out error.

- :func:`fit_evidence`: maximise each measurement's log marginal likelihood
  (:func:`~abrdf_jax.prior._fused.evidence`, per mapped value) over the logs of the widths and
  scales, with a weak Gaussian hyper-prior ``N(log θ₀, τ²)`` around the start ``θ₀`` (type-II
  maximum a posteriori; it keeps a scale that the samples cannot see, e.g. ``σ_k`` of a material
  the prior explains exactly, from running off). A fixed number of Adam steps (Kingma & Ba
  2015) in one ``lax.scan``: the same cost for every material, one material after the other over a stack.
- :func:`fit_population`: one set of hyper-parameters for a population of materials, by gradient
  descent on the mean held-out ΔE76 (PROTOCOL.md) of a ``folds``-fold split *within* the training
  tables: each fold's materials are reconstructed by the fused model with a prior trained on the
  other folds (the design's "tuning against held-out measurements", differentiated end to end).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._errors import InputError
from .._measurements import Measurements
from ._covariance import FusedHyper
from ._fused import each, evidence, fused_basis, fused_bases, reconstruct_fused
from ._model import Prior, train_prior


def adam_update(params, state, g, t, lr, b1=0.9, b2=0.999, eps=1e-8):
    """One Adam step (Kingma & Ba 2015) at step number ``t ≥ 1``: ``(params, state)``; the state
    is ``(m, v)`` (start: zeros like ``params``). A non-finite gradient skips the step (no silent
    NaN in the parameters)."""
    leaves = jax.tree_util.tree_leaves(g)
    ok = jnp.all(jnp.asarray([jnp.all(jnp.isfinite(x)) for x in leaves]))
    g = jax.tree_util.tree_map(lambda x: jnp.where(ok, x, 0.0), g)
    m, v = state
    m = jax.tree_util.tree_map(lambda a, b: b1 * a + (1 - b1) * b, m, g)
    v = jax.tree_util.tree_map(lambda a, b: b2 * a + (1 - b2) * b * b, v, g)

    def move(p, a, b):
        return p - jnp.where(ok, lr * (a / (1 - b1**t)) / (jnp.sqrt(b / (1 - b2**t)) + eps), 0.0)

    return jax.tree_util.tree_map(move, params, m, v), (m, v)


def adam(loss, params, steps: int, lr: float):
    """``steps`` Adam steps on ``loss(params)`` (a pytree of arrays) in one ``lax.scan``:
    ``(params, losses (steps,))``."""
    grad = jax.value_and_grad(loss)
    zeros = jax.tree_util.tree_map(jnp.zeros_like, params)

    def step(carry, t):
        p, state = carry
        val, g = grad(p)
        return adam_update(p, state, g, t, lr), val

    ts = jnp.arange(1, steps + 1, dtype=jax.tree_util.tree_leaves(params)[0].dtype)
    (p, _), losses = jax.lax.scan(step, (params, (zeros, zeros)), ts)
    return p, losses


def _check_steps(steps, lr):
    if int(steps) < 1 or not lr > 0:
        raise InputError(f"steps must be >= 1 and lr > 0, got steps={steps}, lr={lr}")


def fit_evidence(
    meas: Measurements,
    prior: Prior,
    init: FusedHyper,
    alpha=None,
    *,
    steps: int = 60,
    lr: float = 0.05,
    tau: float = 1.0,
    reference: str = "log",
) -> FusedHyper:
    """Per-material hyper-parameters by maximum evidence (module docstring).

    Args:
        meas: one measurement, or a stack ``(B, S, nmax)`` (each fitted on its own).
        prior: the prior.
        init: the start and centre of the hyper-prior (e.g. :func:`fit_population`'s result).
        alpha: slice offset α in radians (default 15°; scalar or ``(B,)``).
        steps, lr: Adam steps and step size (on the logs).
        tau: standard deviation of the hyper-prior on each log (``inf``: plain evidence).

    Returns:
        A :class:`FusedHyper` (stacked ``(B,)`` leaves for a stack).
    """
    _check_steps(steps, lr)
    if meas.t.ndim > 2:
        return each(
            lambda m, a: fit_evidence(
                m, prior, init, a, steps=steps, lr=lr, tau=tau, reference=reference
            ),
            meas,
            alpha,
            prior.dtype,
        )
    params, static = eqx.partition(init, eqx.is_array)
    basis = fused_basis(prior, meas, alpha, reference)  # once, not at every step

    def loss(p):
        h = eqx.combine(p, static)
        lml, n = evidence(meas, prior, h, alpha, reference=reference, basis=basis)
        dev = jax.tree_util.tree_map(lambda a, b: jnp.sum((a - b) ** 2), p, params)
        return -lml / n + 0.5 * sum(jax.tree_util.tree_leaves(dev)) / (tau**2 * n)

    p, _ = adam(loss, params, steps, lr)
    return eqx.combine(p, static)


def fit_population(
    tables,
    meas: Measurements,
    init: FusedHyper,
    *,
    folds: int = 6,
    steps: int = 40,
    lr: float = 0.05,
    k: int = 32,
    channels: str = "shared",
    eps: float = 1e-6,
    reference: str = "log",
    dtype=jnp.float32,
    log=None,
    prior: Prior | None = None,
) -> tuple[FusedHyper, list[float]]:
    """One set of hyper-parameters for a population, by gradient descent on held-out ΔE76.

    Args:
        tables: ``(N, 81, 81, 3)`` training tables (the dense truth of the held-out losses).
        meas: stacked ``Measurements`` ``(N, S, nmax)`` of the same materials in one layout.
        init: start hyper-parameters (their coordinates and kernel are kept).
        folds: number of folds (material ``j`` is held out in fold ``j % folds``).
        steps, lr: Adam steps and step size on the logs.
        k, channels, eps: the fold priors' settings (:func:`~abrdf_jax.prior.train_prior`).
        log: optional ``print``-like callable (the loss every 10 steps).
        prior: a prior trained on none of ``tables`` (e.g. the default prior, on measured
            tables): every material is then already held out, so no folds: the loss is the
            mean ΔE76 of all of them with this prior (``folds``, ``k``, ``channels``, ``eps``
            unused).

    Returns:
        ``(hyper, losses)``: the fitted :class:`FusedHyper` and the mean held-out ΔE76 per step
        (at the parameters before that step).
    """
    from ..metrics import delta_e76

    _check_steps(steps, lr)
    tables = np.asarray(tables, np.float32)
    n = len(tables)
    if not (prior is not None or 2 <= folds <= n) or meas.t.shape[0] != n:
        raise InputError(
            f"fit_population: {n} tables, {meas.t.shape[0]} measurements, {folds} folds"
        )
    fold = np.arange(n) % folds
    split = [] if prior is None else [(prior, meas, jnp.asarray(tables))]
    for f in range(folds if prior is None else 0):
        te = np.flatnonzero(fold == f)
        kf = min(k, 3 * (n - len(te)) - 1 if channels == "shared" else n - len(te) - 1)
        prior = train_prior(tables[fold != f], k=kf, channels=channels, eps=eps, dtype=dtype)
        m = jax.tree_util.tree_map(lambda x: x[te], meas)
        split.append((prior, m, jnp.asarray(tables[te])))
    # The prior at each material's samples does not depend on the hyper-parameters: computed
    # once here, not at every step (the default prior's exact basis evaluates its training
    # draws there, by far the largest part of a step's program).
    bases = eqx.filter_jit(fused_bases)
    split = [(p_, m, ref, bases(p_, m, None, reference)) for p_, m, ref in split]
    params, static = eqx.partition(init, eqx.is_array)

    def loss(p, split):  # the data as an argument: closed-over arrays would be constant-folded
        h = eqx.combine(p, static)
        total = 0.0
        for prior, m, ref, basis in split:
            rec = reconstruct_fused(m, prior, h, reference=reference, basis=basis)
            total = total + jnp.sum(jax.vmap(delta_e76)(rec, ref))
        return total / n

    grad = eqx.filter_jit(jax.value_and_grad(loss))
    update = eqx.filter_jit(adam_update)
    zeros = jax.tree_util.tree_map(jnp.zeros_like, params)
    state, losses, best = (zeros, zeros), [], (np.inf, params)
    for i in range(steps):
        val, g = grad(params, split)
        losses.append(float(val))
        if losses[-1] < best[0]:
            best = (losses[-1], params)
        if log and i % 10 == 0:
            log(f"  population step {i}: held-out dE76 {losses[-1]:.4f}")
        params, state = update(params, state, g, i + 1.0, lr)
    return eqx.combine(best[1], static), losses
