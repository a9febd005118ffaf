"""A folder run's plan of one block of inputs (``reconstruct DIR``): the inputs grouped by
setting, and each setting's :func:`abrdf_jax._engine.plan_job`.

Whether layouts shared by fewer than ``OPERATOR_MIN_GROUP`` inputs get operators of their own
(``plan_job``'s ``small``) is decided once for the whole block, over every setting in it: a
folder of a few files, whatever models they get, builds each its operator (a rerun loads them),
and a jittered folder (a layout a file) goes through the pipeline. A resumed run takes the
decision the interrupted run recorded (``batch.small`` of its kept entries), so its tables
get the uninterrupted run's paths and bits.
"""

from __future__ import annotations

#: A capture whose samples lie off their nominal slices by more than this spread (degrees: the
#: grouping's ``offset_sigma_deg``, the encoder's error) has slice positions of its own
#: (:func:`lone_of`); an exact capture, such as the protocol's file, spreads by its angles'
#: rounding only, far below it (scratch figures: docs/notes.md, thirtieth session).
JITTER_MIN_DEG = 0.01


def lone_of(item) -> frozenset:
    """The layout key of a single input (``common.Measured``) that is lone although no other
    input is there to count (``abrdf_jax._engine.lone_layouts``): a jittered capture's, whose
    positions are its own and never met again, so that its call reads the setting's shared
    second stage and scores its candidates by the direct fits instead of building an operator
    and a held-out entry that would serve it once. Decided from the file alone: a cold and a
    warm call take the same path and give the same bits. Empty for an exact capture (its
    layout recurs: its own operator and entry are built once and stored)."""
    from .._grouping import layout_key

    if not item.used.get("offset_sigma_deg", 0.0) > JITTER_MIN_DEG:
        return frozenset()
    return frozenset({layout_key(item.meas)})


def block_jobs(items, choices, place: dict, kept: dict, *, block: int, slices) -> list[tuple]:
    """``[(config, members, meas, job)]``: per setting of the block's ``items`` (with their
    ``choices``), the members' indices, their slices, and the keywords of
    :func:`abrdf_jax._engine.reconstruct_many` (``done``, ``order``, ``plan``); each choice's
    record gets its ``batch`` entry (what ``--resume`` reads). ``place``: each input's place in
    the whole job (by its path's text); ``kept``: the kept tables (``common.kept_batches``,
    whose ``small`` says how the interrupted run decided); ``block``: files a block
    (``common.BLOCK``); ``slices(item,
    config)``: an input's slices for a setting (``common.measurements_for``)."""
    from .._engine import OPERATOR_MAX_BUILDS, build_cost, job_keys, job_layouts, lone_layouts
    from .._engine import plan_job, small_build_set
    from ._resume import settings_key

    at = place[str(items[0].path)] // block  # blocks of the whole job
    groups: dict[tuple, list[int]] = {}
    for k, (item, choice) in enumerate(zip(items, choices)):
        key = (item.budget, item.alpha, choice["config"])  # what one call must share
        groups.setdefault(key, []).append(k)
    jobs = []  # per setting: its measurements and the job's layouts (done included)
    for (_, alpha, config), members in groups.items():
        meas = [slices(items[k], config) for k in members]
        setting = settings_key(choices[members[0]]["record"])
        done = [d for d in kept.get(setting, ()) if d.order // block == at]
        job = dict(done=done, order=[place[str(items[k].path)] for k in members])
        jobs.append((config, alpha, members, meas, job, job_layouts(meas, config, done)))
    kept_here = [d for ds in kept.values() for d in ds if d.order // block == at]
    # layouts no other input of the block (any setting, kept ones too) shares: jittered captures
    lone = lone_layouts((k for *_, layouts in jobs for k in layouts.keys), kept_here)
    builds: set = set()  # what the small layouts of every setting take (shared maps once)
    for config, alpha, *_, layouts in jobs:
        builds |= small_build_set(layouts, config, alpha=alpha, lone=lone)
    # the interrupted run's decision, where its kept tables of this block recorded it
    small = next((d.small for d in kept_here if d.small is not None), None)
    if small is None:
        small = OPERATOR_MAX_BUILDS >= build_cost(builds)
    out = []
    for config, _, members, meas, job, layouts in jobs:
        plan = plan_job(meas, config, layouts=layouts, small=small, lone=lone, **job)
        job["plan"] = plan  # one plan:
        for k, keys in zip(members, job_keys(meas, config, **job)):  # the record's and the run's
            choices[k]["record"]["batch"] = {**keys, "small": small}
        out.append((config, members, meas, job))
    return out
