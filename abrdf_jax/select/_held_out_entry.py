"""The held-out errors of model selection as numpy matrices: ``--model auto`` without JAX.

For candidates whose subspace rule is affine in the slice terms (:mod:`abrdf_jax._rules`: every
rule but the multiplicative one, ``"filip2012"`` included) in a value space without a log after
the rule (the recommended ``"logsamples"``), on a sparse centre layout, the held-out prediction of
fold ``j`` is ``Σ_p Σ_t coef_pt · T_jpt · z + const_p · 1_jp``: matrices ``T_jpt`` of the RBF fit of
pair ``p``'s slice term ``t`` (``a``, ``b``, ``c``) applied to fold ``j``'s training samples ``z``
(spike-capped log samples), and the rule's coefficients, numbers or functions of the slices'
sample extremes, computed here in numpy. :class:`HeldOutEntry` holds those matrices for one
layout, α, kernel group, slice interpolation and fold count, built once by
:func:`abrdf_jax.select._select.held_out_terms` (the held-out fits' own linear parts, in
float64, stored float32) and kept in the operator store
(``abrdf_jax._cache``) beside the reconstruction operators, so a warm ``abrdf-jax reconstruct``
of anisotropic captures imports no JAX. Its errors equal :func:`~abrdf_jax.select.held_out_errors`
to float32 rounding (tests/test_held_out_entry.py). This module imports numpy only.
"""

from __future__ import annotations

import dataclasses
import functools
import time

import numpy as np

from .._config import Config, default_values
from .._errors import InputError
from .._names import LOG_SAMPLES
from .._folds import fold_slots, log_residual
from .._host_eps import sample_eps
from .._operator_entry import check_layout
from .. import _engine
from .._rules import AFFINE, combine
from .._smoothing import smoothing_from_json, smoothing_to_json
from ._candidates import LEARNED
from ._dense_held_out import affine_plan, fold_layout, log_training_values, plan_errors
from ._choice import entry_groups, finish, plan, rbf_configs, with_prior
from ._learned_entry import cached_entry as learned_entry
from ._learned_entry import learned_model

#: Inputs of one layout (α, candidates) that make a held-out entry worth building in a call of
#: several with many layouts: the reconstruction operators' threshold and rule
#: (``abrdf_jax._engine.plan_job``: a call of few layouts builds an entry for each); a
#: single file passes 1.
MIN_GROUP = _engine.OPERATOR_MIN_GROUP


