"""A cold call's operator builds on a second core (issue 13: the cold 1000-file folder).

A new sample layout's operators are built in numpy, on one core (BLAS runs one thread,
:mod:`abrdf_jax.cli._blas`): the setting's RBF blocks at the UBO targets (a 5,265 × 1,296
kernel block and the centres' system, shared by the candidates of one setting), then per chosen
model a solve and a product (``abrdf_jax._host_build.host_matrix``). The main thread did them
one after the other, between the model choice and each model's first batch, while the second
core, busy while the readers ran, waited: a cold 1000-file aniso204 folder took 0.7 s more than
a warm one (``python -m benchmarks.cli``, 30th session).

:class:`Prefetch` runs them on one worker thread instead (numpy releases the GIL in its loops
and products):

- during the model choice, the RBF blocks at the targets of a layout's setting
  (:meth:`Prefetch.targets`, told by ``select._held_out_entry.entry_selections`` of a layout
  group whose held-out entry the store lacks, before that entry is built: a new layout, in a
  folder or one file's call), where the store lacks an operator of its candidates; then, as
  soon as a group's members are chosen, the operators of the models chosen by many of them
  (:meth:`Prefetch.chosen`);
- before the direct fits of jittered or dense captures (a layout each: no held-out entry),
  the second stage that their candidates share (:meth:`Prefetch.shared`: one per setting,
  pairs and centre layout, a 5,265 × 1,296 map or larger, the longest build of such a run);
- once a folder block's models are chosen, the operators its jobs read that nothing builds
  yet (:meth:`Prefetch.operators`), in the order the jobs read them.

The main thread takes each from its future when its turn comes (:meth:`Prefetch.take`, through
``Caches.operator``; it waits for the target blocks before any build of its own, so none is
made twice), reconstructing the groups before it meanwhile. The same bits: each build is the
function the main thread would call on the same inputs, stored the same way. What is built is
what the run reads: the chosen models' operators; the target blocks and the shared second stage
of candidates of which one is about to be chosen (every RBF candidate reads them). Only numpy
builds run here (a build that needs JAX, a singular RBF system, is left to the main thread,
which reports it; so is any error: a build that fails here is built again where the run would
have built it). Tests: tests/test_cli_prefetch.py.
"""

from __future__ import annotations

import concurrent.futures
import contextlib


class _NeedsJax(Exception):
    """A build here would need JAX: left to the main thread."""


def _no_jax() -> None:
    raise _NeedsJax


