"""Caches that make a repeat call cheap (issue 13): where they live, and built operators.

One folder per user (:func:`cache_dir`) holds two caches:

- ``xla/``: JAX's persistent compilation cache (:func:`enable_compilation_cache`, from
  ``_compilation_cache``), so a function compiled once on this machine is loaded, not compiled,
  by the next process.
- ``operators/``: built reconstruction operators (:class:`OperatorStore`), one ``KEY.npz`` per
  operator, keyed by everything the matrix depends on (:func:`operator_key`). An entry is a
  numpy :class:`OperatorEntry` (``_operator_entry``) whose ``apply`` is
  :func:`abrdf_jax.compile_operator`'s single-stage map without JAX.

Every write is atomic (a temporary file in the same folder, then ``os.replace``), so processes
may share the folder. A cache that cannot be used (read-only, full, corrupt, stale) gives a
warning and a run without it, never a failure. This module imports numpy and the standard
library only; JAX is imported inside :func:`build_entry`.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import hashlib
import json
import os
import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np

from ._errors import InputError
from ._grouping import layout_key
from ._compilation_cache import XLA, Warn, default_warn, prune, touch
from ._compilation_cache import disable_compilation_cache as disable_compilation_cache
from ._compilation_cache import enable_compilation_cache as enable_compilation_cache
from ._operator_entry import OperatorEntry, digest
from .io._atomic import atomic_write, write_cause

CACHE_ENV = "ABRDF_JAX_CACHE_DIR"
NO_CACHE_ENV = "ABRDF_JAX_NO_CACHE"
#: Version of the operator entry format and key; bump it when either changes meaning.
CACHE_FORMAT = 4
#: The :class:`Config` fields that only a two-stage operator's first stage reads (the rule at
#: the centres and the values it reads): not in its second stage's key (:func:`operator_key`).
FIRST_STAGE = ("budget", "rule", "interp", "log_eps", "spike_cap", "slice_smoothing",
               "slice_count", "pairs")  # fmt: skip
#: ``cache_dir("off")``: no cache.
OFF = "off"
OPERATORS = "operators"
PRIORS = "priors"  # the default prior's subfolder (abrdf_jax.prior.default_prior)
#: Bound of ``operators/``: least recently used entries past it are removed on a save (an
#: iso102 entry is about 2.7 MB, an aniso204 one 5.4 MB, a two-stage aniso204 one 34 MB).
OPERATORS_MAX_BYTES = 1 << 30
#: dtype in which :func:`build_entry` computes the matrix (then rounded to float32).
BUILD_DTYPE = "float64"
_SUFFIX = ".npz"

__all__ = [
    "CACHE_ENV",
    "CACHE_FORMAT",
    "NO_CACHE_ENV",
    "OperatorEntry",
    "OperatorStore",
    "build_entry",
    "cache_dir",
    "cache_disabled",
    "cache_location",
    "cache_summary",
    "cached_entry",
    "clear_cache",
    "disable_compilation_cache",
    "enable_compilation_cache",
    "operator_key",
]


# ---- Where the cache lives ----


def cache_disabled(override: str | os.PathLike | None = None) -> str | None:
    """Why the cache is off (``None``: it is on): ``override == "off"`` or ``$ABRDF_JAX_NO_CACHE``
    set to anything but ``""`` or ``"0"``."""
    if override is not None and str(override) == OFF:
        return f"cache folder {OFF!r} was asked for"
    if os.environ.get(NO_CACHE_ENV, "") not in ("", "0"):
        return f"${NO_CACHE_ENV} is set"
    return None


def cache_location(override: str | os.PathLike | None = None) -> Path | None:
    """The cache folder, whether or not the cache is on: ``override``, else
    ``$ABRDF_JAX_CACHE_DIR``, else ``$XDG_CACHE_HOME/abrdf_jax``, else ``~/.cache/abrdf_jax``
    (``None`` only when no home folder can be found)."""
    for value in (override, os.environ.get(CACHE_ENV)):
        if value is not None and str(value) not in ("", OFF):
            return Path(os.path.abspath(os.path.expanduser(value)))
    xdg = os.environ.get("XDG_CACHE_HOME", "")
    if os.path.isabs(xdg):  # the XDG spec: a relative value is ignored
        return Path(xdg) / "abrdf_jax"
    try:
        return Path.home() / ".cache" / "abrdf_jax"
    except (RuntimeError, KeyError):  # no $HOME and no password entry
        return None


def cache_dir(override: str | os.PathLike | None = None) -> Path | None:
    """The cache folder to use, or ``None`` when the cache is off (:func:`cache_disabled`).

    The folder is not created here; each cache creates its subfolder on its first write.
    """
    return None if cache_disabled(override) else cache_location(override)


# ---- The key: everything the matrix depends on ----


def _canon(value):
    """A JSON value that is the same for equal settings (numbers as floats, tuples as lists)."""
    if isinstance(value, (bool, str)) or value is None:
        return value
    if isinstance(value, (int, float, np.integer, np.floating)):
        return float(value)
    if isinstance(value, (tuple, list)):
        return [_canon(v) for v in value]
    if hasattr(value, "shape") and hasattr(value, "dtype"):  # a numpy or JAX array
        return [float(v) for v in np.asarray(value, np.float64).reshape(-1)]
    raise TypeError(f"cannot key a cache entry on {type(value).__name__} {value!r}")


def package_version() -> str:
    """The package's version (its source tree's ``__version__``)."""
    from . import __version__

    return __version__


@functools.lru_cache(maxsize=1)
def _code_digest() -> str:
    """sha256 of the package's root modules: the numerics an operator is built from. An editable
    install keeps one version number while its code changes; a changed module is a new key."""
    h = hashlib.sha256()
    for path in sorted(Path(__file__).parent.glob("*.py")):
        with contextlib.suppress(OSError):
            h.update(path.name.encode() + b"\0" + path.read_bytes())
    return h.hexdigest()


@functools.lru_cache(maxsize=None)
def _dist_version(name: str) -> str:
    try:
        from importlib.metadata import version

        return version(name)
    except Exception:  # noqa: BLE001 - not installed as a distribution
        return ""


def config_doc(config) -> dict:
    """Every field of a :class:`Config` as canonical JSON (part of a cache key)."""
    return {
        "type": type(config).__qualname__,
        **{f.name: _canon(getattr(config, f.name)) for f in dataclasses.fields(config)},
    }


def operator_key(
    config,
    params,
    meas,
    *,
    build_dtype: str = BUILD_DTYPE,
    extra: dict | None = None,
    centres: bool = False,
) -> str:
    """The cache key of the operator built for ``config``, ``params`` and ``meas``'s layout.

    sha256 (hex) of a canonical JSON of: the package version, :data:`CACHE_FORMAT`, a digest of
    the package's modules, the JAX/jaxlib versions and ``JAX_PLATFORMS`` (they change the built
    matrix's rounding), the entry dtype and the build dtype, every :class:`Config` field, the
    parameter values (α, widths, λ) and the layout (:func:`abrdf_jax._grouping.layout_key`, and
    the slice parameters' dtype), and ``extra`` (what else an entry of
    another kind depends on, canonical JSON). ``centres``: the key of a two-stage entry's
    second stage, which depends on the elevation pairs and the centres' layout but not on where
    the samples lie, on α nor on the :data:`FIRST_STAGE` settings (:func:`cached_entry`;
    ``OperatorEntry.for_layout`` sets them). No JAX is imported.
    """
    t = np.asarray(meas.t)
    count = np.asarray(meas.count).astype(np.int64)
    if t.ndim != 2 or count.shape != (t.shape[0],):
        raise InputError(f"operator_key needs one measurement's layout, got t of shape {t.shape}")
    names = ("widths", "reg") if centres else ("alpha", "widths", "reg")
    settings = config_doc(config)
    if centres:  # the second stage: no first-stage setting (one map for the rules, budgets)
        pairs = [[float(v) for v in p] for p in meas.pairs]
        layout = {"centres": [pairs, meas.centre_azimuths]}
        settings = {n: v for n, v in settings.items() if n not in FIRST_STAGE}
    else:
        layout = {"key": layout_key(meas), "t_dtype": t.dtype.name}
    doc = {
        "format": CACHE_FORMAT,
        "version": package_version(),
        "code": _code_digest(),
        "jax": [_dist_version("jax"), _dist_version("jaxlib")],
        "platforms": os.environ.get("JAX_PLATFORMS", ""),
        "dtype": "float32",
        "build_dtype": build_dtype,
        "config": settings,
        "params": {n: _canon(getattr(params, n)) for n in names},
        "layout": layout,
    }
    if extra is not None:
        doc["extra"] = extra
    text = json.dumps(doc, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()


# ---- The store ----


class OperatorStore:
    """Operator entries on disk, ``folder / "operators" / f"{key}.npz"``; never fatal.

    An entry file holds the arrays, its own key, :data:`CACHE_FORMAT` and a CRC-32C of the arrays;
    :meth:`load` checks all three (and the shapes), so a truncated, corrupt or misplaced entry is
    a warning, is removed when possible, and reads as a miss.
    """

    def __init__(
        self,
        folder: str | os.PathLike,
        warn: Warn = default_warn,
        max_bytes: int = OPERATORS_MAX_BYTES,
    ):
        self.folder = Path(folder) / OPERATORS
        self.warn = warn
        self.max_bytes = max_bytes
        self._warned: set[str] = set()

    def path(self, key: str) -> Path:
        return self.folder / f"{key}{_SUFFIX}"

    def _warn_once(self, token: str, message: str, warn: Warn | None) -> None:
        """Warn about ``token`` (an entry's key, or ``"write"`` for the folder) once."""
        if token not in self._warned:
            self._warned.add(token)
            (self.warn if warn is None else warn)(message)

    def load(self, key: str, warn: Warn | None = None, kind=OperatorEntry):
        """The entry stored under ``key``, or ``None`` (a miss, or a bad entry: warned, removed).

        ``kind``: the entry class (:class:`OperatorEntry`, or ``_prior_entry.PriorEntry``): its
        ``KIND``, ``ARRAYS``, ``check`` and ``from_stored``."""
        path = self.path(key)
        try:
            with np.load(path, allow_pickle=False) as f:
                meta = json.loads(str(f["meta"][()]))
                same = isinstance(meta, dict) and meta.get("kind", OperatorEntry.KIND) == kind.KIND
                arrays = {n: f[n] for n in kind.ARRAYS} if same else {}  # else: rejected below
        except (FileNotFoundError, NotADirectoryError):  # a miss (a broken folder warns on save)
            return None
        except Exception as e:  # noqa: BLE001 - a truncated or corrupt file of any kind
            return self._reject(key, path, f"unreadable ({type(e).__name__}: {e})", warn)
        problem = _check_entry(key, arrays, meta, kind)
        if problem:
            return self._reject(key, path, problem, warn)
        touch(path)
        return kind.from_stored(arrays, meta)

    def _reject(self, key: str, path: Path, why: str, warn: Warn | None) -> None:
        removed = True
        try:
            path.unlink()
        except FileNotFoundError:
            pass
        except OSError:
            removed = False
        action = "removed it" if removed else "could not remove it"
        self._warn_once(key, f"operator cache entry {path} is {why}; {action} and rebuilding", warn)
        return None

    def save(self, key: str, entry, warn: Warn | None = None) -> bool:
        """Store ``entry`` (of any kind) under ``key`` atomically; ``False`` (and a warning)
        when it cannot."""
        arrays = entry.arrays()
        meta = {
            "key": key,
            "format": CACHE_FORMAT,
            "kind": entry.KIND,
            "crc32c": digest(arrays),
            **entry.meta(),
            "version": package_version(),
        }
        try:
            self.folder.mkdir(parents=True, exist_ok=True)
            with atomic_write(self.path(key), "wb") as f:
                np.savez(f, meta=np.array(json.dumps(meta)), **arrays)
        except (OSError, InputError) as e:  # read-only, full, not a folder: atomic_write says which
            why = write_cause(e)
            self._warn_once(
                "write",
                f"cannot write the operator cache {self.folder} ({why}); running without it",
                warn,
            )
            return False
        prune(self.folder, f"*{_SUFFIX}", self.max_bytes, keep=self.path(key))
        return True

    def entries(self) -> list[Path]:
        """The entry files (``KEY.npz``)."""
        return sorted(self.folder.glob(f"*{_SUFFIX}")) if self.folder.is_dir() else []

    def size(self) -> int:
        """Bytes in the store's folder (entries and any temporary files left by a killed writer)."""
        return folder_size(self.folder)[0]

    def clear(self) -> None:
        """Remove every entry (and the store's folder)."""
        if self.folder.exists():
            shutil.rmtree(self.folder)


def _check_entry(key: str, arrays: dict[str, np.ndarray], meta: dict, kind) -> str | None:
    """What is wrong with a loaded entry (``None``: nothing)."""
    if not isinstance(meta, dict):
        return "malformed (no metadata)"
    if meta.get("format") != CACHE_FORMAT:
        return f"of another format ({meta.get('format')!r}, this version reads {CACHE_FORMAT})"
    if meta.get("key") != key:
        return f"stored under another key ({str(meta.get('key'))[:12]}...)"
    if meta.get("kind", OperatorEntry.KIND) != kind.KIND:
        return f"of another kind ({meta.get('kind')!r}, expected {kind.KIND!r})"
    if meta.get("crc32c") != digest(arrays):
        return "corrupt (its checksum does not match)"
    return kind.check(arrays, meta)


def folder_size(folder: Path) -> tuple[int, int]:
    """``(bytes, files)`` under ``folder`` (``(0, 0)`` when it does not exist)."""
    total = files = 0
    for root, _, names in os.walk(folder):
        for name in names:
            with contextlib.suppress(OSError):
                total += os.stat(os.path.join(root, name)).st_size
                files += 1
    return total, files


def cache_summary(folder: Path) -> dict:
    """Size and entry counts of the caches in ``folder``."""
    xla_bytes, _ = folder_size(folder / XLA)
    xla_entries = len(list((folder / XLA).glob("*-cache"))) if (folder / XLA).is_dir() else 0
    store = OperatorStore(folder)
    return {
        XLA: {"bytes": xla_bytes, "entries": xla_entries},
        OPERATORS: {"bytes": store.size(), "entries": len(store.entries())},
        PRIORS: {
            "bytes": folder_size(folder / PRIORS)[0],
            "entries": len(list((folder / PRIORS).glob("*.npz")))
            if (folder / PRIORS).is_dir()
            else 0,
        },
    }


def clear_cache(folder: Path) -> None:
    """Remove the caches (``xla/``, ``operators/``, ``priors/``) under ``folder``; nothing else."""
    for name in (XLA, OPERATORS, PRIORS):
        if (folder / name).exists():
            shutil.rmtree(folder / name)


# ---- Build, or load when cached ----


def build_entry(
    meas, config, params, *, build_dtype: str = BUILD_DTYPE, before_jax=None, two_stage=False
) -> OperatorEntry:
    """Build the operator of :func:`abrdf_jax.compile_operator` as a float32 entry.

    The matrix is computed in ``build_dtype``: float64 (the default) in numpy, without JAX
    (:mod:`abrdf_jax._host_build`; the JAX build, in a scoped ``jax.enable_x64``, only where
    the RBF system stays singular after the guard), float32 by the JAX build; it is rounded
    to float32 once (``before_jax()``, when given, runs before any JAX work: the command
    line turns on JAX's compilation cache there). Applied in float32 it matches the
    float64 reconstruction to float32 rounding (tests/test_cache.py), which a float32 build
    does not: its RBF solve is off by about 4e-4 of the table's maximum (docs/cache.md).

    A rule that is not linear in the samples but affine in the slice terms (``"filip2012"`` on
    the log of the samples, ``--model aniso``) is a two-stage entry: the rule per material in
    numpy, then the matrix from the RBF centres (:mod:`abrdf_jax._centre_step`); so is any
    affine rule on the log of the samples with ``two_stage`` (:func:`cached_entry`).

    Raises:
        InputError: for settings that are not linear in the (log) samples, as
            ``compile_operator`` does, except the two-stage ones above (the rule ``"log"``, a
            nonlinear rule on linear values, or ``value_space="log"``).
    """
    from ._centre_step import CentreStep, nonlinear_mode
    from ._host_build import host_matrix_or_none
    from ._names import LOG_SAMPLES

    mode = "two_stage" if two_stage else nonlinear_mode(config, meas)  # (numpy: no JAX)
    built = host_matrix_or_none(config, params, meas, mode) if build_dtype == "float64" else None
    if built is None:
        if before_jax is not None:
            before_jax()
        from ._operator import operator_matrix

        # Host inputs straight into the one compiled build: no eager JAX operation (each
        # compiles a small program on a cold call; _operator.operator_matrix).
        with x64_scope(build_dtype == "float64"):
            built = operator_matrix(config, params, meas, build_dtype=build_dtype, nonlinear=mode)
    step = CentreStep.of(config, params, meas) if built.stage == "two_stage" else None
    matrix = np.asarray(built.matrix)
    return OperatorEntry(
        matrix=np.ascontiguousarray(matrix.astype(np.float32)),
        index=np.asarray(built.index, np.int64),
        t=np.asarray(built.t, np.float32),
        count=np.asarray(built.count, np.int32),
        keep=np.asarray(built.keep, np.int32),
        log_samples=config.value_space in LOG_SAMPLES,
        log_eps=float(config.log_eps),
        spike_cap=config.spike_cap,
        slice_smoothing=config.slice_smoothing,
        subspace=step,
    )


def x64_scope(on: bool):
    """A context in which JAX computes in float64 (``on``), whatever the global switch."""
    import jax

    if not on or jax.config.jax_enable_x64:
        return contextlib.nullcontext()
    scope = getattr(jax, "enable_x64", None)
    if scope is not None:
        return scope(True)
    from jax.experimental import enable_x64  # JAX before jax.enable_x64

    return enable_x64()


def _fits(entry: OperatorEntry, meas) -> bool:
    count = np.asarray(meas.count)
    return entry.t.shape == tuple(np.shape(meas.t)[-2:]) and np.array_equal(entry.count, count)


def cached_entry(
    store: OperatorStore | None,
    meas,
    config,
    params,
    warn: Warn = default_warn,
    before_build: Callable[[], None] | None = None,
    shared: bool = False,
) -> tuple[OperatorEntry, bool]:
    """The operator entry for ``(config, params, meas's layout)``: ``(entry, hit)``.

    Loaded from ``store`` when it holds a valid entry (``hit=True``); else built (in numpy;
    ``before_build()`` before any JAX work, :func:`build_entry`) and saved. ``store=None``:
    always built. A store that cannot be read or written gives a warning through ``warn`` and
    the built entry. A two-stage entry (``_centre_step.host_two_stage``, or any affine rule on
    the log of the samples with ``shared``: a folder's many small layouts, ``_engine``) is
    stored once per setting, pairs and centre layout, whatever the samples' layout and α, and
    kept in memory (:data:`SHARED_ENTRIES`; without a store too) for the next layout.

    Raises:
        InputError: for nonlinear settings (see :func:`build_entry`).
    """
    from ._centre_step import host_two_stage

    shared = shared or host_two_stage(config, meas)  # a second stage any layout of its pairs reads
    if store is None and not shared:  # (no store: a shared entry is kept in memory only)
        return build_entry(meas, config, params, before_jax=before_build), False
    key = operator_key(config, params, meas, centres=shared)
    memo = ("" if store is None else str(store.folder), key)
    entry = _SHARED.get(memo) if shared else None
    hit = entry is not None
    if entry is None and store is not None:
        entry = store.load(key, warn)
        hit = entry is not None and (shared or _fits(entry, meas))
    if not hit:
        entry = build_entry(meas, config, params, before_jax=before_build, two_stage=shared)
        if store is not None:
            store.save(key, entry, warn)
    if shared:
        _SHARED[memo] = entry
        while len(_SHARED) > SHARED_ENTRIES:
            _SHARED.pop(next(iter(_SHARED)))
        entry = entry.for_layout(config, params, meas)
    return entry, hit


#: Two-stage entries kept in memory after a load or a build (by store folder and key): a folder
#: of dense or jittered captures (a layout each) reads one shared second stage, loaded once.
SHARED_ENTRIES = 2
_SHARED: dict[tuple[str, str], OperatorEntry] = {}
