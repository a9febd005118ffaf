"""The held-out errors of model selection on dense captures, in numpy: ``--model auto`` of a
continuous capture without JAX.

A dense capture (hundreds or thousands of samples a slice, ``meas.centre_azimuths`` set) has
its RBF at denser centres (2,304 for the protocol's pairs) and a layout of its own (every
capture's encoder angles differ), so the held-out entries of sparse layouts
(:mod:`abrdf_jax.select._held_out_entry`: a matrix per fold on the sample slots, built once per
layout and stored) do not pay: their matrices would have a column per sample and serve one
file. The fits are computed here instead, as the JAX path computes them
(:func:`abrdf_jax.select._select._cv_core`), for the candidates the entries take (subspace
rules affine in the slice terms, no log after the rule): per fold ``j`` the training samples'
values (log with the fold's ε, slice smoothing and spike cap on the fold's own slices), every
candidate rule's subspaces at the centres (:func:`abrdf_jax._subspace.centre_subspaces`), then
*one* RBF solve for every fold, rule, channel and input, since the centres' system does not
depend on where the samples lie (the same reason a dense capture's second stage is shared:
:mod:`abrdf_jax._centre_step`), read at each fold's held-out directions.

In float64: the errors equal the JAX path's run in float64 to 1e-8
(tests/test_dense_held_out.py). The JAX path runs float32 by default, and its solve on 2,304
centres is not accurate there (a scratch comparison on one 300-a-slice capture:
docs/notes.md), so a choice near
the tolerance may differ from the one that path made; this one is the more accurate.

The same fits serve, on the command line, every sparse layout no stored held-out entry serves:
a folder of jittered captures (a layout each) beyond the small-layout rule
(:func:`abrdf_jax.select._held_out_entry.direct_selections`; on the UBO centres the solve is
the 1,296-centre system's, its map 1,311 × 1,296 float64): one shared map for the folder,
where the JAX path compiled per layout. This module imports numpy only.
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np

from .._config import Config, default_values, resolve_degree
from .._coords import pair_coordinates
from .._folds import fold_slots, gather, held_out_directions, log_residual
from .._host_build import sample_index, template_layout
from .._host_eps import sample_eps
from .._kernels import kernel_block
from .._names import LOG_SAMPLES, LOG_SUBSPACE
from .._protocol import on_ubo_rings
from .._grid import centre_count, centre_vectors
from .._rbf_system import blocks, centre_stats, combine, coordinate_widths, host_solve, poly
from .._rules import AFFINE
from .._smoothing import smooth_compact
from .._spikes import cap_samples
from .._centre_batch import centre_subspaces_many
from .._subspace import centre_subspaces
from ._choice import entry_groups, rbf_configs


#: Captures whose fits :func:`dense_errors` makes at once (a capture's right-hand sides are
#: 2,304 × 48 float64 for the default anisotropic candidates: 0.9 MB).
CHUNK = 64
#: Captures of pairs off the UBO rings (``_protocol.on_ubo_rings``: a device's own levels, which
#: a later call may not see again) that make a stored coefficient map worth building (it costs
#: about three solves; below, one solve each).
MAP_MIN_GROUP = 4


def affine_plan(p) -> bool:
    """Whether a selection plan's RBF candidates are affine in the slice terms
    (:mod:`abrdf_jax._rules`) with no log after the rule, every diagonal slice measured: the
    candidates whose held-out fits numpy computes (here, and as the stored matrices of
    :mod:`abrdf_jax.select._held_out_entry` on sparse layouts)."""
    count = np.asarray(p.meas.count)
    return bool(np.all(count[1::2] > 0)) and all(
        isinstance(c, Config) and c.subspace_rule in AFFINE and c.value_space not in LOG_SUBSPACE
        for c in rbf_configs(p.configs).values()
    )


def dense_layout_plan(p) -> bool:
    """:func:`affine_plan` on a dense layout (``centre_azimuths`` set): :func:`plan_errors`."""
    return p.meas.centre_azimuths is not None and affine_plan(p)


def plan_errors(plans, k: int, store=None, warn=None) -> list[dict | None]:
    """The RBF candidates' held-out errors ``{name: error}`` of every plan of
    :func:`dense_layout_plan` (the learned candidates' are not here), by :func:`dense_errors`:
    the plans of one elevation-pair and centre layout and candidate list share a solve (a stored
    coefficient map with ``store``); ``None`` for a group whose
    RBF system stays singular after the guard (the JAX path then reports it)."""
    groups: dict = {}
    for i, p in enumerate(plans):
        key = (_pairs(p.meas), p.meas.centre_azimuths, tuple(p.configs))
        groups.setdefault(key, []).append(i)
    out: list[dict | None] = [{} for _ in plans]
    for (pairs, _, _), members in groups.items():
        # a stored map serves pairs that other captures share (the UBO rings') or a group of
        # several; else one solve with the values costs less (no map of a capture's own pairs)
        keep = store if on_ubo_rings(pairs) or len(members) >= MAP_MIN_GROUP else None
        try:
            for names, cfgs in entry_groups(rbf_configs(plans[members[0]].configs)):
                found = dense_errors(
                    [plans[i].meas for i in members],
                    [np.asarray(plans[i].meas.y) for i in members],
                    [plans[i].alpha for i in members],
                    cfgs,
                    k,
                    keep,
                    warn,
                )
                for i, err in zip(members, found):
                    out[i].update({n: float(e) for n, e in zip(names, err)})
        except np.linalg.LinAlgError:
            for i in members:
                out[i] = None
    return out


def dense_errors(metas, ys, alphas_deg, cfgs, k: int, store=None, warn=None) -> np.ndarray:
    """RMS held-out log errors ``(N, G)`` of the configurations ``cfgs`` (one kernel group and
    slice interpolation, :func:`abrdf_jax.select._choice.entry_groups`) on ``N``
    dense measurements.

    Args:
        metas: the grouped measurements (each its own layout; the same elevation pairs and
            centre azimuths: one RBF system for all).
        ys: each measurement's values ``(S, nmax, C)`` (its own ``nmax``).
        alphas_deg: each measurement's slice offset α in degrees.
        cfgs: the configurations, differing in the subspace rule only.
        k: the number of folds (:func:`abrdf_jax._folds.fold_slots`).
        store: an operator store (``abrdf_jax._cache``) that keeps the system's
            :class:`CentreMap` (built on a miss); ``None``: one solve with the values instead.
        warn: the store's warnings (a bad entry, an unwritable folder).

    Raises:
        numpy.linalg.LinAlgError: the RBF system stays singular after the guard (the caller
            takes the JAX path, whose guard reports it).
    """
    cfg = cfgs[0]
    pairs, azimuths = metas[0].pairs, metas[0].centre_azimuths
    rules = tuple(c.subspace_rule for c in cfgs)
    values = default_values(cfg, float(alphas_deg[0]), dtype="float64")
    name, kernel = cfg.parameterization, cfg.kernel
    xc = pair_coordinates(*centre_vectors(pairs, np.float64, azimuths, np), name, np)
    widths = coordinate_widths(np.asarray(values.widths, np.float64), xc.shape[1], np)
    degree = resolve_degree(kernel, cfg.degree)
    shift, scale = centre_stats(xc, np)
    reg = np.float64(np.asarray(values.reg))

    @functools.cache
    def system():  # the centres' Gram matrix and tail: made once, only to solve or build
        return (*blocks(xc, widths, kernel, max(degree, -1), shift, scale, np), reg)

    coef = None if store is None else _stored_map(store, warn, cfg, values, metas[0], system)
    out = []
    for at in range(0, len(metas), CHUNK):
        part = slice(at, at + CHUNK)
        folds = [
            _Folds(m, y, a, cfg, rules, k)
            for m, y, a in zip(metas[part], ys[part], alphas_deg[part])
        ]
        _set_centre_values(folds, pairs, azimuths, rules, cfg.interp)
        # every input's every fold, rule and channel: the columns of one solve
        rhs = np.concatenate([f.centre_values for f in folds], axis=1)
        if coef is None:
            coeffs, tail, _ = host_solve(*system(), rhs)
        else:
            n = xc.shape[0]
            coeffs, tail = coef.coef[:n] @ rhs, coef.coef[n:] @ rhs
        col = 0
        for f in folds:
            width = f.centre_values.shape[1]
            xq = pair_coordinates(f.wi, f.wv, name, np)
            kq = kernel_block(xq, xc, widths, kernel, np)
            pq = poly(xq, shift, scale, degree, np) if degree >= 0 else None
            pred = combine(kq, pq, coeffs[:, col : col + width], tail[:, col : col + width], np)
            out.append(f.errors(pred))
            col += width
    return np.stack(out)


def fold_layout(t, train_j) -> tuple:
    """Fold ``j``'s training layout: the flat slots ``cols`` of its training samples in its own
    padded layout, its slice positions ``(S, nmax)`` (0 where a slice ends) and counts."""
    cols = np.flatnonzero(train_j.reshape(-1) >= 0)
    return cols, np.where(train_j >= 0, t.reshape(-1)[train_j], 0), (train_j >= 0).sum(-1)


def log_training_values(x, layout, log_eps: float, smoothing, cap):
    """A fold's training values ``x`` ``(B, n_train, C)`` as the log-sample value space fits
    them (``abrdf_jax._pipeline``'s fit inputs): the log with the fold's own ε, the slice
    smoothing on the fold's slices (``layout``: :func:`fold_layout`) and the spike cap;
    ``(values, ε (B, C))``. The held-out entries' errors and the direct fits share it."""
    eps = sample_eps(x, log_eps, axis=1)
    x = np.log(np.maximum(x, 0.0) + eps[:, None, :])
    if smoothing is not None:
        x = smooth_compact(smoothing, x, *layout, np)
    if cap:
        x = cap_samples(x, cap, xp=np)
    return x, eps


class _Folds:
    """One measurement's ``k`` folds: the centre values each fold's training samples give under
    every rule (``centre_values`` ``(n_c, k · R · C)``) and its held-out samples' directions
    ``wi``, ``wv`` ``(Σ_j q_j, 3)``, values and ε (module docstring)."""

    def __init__(self, meas, y, alpha_deg: float, cfg: Config, rules: tuple, k: int):
        t, count = template_layout(meas)
        t = t.astype(np.float64)
        s, nmax = t.shape
        c = y.shape[-1]
        alpha = np.deg2rad(np.float64(alpha_deg))
        pairs = _pairs(meas)
        flat = np.asarray(y, np.float64).reshape(s * nmax, c)
        log_samples = cfg.value_space in LOG_SAMPLES
        valid = flat[sample_index(t, count)][None]
        self.res_eps = sample_eps(valid, Config().log_eps, axis=1)[0]  # (C,)
        train, test = fold_slots(count, nmax, k)
        self.eps, self.held, self.sizes = [], [], []
        wis, wvs, slices = [], [], []
        for j in range(k):
            cols, fold_t, fold_count = fold_layout(t, train[j])
            x = flat[train[j].reshape(-1)[cols]][None]  # (1, n_train, C)
            eps = None
            if log_samples:
                x, eps = log_training_values(
                    x, (cols, fold_t, fold_count), cfg.log_eps, cfg.slice_smoothing, cfg.spike_cap
                )
            padded = np.zeros((s * nmax, c))
            padded[cols] = x[0]
            slices.append((fold_t, padded.reshape(s, nmax, c), fold_count))
            rows = np.flatnonzero(test[j].reshape(-1) >= 0)
            held_t = gather(t, test[j])
            wi, wv = held_out_directions(held_t, pairs, alpha, np)
            wis.append(wi[rows])
            wvs.append(wv[rows])
            self.held.append(flat[test[j].reshape(-1)[rows]])  # (q_j, C)
            self.eps.append(None if eps is None else eps[0])
            self.sizes.append(rows.size)
        self.slices, self.alpha = slices, alpha  # each fold's (t, y, count): the centre values
        self.centre_values = None  # (n_c, k · R · C): _set_centre_values, all folds at once
        self.wi, self.wv = np.concatenate(wis), np.concatenate(wvs)
        self.n_rules, self.k = len(rules), k

    def errors(self, pred) -> np.ndarray:
        """The RMS held-out log error ``(R,)`` of every rule from the RBF's values ``pred``
        ``(Σ_j q_j, k · R · C)`` at every fold's held-out directions (a fold reads its own)."""
        r_, c = self.n_rules, self.held[0].shape[-1]
        total, n, at = np.zeros(r_), 0, 0
        for j, (q, held, eps) in enumerate(zip(self.sizes, self.held, self.eps)):
            mine = pred[at : at + q].reshape(q, self.k, r_, c)[:, j]  # (q, R, C)
            if eps is not None:
                mine = np.exp(mine) - eps[None, None, :]
            res = log_residual(mine, held[:, None, :], self.res_eps, True, xp=np)
            total += np.sum(np.square(res), axis=(0, 2))
            n += q * c
            at += q
        return np.sqrt(total / max(n, 1))


def _set_centre_values(folds, pairs, azimuths, rules: tuple, interp: str) -> None:
    """Each fold's subspaces at the RBF centres under every rule (``_Folds.centre_values``
    ``(n_c, k · R · C)``) of inputs of one elevation-pair and centre layout: every fold of every
    input in one pass where the slices are read linearly and the rules are affine
    (:func:`abrdf_jax._centre_batch.centre_subspaces_many`, the values of one fold at a time:
    slices padded to the longest, which the counts leave out), else fold by fold."""
    rows = [(f.alpha, *sl) for f in folds for sl in f.slices]
    if interp == "linear" and all(r in AFFINE for r in rules):
        nmax = max(t.shape[-1] for _, t, _, _ in rows)

        def pad(a):  # (S, n, ...) -> (S, nmax, ...)
            return np.pad(a, [(0, 0), (0, nmax - a.shape[1])] + [(0, 0)] * (a.ndim - 2))

        t, y = (np.stack([pad(r[i]) for r in rows]) for i in (1, 2))
        count = np.stack([r[3] for r in rows])
        alpha = np.array([r[0] for r in rows])
        vals = centre_subspaces_many(t, y, count, pairs, azimuths, alpha, rules)
    else:
        vals = [
            centre_subspaces(t, y, n, pairs, azimuths, a, rules, interp, xp=np)
            for a, t, y, n in rows
        ]
    at = 0
    for f in folds:
        mine = vals[at : at + len(f.slices)]
        at += len(f.slices)
        f.centre_values = np.concatenate(
            [np.transpose(v, (1, 0, 2)).reshape(v.shape[1], -1) for v in mine], axis=1
        )
        f.slices = None


def _pairs(meas) -> tuple:
    """The measurement's elevation pairs as a tuple of float pairs."""
    return tuple(tuple(float(v) for v in p) for p in meas.pairs)


@dataclasses.dataclass(frozen=True, eq=False)
class CentreMap:
    """The RBF's coefficients as a map of the values at one centre layout: ``coef`` ``(n + m,
    n)`` float64, ``A⁻¹ [I; 0]`` of the system ``A`` (:mod:`abrdf_jax._rbf_system`, λ the
    guard's), its ``m`` tail rows unscaled (as :func:`abrdf_jax._rbf_system.evaluate` reads
    them). It depends on the elevation pairs, the centres' layout and the kernel's setting, not
    on the samples: the operator store keeps one per setting, and a dense capture's held-out
    fits are a product with it, without the Gram matrix and the factorisation of a solve."""

    coef: np.ndarray

    KIND = "centre-map"
    ARRAYS = ("coef",)

    def arrays(self) -> dict[str, np.ndarray]:
        return {"coef": self.coef}

    def meta(self) -> dict:
        return {}

    @classmethod
    def from_stored(cls, arrays: dict[str, np.ndarray], meta: dict) -> "CentreMap":
        return cls(arrays["coef"])

    @staticmethod
    def check(arrays: dict[str, np.ndarray], meta: dict) -> str | None:
        """What is wrong with stored arrays (``None``: nothing)."""
        coef = arrays["coef"]
        if coef.dtype != np.float64 or coef.ndim != 2 or coef.shape[0] < coef.shape[1]:
            return "malformed (not a centre map)"
        if not np.all(np.isfinite(coef)):
            return "malformed (values not finite)"
        return None


def _stored_map(store, warn, cfg, values, meas, system) -> CentreMap:
    """The :class:`CentreMap` of ``cfg``'s kernel setting on ``meas``'s centres from ``store``,
    else built from ``system()`` (the blocks ``K``, ``P``, their scale and λ) and stored."""
    from .. import _cache

    key = _cache.operator_key(cfg, values, meas, centres=True, extra={"kind": CentreMap.KIND})
    found = store.load(key, warn, kind=CentreMap)
    n = centre_count(meas.pairs, meas.centre_azimuths)
    if found is not None and found.coef.shape[1] == n:
        return found
    coeffs, tail, _ = host_solve(*system(), np.eye(n))  # A⁻¹ [I; 0], the tail unscaled
    entry = CentreMap(np.ascontiguousarray(np.concatenate([coeffs, tail])))
    store.save(key, entry, warn)
    return entry