class Prefetch:
    """The builds of one ``reconstruct`` run on one worker thread (module docstring), stored
    in ``store`` (``None``: ``--cache-dir off``, kept for the run only)."""

    def __init__(self, store, warn):
        self.store, self.warn = store, warn
        self._pool: concurrent.futures.ThreadPoolExecutor | None = None
        self._building: dict[str, concurrent.futures.Future] = {}
        self._targets: dict = {}  # the target blocks made here, by setting

    def _stored(self, key: str) -> bool:
        return self.store is not None and self.store.path(key).exists()

    def _submit(self, fn, *args) -> concurrent.futures.Future:
        if self._pool is None:
            self._pool = concurrent.futures.ThreadPoolExecutor(1, "abrdf-jax-build")
        return self._pool.submit(fn, *args)

    def _missing(self, config, params, template) -> str | None:
        """The store key of a single-stage numpy build of ``config`` on ``template``'s layout
        that the store lacks and nothing builds yet; ``None`` otherwise."""
        from .. import _cache
        from .._centre_step import host_two_stage
        from .._errors import InputError
        from .._host_build import build_stage

        if getattr(config, "operator_only", False):
            return None
        if host_two_stage(config, template):
            return None
        try:
            build_stage(config, template)
        except InputError:
            return None
        key = _cache.operator_key(config, params, template)
        if key in self._building or self._stored(key):
            return None
        return key

    def targets(self, meas, alpha: float, configs) -> None:
        """Before a held-out entry missing from the store is built (``meas``'s layout, α
        ``alpha`` in degrees, candidate ``configs``): the RBF blocks at the targets of the
        first candidate whose operator the store lacks, made on the worker (once a setting).
        The candidates are compared because one of them will be chosen, and its operator's
        build reads these blocks (:meth:`take` waits for them: no build makes them twice)."""
        from .._config import default_values
        from .._host_build import _targets_key, warm_targets

        for config in configs:
            params = default_values(config, alpha, meas.y.dtype)  # the choice's (_choice.finish)
            if self._missing(config, params, meas) is None:
                continue
            key = _targets_key(config, params, meas)
            if key not in self._targets:
                self._targets[key] = self._submit(_quietly, warm_targets, config, params, meas)
            return

    def chosen(self, meas, selections) -> None:
        """A layout group of ``meas``'s layout chosen (its members' ``selections``): the
        operators of the models chosen for :data:`~abrdf_jax._engine.OPERATOR_MIN_GROUP`
        inputs or more, built on the worker while the choice goes on."""
        from .._engine import OPERATOR_MIN_GROUP

        counts: dict = {}
        for s in selections:
            counts.setdefault(s.config, [0, s.params])[0] += 1
        for config, (count, params) in counts.items():
            if count >= OPERATOR_MIN_GROUP:
                self._build_later(config, params, meas)

    def shared(self, plans) -> None:
        """Before the direct fits of ``plans`` (a folder's jittered captures, a dense capture, a
        single jittered file: :func:`abrdf_jax.select._held_out_entry.direct_plan`): the
        second stage their affine candidates on the log of the samples read, which every
        layout of the pairs and centre layout shares (``_cache.cached_entry(shared=True)``;
        one per setting, whatever the rule), built on the worker while the fits run."""
        from .. import _cache
        from .._centre_step import affine_on_log
        from .._config import default_values

        seen = set()  # a folder's captures share their pairs: a key a setting and pairs
        for p in plans:
            for config in p.configs.values():
                if getattr(config, "operator_only", False) or not affine_on_log(config):
                    continue
                at = (config, tuple(map(tuple, p.meas.pairs)), p.meas.centre_azimuths)
                if at in seen:
                    continue
                seen.add(at)
                params = default_values(config, p.alpha, p.meas.y.dtype)
                key = _cache.operator_key(config, params, p.meas, centres=True)
                memo = ("" if self.store is None else str(self.store.folder), key)
                if key in self._building or memo in _cache._SHARED or self._stored(key):
                    continue
                self._building[key] = self._submit(self._build_shared, config, params, p.meas)

    def _build_shared(self, config, params, template):
        from .. import _cache

        try:
            _cache.cached_entry(
                self.store, template, config, params, self.warn, before_build=_no_jax, shared=True
            )
        except Exception:  # noqa: BLE001 - the main thread builds it again and reports
            pass

    def operators(self, jobs, params_of) -> None:
        """The operators the block's ``jobs`` (``cli._block_plan.block_jobs``) will read and
        nothing builds yet, built on the worker in the jobs' order; ``params_of(members)``: a
        job's parameters."""
        for config, members, meas, job in jobs:
            params = params_of(members)
            for g in job["plan"].values():
                if g["kind"] == "operator" and not g["shared"]:
                    self._build_later(config, params, meas[g["members"][0]])

    def _build_later(self, config, params, template) -> None:
        key = self._missing(config, params, template)
        if key is not None:
            self._building[key] = self._submit(self._build, key, config, params, template)

    def _build(self, key, config, params, template):
        from .. import _cache

        try:
            entry = _cache.build_entry(template, config, params, before_jax=_no_jax)
        except Exception:  # noqa: BLE001 - the main thread builds it again and reports
            return None
        if self.store is not None:
            self.store.save(key, entry, self.warn)
        return entry

    def take(self, config, params, template, shared: bool = False):
        """The entry built here for ``config`` on ``template``'s layout (waiting for it), or
        ``None`` (not built here, or given up: the caller builds it). ``shared``: wait for the
        setting's second stage, if it is being built here (the caller then reads it from
        ``_cache.cached_entry``'s memory); ``None``."""
        for future in self._targets.values():  # a build of the caller's reads them
            future.result()
        if not self._building:
            return None
        from .. import _cache
        from .._centre_step import host_two_stage

        shared = shared or host_two_stage(config, template)  # as _cache.cached_entry decides
        key = _cache.operator_key(config, params, template, centres=shared)
        future = self._building.pop(key, None)
        entry = None if future is None else future.result()
        return None if shared else entry

    def close(self) -> None:
        """Stop the worker: builds not started are dropped, a running one ends first."""
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)
            self._pool = None
        self._building.clear()

    def __enter__(self) -> "Prefetch":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _quietly(fn, *args) -> None:
    with contextlib.suppress(Exception):  # a head start only: the build makes it again
        fn(*args)
