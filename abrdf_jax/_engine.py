"""Many measurements of one configuration, reconstructed on the fastest exact path.

:func:`reconstruct_many` is what a folder of measurement files needs: the measurements are
grouped by sample layout (elevation pairs, RBF centre layout and, for the compiled operator,
the slice positions and counts); every group runs in batches of one fixed shape, so that a run
compiles once per layout and never again for its last, smaller batch (it is padded with copies
of its last member, whose tables are dropped).

- **Operator groups**: settings that are linear in the (log) samples (a linear subspace rule
  and ``value_space`` ``"linear"`` or ``"logsamples"``) and a sparse centre layout are one
  matrix (:func:`~abrdf_jax.compile_operator`) per slice layout, built once per group, or
  loaded from an operator store (``abrdf_jax._cache``) keyed by everything it depends on; an
  affine rule on the log samples that is not linear (``--model aniso``), or any on a dense
  capture, is two stages (:func:`operator_applies`). The operator reproduces
  :func:`~abrdf_jax.reconstruct` to float32 rounding (``tests/test_operator.py``). A job's
  layouts that are too many to build an operator each (jittered captures: a layout a file) take
  the two-stage form where the setting has it (an affine rule on the log of the samples): each
  capture's subspaces at the RBF centres, then the one second stage of its setting and pairs
  (:class:`SharedStages`: the captures that read one second stage wait for each other and run
  it as one product, the same bits as one product each).
- **Numpy maps** (the learned models, ``abrdf_jax._prior_operator.PriorModel``, and the
  bivariate model, ``abrdf_jax._bivariate.BivariateModel``, passed as ``config``;
  ``operator_only``): one map per slice layout, whatever the group's size, in batches of at
  most the job's group (they compile nothing: a capture whose layout no other file shares, as
  every jittered one, is one row, not a padded batch of 256).
- **Pipeline groups**: everything else (nonlinear rules on linear values, the log after
  interpolation, the multiplicative rule, and the many small layouts of a setting on linear
  values) goes through :func:`~abrdf_jax.reconstruct_batch` in
  padded batches; the slices are padded to the group's longest.

The tables come back batch by batch (``yield``), so a caller can write each batch as soon as it
is done and an interrupted run keeps what it finished.
"""

from __future__ import annotations

import hashlib
from collections import Counter
from collections.abc import Callable, Iterator, Sequence
from typing import TYPE_CHECKING, NamedTuple

import numpy as np

from ._centre_step import affine_on_log, host_two_stage, nonlinear_mode
from ._config import Config
from ._grouping import layout_key

if TYPE_CHECKING:  # JAX pytrees: the pipeline path makes them (importing JAX), the operator
    # path needs none (the command line passes numpy slices and parameter values)
    from ._measurements import Measurements
    from ._params import Params

#: Materials per batch: one matrix product per operator batch (bounded by the output's
#: 6561 x 3 floats a material, 20 MiB at 256); the general pipeline holds one RBF evaluation a
#: material, so its batches are smaller.
OPERATOR_BATCH, PIPELINE_BATCH = 256, 32
#: Captures' rows whose shared second stage (:func:`plan_job`'s ``"shared"`` groups) one
#: product computes (``OperatorEntry.apply_many``; 128 captures' first stages, 19 MB of tables).
SHARED_ROWS = 128
#: A slice layout shared by this many measurements of a job or more gets an operator. Below
#: it, a job whose small layouts would cost more than :data:`OPERATOR_MAX_BUILDS` builds
#: (every jittered capture is a layout of its own, never seen again) gives them the setting's
#: shared two-stage form (an affine rule on the log of the samples), else the pipeline:
#: building an operator costs an RBF solve with one right-hand side per sample,
#: about as much as reconstructing dozens of materials in a batch (docs/notes.md, "Issue 13":
#: 100 jittered files, one operator each, took 55 s and 257 MB of cache against 33 s through
#: the pipeline). A caller with one measurement (``abrdf-jax reconstruct FILE``) passes
#: ``min_group=1``: the next call with its layout loads the operator from the operator store.
OPERATOR_MIN_GROUP = 32
#: A job builds an operator for each layout below :data:`OPERATOR_MIN_GROUP` too while they
#: cost at most this many single-stage builds (:func:`small_builds`): a few numpy builds cost
#: less than the pipeline's JAX start and compilation (seconds, once per setting and call), and
#: a rerun loads them from the store. Chosen on scratch timings of jittered folders of 4–16
#: files, cold and warm (docs/notes.md, 2026-12-07); ``python -m benchmarks.cli`` times a
#: folder of 8 aniso204 files whose models are small layouts.
OPERATOR_MAX_BUILDS = 16
#: What one two-stage entry (``--model aniso``: 6561 × 1296 float32, 34 MB in the store)
#: counts against :data:`OPERATOR_MAX_BUILDS`: it takes several times a single-stage build's
#: time and space (scratch, as above).
TWO_STAGE_BUILD_COST = 4


