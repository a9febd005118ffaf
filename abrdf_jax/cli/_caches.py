"""The caches of a command's run (docs/cache.md): the folder ``--cache-dir`` names (or
``$ABRDF_JAX_CACHE_DIR``, ``ABRDF_JAX_NO_CACHE``), its store of built operators and JAX's
persistent compilation cache. One copy of the flag's help and of its handling, for every command
that compiles (``reconstruct``, ``fit``, ``btf reconstruct``). Used through
:mod:`abrdf_jax.cli._common`."""

from __future__ import annotations

from collections.abc import Callable

#: The ``--cache-dir`` help, the same in every command that has the flag.
CACHE_DIR_HELP = (
    "cache folder of compiled code and built operators, or 'off' (default $ABRDF_JAX_CACHE_DIR, "
    "else ~/.cache/abrdf_jax; ABRDF_JAX_NO_CACHE=1 turns it off; see 'abrdf-jax cache')"
)


def compilation_cache(override, warn: Callable[[str], None]) -> bool:
    """Turn on JAX's persistent compilation cache in the folder of ``--cache-dir`` ``override``
    (:func:`abrdf_jax._cache.cache_dir`) before a command's first compile, so that the next run
    of the same command loads what this one compiled. A folder that cannot be used is a warning
    (``warn``) and a run without it; an ``off`` cache is no cache. Returns whether it is on."""
    from .. import _cache

    return _cache.enable_compilation_cache(_cache.cache_dir(override), warn=warn)


class Caches:
    """The caches of one ``reconstruct`` run: the store of built operators, and JAX's persistent
    compilation cache, turned on only when the run needs JAX (:meth:`numerics`): a warm run
    whose operators are all stored imports no JAX. A folder that cannot be used is a warning
    and a run without it, never a failure."""

    def __init__(self, override, warn: Callable[[str], None]):
        from .. import _cache

        self.folder = _cache.cache_dir(override)
        self.warn = warn
        self.store = None
        if self.folder is not None:
            self.store = _cache.OperatorStore(self.folder, warn=warn)
        self._numerics = False
        self.prior = None  # the run's prior (abrdf_jax._prior_operator.PriorSource), if any
        from ._prefetch import Prefetch

        self.prefetch = Prefetch(self.store, warn)  # cold builds on a second core

    def numerics(self) -> None:
        """Before the first JAX work of the run: JAX's compilation cache on (once)."""
        if not self._numerics:
            from .. import _cache

            self._numerics = True
            _cache.enable_compilation_cache(self.folder, warn=self.warn)

    def operator(self, config, params, template, shared=False):
        """The operator of ``config``, ``params`` and ``template``'s layout
        (:mod:`abrdf_jax._engine`): from the store (no JAX), else built (a matrix built in
        float64, stored as float32) and stored; ``shared``: its two-stage form, whose second
        stage every layout of the setting's pairs reads (``_cache.cached_entry``)."""
        from .. import _cache

        if getattr(config, "operator_only", False):  # the prior-only model's own entries
            return config.operator(params, template, self.store, self.warn, self.numerics)
        entry = self.prefetch.take(config, params, template, shared)  # cli/_prefetch.py
        if entry is not None:  # built on the second thread
            return entry
        entry, _ = _cache.cached_entry(
            self.store, template, config, params, self.warn, before_build=self.numerics,
            shared=shared,
        )  # fmt: skip
        return entry  # callable; the shared ones' second stages batched (_engine)
