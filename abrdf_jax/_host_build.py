"""The operator store's builds in numpy, without importing JAX: the reconstruction operator's
matrix (:func:`host_matrix`) and the held-out fits of model selection (:func:`host_held_out_terms`).

The command line stores one operator per sample layout (:mod:`abrdf_jax._cache`); a cold call
used to import JAX and trace, lower and compile the build (``_operator._build``) to run it once:
about 2 s of a 2.8 s one-file call (docs/notes.md, twelfth session). The build is the linear
part of the pipeline applied to unit sample vectors: the slice interpolation and the subspace
rule at the RBF centres (:func:`abrdf_jax._subspace.centre_subspaces`), the RBF system of the
centres (:mod:`abrdf_jax._rbf_system`) and its evaluation at the 6561 UBO pairs, with the
restored subspaces put back at the centres that are grid pairs. The same functions run in JAX
for :func:`abrdf_jax.compile_operator`; here they run with ``xp = numpy`` in float64. The one
difference is the guard's condition estimate: the first step of the JAX guard's Hager ascent
(one ``numpy.linalg.solve`` carries its starting vectors; numpy keeps no factor to iterate
with), where JAX runs three (:func:`abrdf_jax._rbf_system.host_guarded_solve`). Tests:
tests/test_host_build.py (against the JAX build, every linear setting and layout kind).
"""

from __future__ import annotations

import functools
from typing import Any, NamedTuple

import numpy as np

from ._centre_step import affine_on_log
from ._coords import pair_coordinates
from ._errors import InputError
from ._folds import fold_slots, gather, held_out_directions
from ._grid import _centre_target_index, centre_count, centre_layout, centre_vectors
from ._grid import keep_centres
from ._grid import ubo_target_vectors
from ._kernels import kernel_block
from ._names import LOG_SUBSPACE
from ._rbf_system import combine, host_guarded_solve, host_solve, poly, prepared
from ._subspace import centre_subspaces, get_rule

NONLINEAR_MODES = ("raise", "two_stage")


class BuiltMatrix(NamedTuple):
    """An operator's build: the matrix (numpy, or a JAX array of the build dtype), the flat
    index of the valid samples, the grid rows kept from the centres (empty for other targets),
    the stage, and the template's slice positions and counts (numpy)."""

    matrix: Any
    index: np.ndarray
    keep: np.ndarray
    stage: str
    t: np.ndarray
    count: np.ndarray


def template_layout(template) -> tuple[np.ndarray, np.ndarray]:
    """The template's slice positions ``(S, nmax)`` and counts ``(S,)`` as numpy arrays."""
    t, count = np.asarray(template.t), np.asarray(template.count)
    if t.ndim == 3:  # a stacked template: every member must share the layout
        if not (np.all(count == count[:1]) and np.all(t == t[:1])):
            raise InputError(
                "the stacked template's members have different slice layouts; pass one measurement"
            )
        t, count = t[0], count[0]
    if t.ndim != 2 or count.shape != (t.shape[0],):
        raise InputError(f"template.t must have shape (S, nmax), got {template.t.shape}")
    return t, count


def build_stage(config, template, nonlinear: str = "raise") -> str:
    """``"single"`` (one matrix from the samples) or ``"two_stage"`` (per-material subspace
    step, then the RBF matrix); :class:`InputError` for a setting the operator cannot take."""
    if nonlinear not in NONLINEAR_MODES:
        raise InputError(f"nonlinear must be one of {NONLINEAR_MODES}, got {nonlinear!r}")
    if config.budget == "aniso204" and not template.has_axial:
        raise InputError(
            "Config(budget='aniso204') needs axial slices, but the template has none; use budget='iso102'"
        )
    rule_linear = get_rule(config.subspace_rule).linear
    log_subspace = config.value_space in LOG_SUBSPACE
    dense = getattr(template, "centre_azimuths", None) is not None
    asked = nonlinear == "two_stage" and (dense or affine_on_log(config))
    if rule_linear and not log_subspace and not asked:
        # (asked for, a dense layout takes two stages, its many samples, and so does any on the
        # log of the samples: a second stage that every layout of its pairs shares)
        return "single"
    if nonlinear == "raise":
        why = (
            f"rule={config.subspace_rule!r} is not linear in the samples"
            if not rule_linear
            else f"value_space={config.value_space!r} takes the log after the subspace rule"
        )
        raise InputError(
            f"compile_operator: {why}; use Config(rule='crossing' or 'average' or budget='iso102') with "
            f"value_space='linear' or 'logsamples', or pass nonlinear='two_stage' (slower: per-material subspace step)"
        )
    return "two_stage"