class Layouts(NamedTuple):
    """Each measurement's layout key (``None`` where no operator applies) and how many
    measurements of the whole job (done before or not) share each key (:func:`job_layouts`)."""

    keys: list
    sizes: Counter
    builds: dict  # layout key -> its build, ("layout", key) or ("two-stage", pairs, centres)


def job_layouts(meas: Sequence, config, done: Sequence["Done"] = ()) -> Layouts:
    """The :class:`Layouts` of a job of ``config``: ``meas`` and the measurements ``done``."""
    only = getattr(config, "operator_only", False)
    key_of = getattr(config, "layout_key", layout_key)  # a model may read more of a layout
    keys = [key_of(m) if only or operator_applies(config, m) else None for m in meas]
    sizes = Counter(keys)
    sizes.update(Counter(d.layout for d in done if d.layout is not None))
    builds = {key: ("layout", key) for key in sizes}
    for m, key in zip(meas, keys):  # a two-stage map: one per pairs and centre layout
        if key is not None and not only and host_two_stage(config, m):
            builds[key] = ("two-stage", tuple(map(tuple, m.pairs)), m.centre_azimuths)
    return Layouts(keys, sizes, builds)


def lone_layouts(keys, done: Sequence["Done"] = ()) -> frozenset:
    """The layout keys met once among ``keys`` (``None``: no operator) and the measurements
    ``done`` before: a capture whose slice positions no other input shares (each jittered
    capture's, never met again), whose own operator would serve it alone. Counted over every
    setting of a folder's block, so that a protocol layout that two models share is not lone,
    and with the kept inputs, so that a resumed run decides as the interrupted one."""
    count = Counter(k for k in keys if k is not None)
    count.update(d.layout for d in done if d.layout is not None)
    return frozenset(k for k, n in count.items() if n == 1)


def _goes_shared(layouts: Layouts, key, config, lone: frozenset) -> bool:
    """Whether a small layout ``key`` takes the setting's shared second stage rather than an
    operator of its own: a lone layout (:func:`lone_layouts`) of a single-stage build, under a
    setting that has the shared form (an affine rule on the log of the samples)."""
    return (
        key in lone
        and layouts.builds.get(key, ("layout",))[0] == "layout"
        and not getattr(config, "operator_only", False)
        and affine_on_log(config)
    )


def small_build_set(
    layouts: Layouts,
    config,
    min_group: int = OPERATOR_MIN_GROUP,
    alpha=None,
    lone: frozenset = frozenset(),
) -> set:
    """The builds an operator for each layout of ``layouts`` below ``min_group`` takes, as
    ``(kind, config, what)``: a two-stage map (``"two-stage"``) is one per setting, pairs and
    centre layout whatever α and the samples' layout (its store key has neither), so the jobs
    of one setting at several α (a folder of jittered or dense captures: each file its own α)
    share it; a layout's own operator (``"layout"``) is its setting's at ``alpha``. A learned or
    bivariate model's map is always built: none; a ``lone`` layout that takes the shared second
    stage (:func:`_goes_shared`) builds nothing of its own: none."""
    if getattr(config, "operator_only", False):
        return set()
    small = {
        k
        for k, size in layouts.sizes.items()
        if k is not None and size < min_group and not _goes_shared(layouts, k, config, lone)
    }
    out = set()
    for k in small:
        kind, *what = layouts.builds.get(k, ("layout", k))
        out.add((kind, config, tuple(what) if kind == "two-stage" else (alpha, *what)))
    return out