@dataclasses.dataclass(frozen=True, eq=False)
class HeldOutEntry:
    """The held-out fits of one kernel group on one layout as matrices (module docstring).

    Attributes:
        terms: ``(k, P, 3, q, S·nmax)`` float32: fold ``j``'s prediction (RBF value space) at
            its held-out slots from pair ``p``'s slice term ``a``/``b``/``c``, as a matrix on the
            values at its training slots.
        ones: ``(k, P, q)`` float32: the prediction from the constant 1 at pair ``p``'s centres.
        train, test: ``(k, S, nmax)`` / ``(k, S, ⌈nmax/k⌉)`` int64 flat slots of the samples each
            fold trains on / holds out (``abrdf_jax._folds.fold_slots``; ``-1``: none).
        t, count: the template's layout (checked against the inputs).
        names, rules: the configurations' names and subspace rules, in the order of the errors.
        log_samples, log_eps, spike_cap, slice_smoothing: the group's value space, ε, spike
            cap and slice smoothing (``abrdf_jax._smoothing``; both act on log samples only).
        res_log_eps: the ε of the held-out residual (``Config().log_eps``, as the JAX path).
    """

    terms: np.ndarray
    ones: np.ndarray
    train: np.ndarray
    test: np.ndarray
    t: np.ndarray
    count: np.ndarray
    names: tuple
    rules: tuple
    log_samples: bool
    log_eps: float
    res_log_eps: float
    spike_cap: tuple | None = None
    slice_smoothing: float | tuple | None = None

    KIND = "held-out"
    ARRAYS = ("terms", "ones", "train", "test", "t", "count")

    def errors(self, y) -> np.ndarray:
        """RMS held-out log errors ``(B, G)`` of stacked sample values ``(B, S, nmax, C)``."""
        y = np.asarray(y, np.float32)
        s, nmax = self.t.shape
        b, c = y.shape[0], y.shape[-1]
        flat = y.reshape(b, s * nmax, c)
        valid = (np.arange(nmax)[None, :] < self.count[:, None]).reshape(-1)
        res_eps = sample_eps(flat[:, valid], self.res_log_eps, axis=1)
        total = np.zeros((b, len(self.names)))
        n = 0
        for j in range(self.terms.shape[0]):
            layout = fold_layout(self.t, self.train[j])
            cols = layout[0]
            rows = np.flatnonzero(self.test[j].reshape(-1) >= 0)
            x = flat[:, self.train[j].reshape(-1)[cols]]  # (B, n_train, C)
            eps = None
            if self.log_samples:  # (B, C): the fold's ε, its own slices
                x, eps = log_training_values(
                    x, layout, self.log_eps, self.slice_smoothing, self.spike_cap
                )
            m = self.terms[j][:, :, rows][..., cols]  # (P, 3, q_j, n_train)
            # one GEMM: (P·3·q_j, n_train) @ (n_train, B·C)
            terms = m.reshape(-1, cols.size) @ x.transpose(1, 0, 2).reshape(cols.size, -1)
            terms = terms.reshape(*m.shape[:3], b, c).transpose(3, 0, 1, 2, 4)  # (B, P, 3, q, C)
            ext = _Extremes(x, cols // nmax)
            ones = self.ones[j][None, :, rows, None]  # (1, P, q_j, 1)
            held = flat[:, self.test[j].reshape(-1)[rows]]  # (B, q_j, C)
            for g, rule in enumerate(self.rules):
                pred = np.sum(self._rule_fit(rule, ext, terms, ones), axis=1)  # (B, q_j, C)
                if eps is not None:
                    pred = np.exp(pred) - eps[:, None, :]
                r = log_residual(pred, held, res_eps[:, None, :], True, xp=np)
                total[:, g] += np.sum(np.square(r, dtype=np.float64), axis=(1, 2))
            n += rows.size * c
        return np.sqrt(total / max(n, 1))

    def _rule_fit(self, rule: str, ext, terms, ones):
        """Each pair's part of the held-out prediction under ``rule`` ``(B, P, q, C)``; a pair
        without an axial slice takes its diagonal slice (as ``abrdf_jax._subspace.subspace``)."""
        has_axial = (self.count[0::2] > 0)[None, :, None, None]
        out = combine(
            AFFINE[rule](ext),
            lambda: terms[:, :, 0],
            lambda: terms[:, :, 1],
            lambda: terms[:, :, 2],
            one=lambda: ones,  # the RBF's fit of a constant at the pair's centres
        )
        return np.where(has_axial, out, terms[:, :, 1])

    def arrays(self) -> dict[str, np.ndarray]:
        return {name: getattr(self, name) for name in self.ARRAYS}

    def meta(self) -> dict:
        cap = None if self.spike_cap is None else [float(v) for v in self.spike_cap]
        return {
            "names": list(self.names),
            "rules": list(self.rules),
            "log_samples": bool(self.log_samples),
            "log_eps": float(self.log_eps),
            "res_log_eps": float(self.res_log_eps),
            "spike_cap": cap,
            "slice_smoothing": smoothing_to_json(self.slice_smoothing),
        }

    @classmethod
    def from_stored(cls, arrays: dict[str, np.ndarray], meta: dict) -> "HeldOutEntry":
        cap = meta.get("spike_cap")
        return cls(
            **arrays,
            names=tuple(meta["names"]),
            rules=tuple(meta["rules"]),
            log_samples=meta["log_samples"],
            log_eps=meta["log_eps"],
            res_log_eps=meta["res_log_eps"],
            spike_cap=None if cap is None else tuple(cap),
            slice_smoothing=smoothing_from_json(meta.get("slice_smoothing")),
        )

    @staticmethod
    def check(arrays: dict[str, np.ndarray], meta: dict) -> str | None:
        """What is wrong with stored arrays and scalars (``None``: nothing)."""
        terms, ones, train, test, t = (arrays[n] for n in ("terms", "ones", "train", "test", "t"))
        names, rules = meta.get("names"), meta.get("rules")
        index = np.flatnonzero(np.arange(t.shape[-1])[None, :] < arrays["count"][:, None])
        problem = check_layout({**arrays, "index": index}, index.size) if t.ndim == 2 else "bad t"
        if (
            problem
            or terms.dtype != np.float32
            or ones.dtype != np.float32
            or terms.ndim != 5
            or terms.shape[2] != 3
            or ones.shape != (terms.shape[0], terms.shape[1], terms.shape[3])
            or terms.shape[1] * 2 != t.shape[0]
            or terms.shape[4] != t.size
            or train.shape != (terms.shape[0], *t.shape)
            or test.shape[:2] != (terms.shape[0], t.shape[0])
            or terms.shape[3] != test.shape[1] * test.shape[2]
            or max(train.max(initial=-1), test.max(initial=-1)) >= t.size
        ):
            return "malformed (inconsistent array shapes)"
        if not (
            isinstance(names, list)
            and isinstance(rules, list)
            and len(names) == len(rules)
            and all(r in AFFINE for r in rules)
        ):
            return "malformed (names or rules)"
        if not all(isinstance(meta.get(f), float) for f in ("log_eps", "res_log_eps")):
            return "malformed (no value space)"
        return None


class _Extremes:
    """Each pair's slice extremes of one fold's training values ``x`` ``(B, n, C)`` (``slices``:
    the slice of each value), ``(B, P, 1, C)``: the ``extremes`` of :mod:`abrdf_jax._rules`."""

    xp = np

    def __init__(self, x, slices):
        n_slices = int(slices.max(initial=-1)) + 1
        n_slices += n_slices % 2
        on = slices[None, :] == np.arange(n_slices)[:, None]  # (S, n)
        big = np.float32(np.inf)
        with np.errstate(invalid="ignore"):
            lo = np.min(np.where(on[None, :, :, None], x[:, None], big), axis=2)  # (B, S, C)
            hi = np.max(np.where(on[None, :, :, None], x[:, None], -big), axis=2)
        # a slice without values (an axial slice not measured) takes a neutral 0: its pair
        # reads the diagonal slice alone (HeldOutEntry._rule_fit)
        lo, hi = np.where(np.isfinite(lo), lo, 0), np.where(np.isfinite(hi), hi, 0)
        self.amin, self.dmin = lo[:, 0::2, None], lo[:, 1::2, None]
        self.amax, self.dmax = hi[:, 0::2, None], hi[:, 1::2, None]


def _key(cfgs, names, params, meas, k: int) -> str:
    from .. import _cache

    extra = {
        "kind": HeldOutEntry.KIND,
        "k": k,
        "names": list(names),
        "configs": [_cache.config_doc(c) for c in cfgs],
    }
    return _cache.operator_key(cfgs[0], params, meas, extra=extra)


def build_entry(meas, alpha_deg: float, names, cfgs, k: int, before_jax=None) -> HeldOutEntry:
    """Build the entry of one kernel group and slice interpolation (the matrices in float64
    numpy, :func:`abrdf_jax._host_build.host_held_out_terms`; in JAX only where the RBF system
    stays singular after the guard, ``before_jax()`` first)."""
    from .._host_build import host_held_out_terms

    try:
        values = default_values(cfgs[0], alpha_deg, dtype="float64")
        terms, ones = host_held_out_terms(meas, cfgs[0], values, k)
    except np.linalg.LinAlgError:  # the JAX build's guard reports it
        if before_jax is not None:
            before_jax()
        terms, ones = _jax_terms(meas, alpha_deg, cfgs, k)
    train, test = fold_slots(np.asarray(meas.count), meas.t.shape[-1], k)
    log_samples = cfgs[0].value_space in LOG_SAMPLES
    return HeldOutEntry(
        terms=np.ascontiguousarray(terms.astype(np.float32)),
        ones=np.ascontiguousarray(ones.astype(np.float32)),
        train=train,
        test=test,
        t=np.asarray(meas.t, np.float32),
        count=np.asarray(meas.count, np.int32),
        names=tuple(names),
        rules=tuple(c.subspace_rule for c in cfgs),
        log_samples=log_samples,
        log_eps=float(cfgs[0].log_eps),
        res_log_eps=float(Config().log_eps),
        spike_cap=cfgs[0].spike_cap if log_samples else None,
        slice_smoothing=cfgs[0].slice_smoothing if log_samples else None,
    )


def _jax_terms(meas, alpha_deg: float, cfgs, k: int):
    """:func:`abrdf_jax.select._select.held_out_terms` in float64 JAX."""
    import jax.numpy as jnp

    from .. import _cache
    from .._engine import as_jax
    from .._grid import centre_layout
    from .._params import Params
    from ._select import fold_data, held_out_terms

    meas, _ = as_jax(meas, None)
    centres = tuple(len(pi_) for pi_, _ in centre_layout(meas.pairs, meas.centre_azimuths))
    with _cache.x64_scope(True):
        m64 = meas.replace(t=jnp.asarray(meas.t, jnp.float64), y=jnp.asarray(meas.y, jnp.float64))
        data = fold_data(m64, np.deg2rad(alpha_deg), k)
        params = Params.default(cfgs[0], alpha_deg=alpha_deg, dtype=jnp.float64)
        return tuple(np.asarray(a) for a in held_out_terms(data, cfgs[0], params, centres))


def cached_entry(store, meas, alpha_deg, names, cfgs, k, warn, before_build=None, on_miss=None):
    """The entry of one kernel group from ``store`` (no JAX), else built and stored
    (``on_miss()`` first, when given)."""
    params = default_values(cfgs[0], alpha_deg)
    key = None if store is None else _key(cfgs, names, params, meas, k)
    entry = None if store is None else store.load(key, warn, kind=HeldOutEntry)
    if entry is not None and entry.t.shape == tuple(np.shape(meas.t)):
        return entry
    if on_miss is not None:
        on_miss()
    entry = build_entry(meas, alpha_deg, names, cfgs, k, before_jax=before_build)
    if store is not None:
        store.save(key, entry, warn)
    return entry


def entry_plan(p) -> bool:
    """Whether a plan's candidates can be scored by held-out entries: every rule affine in the
    slice terms (:mod:`abrdf_jax._rules`), no log after the rule, a sparse centre layout, every
    diagonal slice measured (the learned candidates have entries of their own)."""
    return p.meas.centre_azimuths is None and affine_plan(p)


def direct_plan(p) -> bool:
    """Whether the command line scores a plan's candidates by direct numpy fits
    (:func:`abrdf_jax.select._dense_held_out.plan_errors`) when no held-out entry serves it: a
    dense layout, or a sparse one whose group is too small for an entry (a folder of jittered
    captures, a layout each); the rules of :func:`entry_plan`, without learned candidates
    (their entries are of shared layouts)."""
    return affine_plan(p) and len(rbf_configs(p.configs)) == len(p.configs)


def direct_selections(plans, out, tol: float, k: int, store=None, warn=None) -> None:
    """Fill ``out[i]`` (``None``: not chosen yet) for every plan of :func:`direct_plan`
    (:func:`abrdf_jax.select._dense_held_out.plan_errors`: the plans of one pair and centre
    layout share one RBF solve, the coefficient map kept in ``store``); a group whose RBF system
    stays singular is left to the JAX path (its guard reports it)."""
    todo = [i for i, p in enumerate(plans) if out[i] is None and direct_plan(p)]
    for i, err in zip(todo, plan_errors([plans[i] for i in todo], k, store, warn)):
        if err is not None:
            out[i] = finish(plans[i], err, tol, k, 0.0)


def entry_selections(
    items,
    *,
    store,
    warn,
    budget=None,
    tol: float,
    k: int = 4,
    noise=None,
    level: float,
    min_effect: float,
    min_group: int = MIN_GROUP,
    before_build=None,
    where=None,
    learned=None,
    reports=None,
    lone=None,
    prefetch=None,
):
    """:func:`abrdf_jax.select.select_model` (``candidates="auto"``) of grouped measurements
    ``items`` (``(meas, alpha_deg)`` pairs) wherever it needs no JAX: one candidate left (as
    :func:`~abrdf_jax.select.quick_selection`), or candidates of :func:`entry_plan` on a layout shared by
    ``min_group`` inputs or more (or on any layout of a call of few,
    :data:`abrdf_jax._engine.OPERATOR_MAX_BUILDS`), scored by held-out entries (:class:`HeldOutEntry`, from
    ``store``); the other plans of those rules without learned candidates (dense layouts, and a
    folder's layouts too small for an entry) by direct numpy fits (:func:`direct_selections`).
    ``None`` where the caller must run the JAX path
    (:func:`~abrdf_jax.select.select_models`). ``where``: each input's name, put before the
    message of an :class:`~abrdf_jax.InputError` of its plan; ``reports``: each input's
    isotropy test with ``noise``, ``level`` and ``min_effect``, if made already
    (:func:`~abrdf_jax.select._isotropy.isotropy_tests`, a folder's at once); ``learned``: a
    prior (:class:`abrdf_jax._prior_operator.PriorSource`) whose prior-only and fused models join
    the candidates (as :func:`~abrdf_jax.select.select_model`'s ``prior``), scored by their own
    held-out entries (:mod:`abrdf_jax.select._learned_entry`); ``lone``: the layout keys that
    take the direct fits, not an entry, whatever ``min_group`` (default: with ``min_group`` above
    1, those met once among ``items``: ``abrdf_jax._engine.lone_layouts``); ``prefetch``: told
    of each layout group scored by an entry, by ``prefetch.targets(meas, alpha, configs)``
    before an entry missing from the store is built and ``prefetch.chosen(meas,
    selections)`` once its members are chosen, and of the direct fits' plans by
    ``prefetch.shared(plans)`` before they run (the command line builds the operators they
    will read on a second thread meanwhile, ``abrdf_jax.cli._prefetch``). Parameters are
    numpy values (:class:`abrdf_jax._config.ParamValues`)."""
    from .._grouping import layout_key

    t0 = time.perf_counter()
    plans = []
    reports = [None] * len(items) if reports is None else reports
    for i, ((m, a), rep) in enumerate(zip(items, reports)):
        try:
            p = plan(m, a, "auto", budget, noise, level, min_effect, report=rep)
            plans.append(p if learned is None else with_prior(p, fused=True))
        except InputError as e:
            raise InputError(f"{where[i]}: {e}" if where is not None else str(e)) from e
    out = [finish(p, None, tol, k, 0.0) if len(p.configs) == 1 else None for p in plans]
    groups: dict = {}
    for i, p in enumerate(plans):
        if out[i] is None and entry_plan(p):
            key = (layout_key(p.meas), p.alpha, tuple(p.configs))
            groups.setdefault(key, []).append(i)
    # the reconstruction operators' rule (abrdf_jax._engine.plan_job): the small groups too
    # where they are few, but not a lone layout that the direct fits serve (a jittered
    # capture's: an entry would serve it alone; _engine.lone_layouts)
    if lone is None:  # else the caller's (a single jittered capture's: cli/_block_plan)
        keys = (g[0] for g, m in groups.items() for _ in m)  # one a member: lone is a group of 1
        lone = _engine.lone_layouts(keys) if min_group > 1 else frozenset()
    direct = {g for g, m in groups.items() if g[0] in lone and direct_plan(plans[m[0]])}
    small = (
        sum(len(m) < min_group for g, m in groups.items() if g not in direct)
        <= _engine.OPERATOR_MAX_BUILDS
    )
    for g, members in groups.items():
        if g in direct or (len(members) < min_group and not small):
            continue
        p0 = plans[members[0]]
        ys = np.stack([np.asarray(plans[i].meas.y) for i in members])
        errors = [{} for _ in members]
        for names, cfgs in entry_groups(rbf_configs(p0.configs)):
            miss = None  # a new layout: its operators' shared blocks made meanwhile
            if prefetch is not None:
                miss = functools.partial(prefetch.targets, p0.meas, p0.alpha, cfgs)
            entry = cached_entry(store, p0.meas, p0.alpha, names, cfgs, k, warn, before_build, miss)
            for row, err in zip(errors, entry.errors(ys)):
                row.update({n: float(e) for n, e in zip(names, err)})
        for name in (n for n in p0.configs if n in LEARNED):
            model = learned_model(name, learned, p0.configs[name].budget)
            entry = learned_entry(store, model, p0.meas, p0.alpha, k, warn, before_build)
            for row, err in zip(errors, entry.errors(ys)):
                row[name] = float(err)
        for i, err in zip(members, errors):
            out[i] = finish(plans[i], err, tol, k, 0.0)
        if prefetch is not None:
            prefetch.chosen(p0.meas, [out[i] for i in members])
    if prefetch is not None:  # the second stage the direct fits' models read, meanwhile
        prefetch.shared([p for p, s in zip(plans, out) if s is None and direct_plan(p)])
    direct_selections(plans, out, tol, k, store, warn)  # dense layouts, and those left
    share = (time.perf_counter() - t0) / max(len(items), 1)
    return [None if s is None else dataclasses.replace(s, seconds=share) for s in out]