def sample_index(t: np.ndarray, count: np.ndarray) -> np.ndarray:
    """The flat indices ``s · nmax + k`` of the valid samples of a padded layout."""
    return np.nonzero((np.arange(t.shape[1])[None, :] < count[:, None]).reshape(-1))[0]


def host_matrix(config, values, template, nonlinear: str = "raise") -> BuiltMatrix:
    """The operator of ``config`` with parameter values ``values`` (``ParamValues`` or
    ``Params``) on ``template``'s layout, on the UBO grid, built in float64 numpy: one matrix
    from the samples, or with ``nonlinear="two_stage"`` for a rule that is not linear in them
    the second stage's, from the subspaces at the RBF centres (``_operator._build``).

    Raises:
        InputError: as :func:`abrdf_jax.compile_operator` for a setting that is not linear.
        numpy.linalg.LinAlgError: the RBF system stays singular to working precision after
            the guard's raised ``λ`` (the caller may build in JAX instead).
    """
    t, count = template_layout(template)
    stage = build_stage(config, template, nonlinear)
    pairs, azimuths = template.pairs, template.centre_azimuths
    index = sample_index(t, count)
    s, nmax = t.shape
    if stage == "two_stage":  # the centres' values are the inputs
        vals = np.eye(centre_count(pairs, azimuths))
    else:
        unit = np.zeros((s * nmax, index.size))
        unit[index, np.arange(index.size)] = 1.0
        alpha = np.asarray(values.alpha, np.float64)
        vals = centre_subspaces(
            t.astype(np.float64), unit.reshape(s, nmax, -1), count, pairs, azimuths, alpha,
            config.subspace_rule, config.interp, xp=np,
        )  # fmt: skip
    rbf = _rbf_at_targets(*_targets_key(config, values, template))
    coeffs, tail, _ = host_solve(rbf.k, rbf.p, rbf.sc, np.float64(np.asarray(values.reg)), vals)
    out = np.zeros((81 * 81, vals.shape[-1]))
    out[rbf.rest] = combine(rbf.kq, rbf.pq, coeffs, tail, np)  # evaluate(), blocks made once
    return BuiltMatrix(keep_centres(out, vals, pairs, azimuths), index, rbf.keep, stage, t, count)


def host_matrix_or_none(config, values, template, nonlinear: str = "raise") -> BuiltMatrix | None:
    """:func:`host_matrix`, or ``None`` where its RBF system stays singular after the guard
    (the caller's JAX build then reports it)."""
    try:
        return host_matrix(config, values, template, nonlinear)
    except np.linalg.LinAlgError:
        return None


def warm_targets(config, values, template) -> None:
    """Make the RBF blocks at the UBO targets that :func:`host_matrix` of ``config``,
    ``values`` and ``template``'s pairs reads (kept for the next build of the setting): ahead
    of the builds, on a thread of their own (``abrdf_jax.cli._prefetch``)."""
    _rbf_at_targets(*_targets_key(config, values, template))


def _targets_key(config, values, template) -> tuple:
    """The hashable arguments of :func:`_rbf_at_targets` for a build."""
    widths = tuple(float(w) for w in np.ravel(np.asarray(values.widths, np.float64)))
    pairs = tuple(tuple(float(x) for x in pair) for pair in template.pairs)
    c = config
    return c.parameterization, c.kernel, c.degree, widths, pairs, template.centre_azimuths


class _TargetRbf(NamedTuple):
    """What an operator's RBF part needs besides the values: the centres' system blocks and
    the kernel and tail at the UBO targets that no kept centre overwrites."""

    k: np.ndarray
    p: np.ndarray
    sc: Any
    keep: np.ndarray
    rest: np.ndarray
    kq: np.ndarray
    pq: np.ndarray | None