def build_cost(builds: set) -> int:
    """What :func:`small_build_set`'s builds cost in single-stage builds (a two-stage entry
    counts :data:`TWO_STAGE_BUILD_COST`). A job builds them while the cost over its settings is
    at most :data:`OPERATOR_MAX_BUILDS`."""
    return sum(TWO_STAGE_BUILD_COST if kind == "two-stage" else 1 for kind, _, _ in builds)


def small_builds(layouts: Layouts, config, min_group: int = OPERATOR_MIN_GROUP) -> int:
    """:func:`build_cost` of one job's :func:`small_build_set`."""
    return build_cost(small_build_set(layouts, config, min_group))


def operator_applies(config: Config, meas) -> bool:
    """Whether ``config`` on ``meas`` is an operator (:func:`~abrdf_jax.compile_operator`) that
    reproduces :func:`~abrdf_jax.reconstruct`: one matrix (a linear rule, no log after it:
    :attr:`Config.linear`) on a sparse layout, or two stages whose first the operator store
    runs in numpy (:func:`abrdf_jax._centre_step.host_two_stage`: ``--model aniso``, and any
    affine rule on the log of a dense capture's samples). No JAX is imported."""
    return (config.linear and meas.centre_azimuths is None) or host_two_stage(config, meas)


def as_jax(meas, params) -> tuple["Measurements", "Params"]:
    """The JAX pytrees of a measurement and parameters that may be numpy (the command line's
    slices and parameter values, ``abrdf_jax._arrays``/``abrdf_jax._config``)."""
    from ._params import Params

    if hasattr(meas, "to_measurements"):
        meas = meas.to_measurements()
    if params is not None and not isinstance(params, Params):
        params = Params(params.alpha, params.widths, params.reg)
    return meas, params


