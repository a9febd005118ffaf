"""Model selection for many measurements at once (a folder of files): :func:`select_models`.

The per-material steps are :mod:`abrdf_jax.select._select`'s (grouping, the isotropy test, the
candidate list, the tolerance rule); only the held-out errors are computed for a whole group of
one fold layout at once.
"""

from __future__ import annotations

import time

import jax
import jax.numpy as jnp
import numpy as np

from .._params import Params
from ._isotropy import LEVEL, MIN_EFFECT
from ._choice import rbf_configs, with_prior
from ._dense_held_out import dense_layout_plan, plan_errors
from ._select import TOL, Selection, _finish, _plan, fold_data, group_configs, held_out_errors_batch

#: Materials per held-out call (the last chunk of a group is padded: one compile per layout).
BATCH = 16


def select_models(
    measurements,
    *,
    budget: str | None = None,
    tol: float = TOL,
    k: int = 4,
    noise: float | None = None,
    level: float = LEVEL,
    min_effect: float = MIN_EFFECT,
    alpha_deg=None,
    on_done=None,
    prior=None,
    fused=True,
) -> list[Selection]:
    """:func:`select_model` (``candidates="auto"``) for many measurements, with the held-out
    errors of every group of one fold layout, α and candidate list computed in one compiled,
    vmapped call (:func:`held_out_errors_batch`) instead of one call per material: the same
    choices, errors equal to float rounding. Dense captures' candidates affine in the slice
    terms are scored in numpy, float64, all captures of one pair layout at once
    (:func:`abrdf_jax.select._dense_held_out.plan_errors`), as :func:`select_model` does.

    Args:
        measurements: :class:`Measurements` (or :class:`Samples`), one per material.
        alpha_deg: ``None``, one α for all, or one per measurement.
        on_done: called with the number of materials when a group is done (a progress bar).
        prior: a :class:`abrdf_jax.prior.Prior` joining the candidates, as in
            :func:`select_model` (its held-out errors batched the same way).
        fused: the fused candidate, as in :func:`select_model`.

    Returns:
        One :class:`Selection` per measurement, in order (``seconds``: its share of the batch).
    """
    t0 = time.perf_counter()
    items = list(measurements)
    alphas = alpha_deg if isinstance(alpha_deg, (list, tuple)) else [alpha_deg] * len(items)
    plans = [
        _plan(m, "auto", budget, noise, level, min_effect, a, None) for m, a in zip(items, alphas)
    ]
    from ._fused import fused_of

    fh = fused_of(prior, fused)
    if prior is not None:
        plans = [with_prior(p, fh is not None) for p in plans]
    errors: dict[int, dict] = {}
    dense = [i for i, p in enumerate(plans) if len(p.configs) > 1 and dense_layout_plan(p)]
    for i, err in zip(dense, plan_errors([plans[i] for i in dense], k)):  # numpy, float64
        if err is not None:
            errors[i] = err
    groups: dict[tuple, list[int]] = {}
    for i, p in enumerate(plans):
        if len(p.configs) > 1 and (i not in errors or prior is not None):
            m = p.meas
            key = (m.pairs, m.has_axial, m.centre_azimuths, m.t.shape, tuple(np.asarray(m.count)))
            groups.setdefault((key, p.alpha, tuple(p.configs)), []).append(i)
    for (_, alpha, _), members in groups.items():
        for start in range(0, len(members), BATCH):
            chunk = members[start : start + BATCH]
            if not all(i in errors for i in chunk):  # (a dense capture's: made above)
                _rbf_errors(plans, chunk, alpha, k, errors)
            if prior is not None:
                _prior_errors(plans, chunk, alpha, k, prior, errors, fh)
            if on_done is not None:
                on_done(len(chunk))
    share = (time.perf_counter() - t0) / max(len(items), 1)
    out = [_finish(p, errors.get(i), tol, k, share) for i, p in enumerate(plans)]
    if on_done is not None:
        on_done(len(items) - sum(len(m) for m in groups.values()))
    return out


def _rbf_errors(plans, chunk, alpha, k, errors) -> None:
    """The RBF candidates' held-out errors of one chunk, in one padded batch per kernel group
    (one compile per layout)."""
    data = [fold_data(plans[i].meas, np.deg2rad(alpha), k) for i in chunk]
    data += [data[-1]] * (BATCH - len(chunk))  # one shape: one compile per layout
    stacked = jax.tree_util.tree_map(lambda *x: jnp.stack(x), *data)
    for names, cfgs in group_configs(rbf_configs(plans[chunk[0]].configs)):
        dtype = plans[chunk[0]].meas.y.dtype
        params = Params.default(cfgs[0], alpha_deg=alpha, dtype=dtype)
        errs = np.asarray(held_out_errors_batch(stacked, cfgs, params))
        for row, i in zip(errs, chunk):
            errors.setdefault(i, {}).update({n: float(e) for n, e in zip(names, row)})


def _prior_errors(plans, chunk, alpha, k, prior, errors, fh=None) -> None:
    """The prior's (and with ``fh`` the fused model's) held-out errors of one chunk, in one
    padded batch (one compile per layout)."""
    from ._fused import fused_held_out_errors
    from ._prior import prior_fold_data, prior_held_out_errors_batch

    budget = plans[chunk[0]].configs["prior"].budget
    data = [prior_fold_data(plans[i].meas, np.deg2rad(alpha), k, budget) for i in chunk]
    fused = None if fh is None else fused_held_out_errors(data, prior, fh[0], fh[1]["reference"])
    data += [data[-1]] * (BATCH - len(chunk))
    stacked = jax.tree_util.tree_map(lambda *x: jnp.stack(x), *data)
    errs = {"prior": np.asarray(prior_held_out_errors_batch(stacked, prior, prior.lam))}
    if fused is not None:
        errs["fused"] = np.asarray(fused)
    for name, row in errs.items():
        for e, i in zip(row, chunk):
            errors.setdefault(i, {})[name] = float(e)