@functools.lru_cache(maxsize=1)
def _rbf_at_targets(name, kernel, degree, widths, pairs, azimuths) -> _TargetRbf:
    """The RBF's blocks for :func:`host_matrix`, made once per process for one setting
    (hashable arguments): the operators of one layout's candidates (``--model auto`` builds
    the iso and crossing operators of an aniso204 folder) share them. 55 MB for the protocol's
    1,296 centres: the last setting only is kept."""
    xc = pair_coordinates(*centre_vectors(pairs, np.float64, azimuths, np), name, np)
    degree, w, shift, scale, (k, p, sc) = prepared(xc, np.asarray(widths), kernel, degree, np)
    keep = _centre_target_index(pairs, azimuths)[1]
    rest = np.setdiff1d(np.arange(81 * 81), keep)  # the rows the kept centres do not overwrite
    xq = pair_coordinates(*(w_[rest] for w_ in ubo_target_vectors(np.float64, np)), name, np)
    kq = kernel_block(xq, xc, w, kernel, np)
    pq = poly(xq, shift, scale, degree, np) if degree >= 0 else None
    return _TargetRbf(k, p, sc, keep, rest, kq, pq)


def host_held_out_terms(meas, config, values, k: int):
    """The held-out fits of model selection as matrices, in float64 numpy:
    :func:`abrdf_jax.select._select.held_out_terms` (same shapes and meaning) without JAX.

    Per fold ``j`` (:func:`abrdf_jax._folds.fold_slots`): the slice terms at the centres from
    unit vectors on the fold's training slots, and the RBF fitted at the centres read at the
    fold's held-out directions. The latter is ``[K_q, P_q s] A⁻¹ [I; 0]``, got as the
    transpose of one solve ``A⁻¹ [K_q, P_q s]ᵀ`` (``A`` symmetric) with the guard's rule.

    Returns:
        ``(terms, ones)``: ``(k, P, 3, q, S·nmax)`` and ``(k, P, q)``.

    Raises:
        numpy.linalg.LinAlgError: as :func:`host_matrix`.
    """
    t, count = template_layout(meas)
    t = t.astype(np.float64)
    pairs, azimuths = meas.pairs, meas.centre_azimuths
    s, nmax = t.shape
    alpha = np.asarray(values.alpha, np.float64)
    train, test = fold_slots(count, nmax, k)
    unit = np.eye(s * nmax).reshape(s, nmax, s * nmax)
    terms = np.stack([
        centre_subspaces(
            gather(t, train[j]), unit, (train[j] >= 0).sum(-1), pairs, azimuths, alpha, None,
            config.interp, terms=True, xp=np,
        )
        for j in range(k)
    ])  # (k, 3, n, slots)  # fmt: skip
    held = gather(t, test)  # (k, S, ntest)
    wi, wv = (np.stack(w) for w in zip(*(held_out_directions(h, pairs, alpha, np) for h in held)))
    name, kernel = config.parameterization, config.kernel
    xc = pair_coordinates(*centre_vectors(pairs, np.float64, azimuths, np), name, np)
    widths = np.asarray(values.widths, np.float64)
    degree, widths, shift, scale, (kk, p, sc) = prepared(xc, widths, kernel, config.degree, np)
    xq = pair_coordinates(wi.reshape(-1, 3), wv.reshape(-1, 3), name, np)
    rows = np.concatenate(
        [kernel_block(xq, xc, widths, kernel, np), poly(xq, shift, scale, degree, np) * sc],
        axis=1,
    )  # fmt: skip
    sol, _ = host_guarded_solve(kk, p, np.float64(np.asarray(values.reg)), rows.T)
    n = xc.shape[0]
    rbf = sol[:n].T.reshape(k, -1, n)  # (k, q, n)
    bounds = np.cumsum([0] + [len(pi_) for pi_, _ in centre_layout(pairs, azimuths)])
    maps, ones = [], []
    for lo, hi in zip(bounds[:-1], bounds[1:]):
        maps.append(np.einsum("kqn,ktns->ktqs", rbf[..., lo:hi], terms[:, :, lo:hi], optimize=True))
        ones.append(np.sum(rbf[..., lo:hi], axis=-1))
    return np.stack(maps, 1), np.stack(ones, 1)