def _batches(
    members: Sequence[int], slots: Sequence[int], size: int
) -> Iterator[tuple[list[int], list[int], list[int]]]:
    """``(chunk, padded, rows)``: the members whose slot (their place in the whole job's group)
    falls in one batch of ``size``; the batch, each member at row ``slot % size`` and the other
    rows copies of the chunk's last member (their tables are dropped); the members' rows."""
    by_batch: dict[int, dict[int, int]] = {}
    for k, slot in zip(members, slots):
        by_batch.setdefault(slot // size, {})[slot % size] = k
    for b in sorted(by_batch):
        at = by_batch[b]
        rows = sorted(at)
        chunk = [at[r] for r in rows]
        yield chunk, [at.get(r, chunk[-1]) for r in range(size)], rows


def _rows(tables: np.ndarray, rows: list[int]) -> np.ndarray:
    """``tables[rows]``; a view where the rows are consecutive (a full batch: no copy)."""
    if rows == list(range(rows[0], rows[0] + len(rows))):
        return tables[rows[0] : rows[0] + len(rows)]
    return tables[rows]


class Done(NamedTuple):
    """A measurement of the job that an earlier, interrupted run already reconstructed (what a
    folder run's model record keeps of it: :func:`job_keys`)."""

    layout: str | None  # its layout_key where an operator applies
    group: str  # group_id of the group it was reconstructed in
    order: int  # its place in the whole job
    width: int  # its slices' length (t.shape[-1])
    # whether its block gave small layouts operators (plan_job's ``small``; None: not recorded)
    small: bool | None = None


def group_id(group: tuple) -> str:
    """A short digest of a group key (``("operator", layout)`` or ``("pipeline", pairs,
    centre_azimuths)``): what a model record keeps."""
    return hashlib.sha256(repr(group).encode()).hexdigest()[:16]


def plan_job(
    meas: Sequence["Measurements"],
    config: Config,
    *,
    min_group: int = OPERATOR_MIN_GROUP,
    done: Sequence[Done] = (),
    order: Sequence[int] | None = None,
    layouts: Layouts | None = None,
    small: bool | None = None,
    lone: frozenset = frozenset(),
) -> dict[str, dict]:
    """The plan of :func:`reconstruct_many` with these arguments (its groups, each with the
    layout key of its members), made once for both :func:`job_keys` and
    :func:`reconstruct_many` (``plan=``): a folder's record and its reconstruction read one
    plan, and each measurement's layout is digested once (``layouts``: :func:`job_layouts` of
    the same ``meas``, ``config`` and ``done``, if made already).

    A layout is an operator group when the job holds at least ``min_group`` measurements of it
    (whichever of them are left to do), or when ``small``: layouts below ``min_group`` get
    operators too (default: where their :func:`small_builds` are at most
    :data:`OPERATOR_MAX_BUILDS`; a caller with several settings sums them over the job). Other
    small layouts of a setting whose operator takes the two-stage form on any layout (an affine
    rule on the log of the samples, :func:`abrdf_jax._centre_step.affine_on_log`) are operator
    groups that read the setting's one second stage (``"shared"``: each capture's subspaces at
    the RBF centres, then one matrix for all): a folder of jittered captures builds one map a
    setting (a map per elevation pairs: off the UBO rings the levels are rounded to
    ``_grouping.LEVEL_STEP_DEG``, so one device's captures share them). So do the ``lone``
    layouts of such a setting even when ``small`` (:func:`lone_layouts`: a folder's jittered
    captures, whose own operators would serve one file each and never again, while the shared
    map serves the device's next folder too). The rest go through the pipeline."""
    if layouts is None:
        layouts = job_layouts(meas, config, done)
    if small is None:
        small = small_builds(layouts, config, min_group) <= OPERATOR_MAX_BUILDS
    only = getattr(config, "operator_only", False)  # a learned model's map: always built
    shared = not only and affine_on_log(config)
    lone = frozenset(k for k in lone if _goes_shared(layouts, k, config, lone))
    return _plan(meas, layouts, min_group, small or only, shared, done, order, lone)


def _plan(meas, layouts: Layouts, min_group, small, shared, done, order, lone) -> dict[str, dict]:
    """The groups of the whole job (``meas`` and the measurements ``done`` before): ``{group_id:
    {"kind", "members" (indices into meas), "layouts" (their layout keys, ``None`` where no
    operator applies), "slots" (their places among the job's group), "width" (the group's
    longest slices), "shared" (an operator group that reads the setting's shared second
    stage)}}`` (:func:`plan_job`)."""
    done = list(done or ())
    order = list(range(len(meas))) if order is None else list(order)
    keys, sizes = layouts.keys, layouts.sizes
    plan: dict[str, dict] = {}
    for k, (m, key) in enumerate(zip(meas, keys)):
        fast = key is not None and (sizes[key] >= min_group or (small and key not in lone))
        if fast:
            group = ("operator", key)
        elif key is not None and shared:  # a layout of many: the shared second stage
            group = ("shared", key)
        else:
            group = ("pipeline", m.pairs, m.centre_azimuths)
        g = plan.setdefault(
            group_id(group),
            {"kind": "operator" if group[0] == "shared" else group[0], "members": [],
             "layouts": [], "width": 0, "shared": group[0] == "shared"},
        )  # fmt: skip
        g["members"].append(k)
        g["layouts"].append(key)
        g["width"] = max(g["width"], int(np.shape(m.t)[-1]))
    for gid, g in plan.items():
        before = [d for d in done if d.group == gid]
        g["width"] = max([g["width"], *(d.width for d in before)])
        ranks = sorted([*(d.order for d in before), *(order[k] for k in g["members"])])
        place = {o: i for i, o in enumerate(ranks)}
        g["slots"] = [place[order[k]] for k in g["members"]]
        g["size"] = len(ranks)  # the whole job's group, done before or not
    return plan


def job_keys(
    meas: Sequence["Measurements"],
    config: Config,
    *,
    min_group: int = OPERATOR_MIN_GROUP,
    done=(),
    order: Sequence[int] | None = None,
    plan: dict[str, dict] | None = None,
) -> list[dict]:
    """What :func:`reconstruct_many` with the same arguments makes of each measurement, for a
    record that a resumed run reads back as :class:`Done`: ``{"layout", "group", "width"}``.
    ``plan``: :func:`plan_job` of the same arguments, if made already."""
    if plan is None:
        plan = plan_job(meas, config, min_group=min_group, done=done, order=order)
    out: list[dict] = [{} for _ in meas]
    for gid, g in plan.items():
        for k, key in zip(g["members"], g["layouts"]):
            out[k] = {"layout": key, "group": gid, "width": int(np.shape(meas[k].t)[-1])}
    return out


def _pad_slices(meas: "Measurements", nmax: int) -> "Measurements":
    import jax.numpy as jnp

    extra = nmax - meas.t.shape[-1]
    if extra <= 0:
        return meas
    return meas.replace(
        t=jnp.pad(meas.t, ((0, 0), (0, extra))), y=jnp.pad(meas.y, ((0, 0), (0, extra), (0, 0)))
    )


def reconstruct_many(
    meas: Sequence["Measurements"],
    config: Config,
    params: "Params",
    *,
    operator: Callable | None = None,
    batch: int | None = None,
    min_group: int = OPERATOR_MIN_GROUP,
    before_jax: Callable[[], None] | None = None,
    done: Sequence[Done] = (),
    order: Sequence[int] | None = None,
    plan: dict[str, dict] | None = None,
    host: bool = False,
    stages: "SharedStages | _Tagged | None" = None,
) -> Iterator[tuple[list[int], np.ndarray, str]]:
    """Reconstruct measurements that share ``config`` and ``params`` (module docstring).

    Args:
        meas: the measurements (or their numpy slices); they may differ in pairs, layout and
            slice positions. The operator path imports no JAX when ``operator`` does not.
        operator: ``operator(config, params, template)`` returning a callable on stacked
            sample values ``(B, S, nmax, C)`` (e.g. one
            that looks in an operator store first); default :func:`~abrdf_jax.compile_operator`.
            A group that reads its setting's shared second stage (:func:`plan_job`) calls it
            with ``shared=True``: the operator's two-stage form.
        batch: materials per call (default ``OPERATOR_BATCH`` / ``PIPELINE_BATCH``).
        min_group: the fewest measurements of one slice layout that get an operator
            (:data:`OPERATOR_MIN_GROUP`) in a job whose smaller layouts would cost more
            than :data:`OPERATOR_MAX_BUILDS` builds (:func:`plan_job`).
        before_jax: called before the pipeline's first JAX work (e.g. to turn on a
            compilation cache); the operator path leaves JAX to ``operator``.
        done: the measurements of the same job (settings) that an interrupted run already
            reconstructed (a resumed folder run's kept tables, :class:`Done`); ``order``:
            each measurement's place in the whole job (default: ``0, 1, ...``). Each
            measurement then takes the path, the batch row and the slice padding it takes in one
            uninterrupted run over all of them, and gets the same bits.
        plan: :func:`plan_job` of the same ``meas``, ``config``, ``min_group``, ``done`` and
            ``order``, if made already (e.g. for :func:`job_keys`).
        host: ``operator`` returns numpy maps that compile nothing (the command line's stored
            entries): an operator group's batches are then no larger than the job's group
            (one file's call computes one row, not a batch of copies; still the same shape
            in a resumed run), as a learned model's are; else every batch has ``batch``
            rows (one compiled shape).
        stages: a :class:`SharedStages` of the caller's (or its :meth:`SharedStages.tagged`
            view), which keeps the batches of the groups that read a shared second stage
            (their tables come from its ``flush``, not from this generator: a folder's
            jittered captures, one call each, share one product); default: this call's own,
            flushed before it ends.

    Yields:
        ``(indices, tables, path)``: positions in ``meas``, their ``(len(indices), 81, 81, 3)``
        float32 tables (numpy), and ``"operator"`` or ``"pipeline"``.
    """
    # a learned model (``_prior_operator.PriorModel``) is one operator per layout, always
    only = getattr(config, "operator_only", False)
    if operator is None and only:

        def operator(config, params, template):
            return config.operator(params, template)

    elif operator is None:
        from ._operator import compile_operator

        def operator(config, params, template, shared=False):
            if shared:  # numpy: the second stage built once for every layout (in memory)
                from ._cache import cached_entry

                return cached_entry(None, template, config, params, shared=True)[0]  # callable
            template, params = as_jax(template, params)
            mode = nonlinear_mode(config, template)
            return compile_operator(config, params, template, nonlinear=mode)

    if plan is None:
        plan = plan_job(meas, config, min_group=min_group, done=done, order=order)
    own = stages is None  # else the caller's: it takes their tables from stages.flush()
    stages = SharedStages() if own else stages
    for gid, g in plan.items():
        members, slots = g["members"], g["slots"]
        if g["kind"] == "operator":
            shared = {"shared": True} if g["shared"] else {}  # the second stage of every layout
            op = operator(config, params, meas[members[0]], **shared)
            size = batch or OPERATOR_BATCH
            if only or host:  # a numpy map compiles nothing: no padding beyond the job's group
                size = min(size, g["size"])
            for chunk, padded, rows in _batches(members, slots, size):
                y = np.stack([np.asarray(meas[k].y) for k in padded])
                if g["shared"] and hasattr(op, "apply_many"):  # the second stage later
                    stages.add(op, y, chunk, rows)
                    if own and stages.full:
                        yield from ((c, t, "operator") for _, c, t in stages.flush())
                    continue
                yield chunk, _rows(np.asarray(op(y)), rows), "operator"
        else:
            if before_jax is not None:
                before_jax()
            from ._measurements import stack_measurements
            from ._pipeline import reconstruct_batch

            jparams = as_jax(meas[members[0]], params)[1]
            nmax = g["width"]  # the longest slices of the whole job's group
            # always the full batch, also for a group of one, and every measurement at its own
            # place in it: XLA's and BLAS's rounding depend on the batch shape and on the row,
            # and a resumed run must give the same bits as an uninterrupted one
            for chunk, padded, rows in _batches(members, slots, batch or PIPELINE_BATCH):
                stack = stack_measurements(
                    [_pad_slices(as_jax(meas[k], None)[0], nmax) for k in padded]
                )
                tables = np.asarray(reconstruct_batch(stack, config, jparams))
                yield chunk, _rows(tables, rows), "pipeline"
    if own:
        yield from ((c, t, "operator") for _, c, t in stages.flush())


class SharedStages:
    """Batches of groups that read a setting's shared second stage (:func:`plan_job`'s
    ``"shared"`` groups: a folder's jittered captures, a group and a call of
    :func:`reconstruct_many` each, since each has its own α), kept until :data:`SHARED_ROWS`
    captures wait, then their second stages in one product per matrix
    (``OperatorEntry.apply_many``: the same bits as one product each, which read the whole
    27 MB matrix, at the UBO centres, for three rows). A caller that passes one to several calls (``stages=``) takes
    their tables from :meth:`flush`, each with the ``tag`` it gave :meth:`tagged`."""

    def __init__(self, rows: int | None = None):
        self.rows, self._items = SHARED_ROWS if rows is None else rows, []

    def add(self, entry, y, chunk, rows, tag=None) -> None:
        """A batch: the group's entry, its stacked values, its members and kept rows."""
        self._items.append((entry, y, chunk, rows, tag))

    def tagged(self, tag) -> "_Tagged":
        """What :func:`reconstruct_many` takes as ``stages``: this collector, its batches
        tagged with ``tag`` (the caller's job)."""
        return _Tagged(self, tag)

    @property
    def full(self) -> bool:
        return sum(len(item[1]) for item in self._items) >= self.rows

    def flush(self) -> Iterator[tuple[object, list[int], np.ndarray]]:
        """``(tag, members, tables)`` of every batch waiting (then none waits)."""
        by_matrix: dict[int, list] = {}
        for item in self._items:
            by_matrix.setdefault(id(item[0].matrix), []).append(item)
        self._items.clear()
        for items in by_matrix.values():
            tables = items[0][0].apply_many([e for e, *_ in items], [i[1] for i in items])
            for (_, _, chunk, rows, tag), t in zip(items, tables):
                yield tag, chunk, _rows(t, rows)


class _Tagged(NamedTuple):
    """A :class:`SharedStages` whose batches carry one ``tag`` (:meth:`SharedStages.tagged`)."""

    stages: SharedStages
    tag: object

    def add(self, entry, y, chunk, rows) -> None:
        self.stages.add(entry, y, chunk, rows, self.tag)
