"""The prior-only model on the operator path: which prior, its operator per layout, its key.

``abrdf-jax reconstruct --model prior [--prior FILE]`` reconstructs with a learned prior alone
(:func:`abrdf_jax.prior.reconstruct_prior`). For one sample layout that is the numpy
:class:`~abrdf_jax._prior_entry.PriorEntry` (map → matrix → inverse map), built once (JAX, in
float64, rounded to float32) and kept in the operator store under :func:`prior_entry_key`: the
layout's digest, α and the slices used, the prior file's sha256, λ, the package version and
code. A stored entry is applied without JAX.

- :class:`PriorSource`: the prior of a run: its file (the default prior's lives in the cache,
  ``<cache>/priors/``), the file's sha256, λ and what the model record says of it; resolved
  with numpy only when the file exists (:func:`resolve_prior`).
- :class:`PriorModel`: the source and the budget (``iso102``: the diagonal slices only); what the
  command line passes to :func:`abrdf_jax._engine.reconstruct_many` in place of a
  :class:`~abrdf_jax.Config` (``operator_only``: every layout is one operator, whatever its
  group's size: a prior entry is cheap to build).
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import hashlib
import json
import os
from pathlib import Path

import numpy as np

from ._errors import InputError
from ._prior_entry import PriorEntry
from .io._atomic import file_sha256 as _file_sha256

#: ``--prior default``: the package's default prior (docs/prior.md), built on first use.
DEFAULT = "default"
#: Version of the prior entry key; bump it when the entry changes meaning.
ENTRY_FORMAT = 3


@dataclasses.dataclass(frozen=True)
class PriorSource:
    """The prior of a run (see the module docstring).

    Attributes:
        file: the prior file (``None``: built in memory, the cache being off).
        sha256: sha256 of the file's bytes (in memory: of its arrays and metadata).
        lam: the ridge λ used (the prior's own).
        info: JSON text of what the model record says of the prior.
        fused: JSON text of the fused model's fixed hyper-parameters (the file's own, else the
            package's defaults; :func:`abrdf_jax.prior._fused_settings.fused_settings`).
    """

    file: str | None
    sha256: str
    lam: float
    info: str
    fused: str = "{}"
    memory: object = dataclasses.field(default=None, compare=False, hash=False, repr=False)

    def record(self) -> dict:
        return json.loads(self.info)

    def fused_settings(self) -> dict:
        return json.loads(self.fused)

    def load(self):
        """The :class:`~abrdf_jax.prior.Prior` (imports JAX; read once per process)."""
        return self.memory if self.memory is not None else _load(self.file, self.sha256)


@functools.lru_cache(maxsize=4)
def _load(path: str, sha256: str):
    from .prior._file import load_prior

    return load_prior(path)


def _summary(path, sha, arrays, meta, default: bool) -> PriorSource:
    from .prior._fused_settings import fused_settings

    lam = float(arrays["lam"])
    n = len(meta.get("trained_on", []))
    prov = meta.get("provenance") or (
        f"trained on {n} tables (abrdf-jax prior info FILE lists them)"
    )
    info = {
        "file": None if path is None else str(path),
        "sha256": sha,
        "default": default,
        "format": meta.get("format"),
        "channels": meta.get("channels"),
        "eps": meta.get("eps"),
        "n_components": int(arrays["components"].shape[1]),
        "lam": lam,
        "n_materials": n,
        "package_version": meta.get("package_version"),
        "provenance": prov,
        **({"licence": meta["licence"]} if "licence" in meta else {}),
    }
    fused = json.dumps(fused_settings(meta), sort_keys=True)
    return PriorSource(None if path is None else str(path), sha, lam, json.dumps(info), fused)


def read_source(path, default: bool = False) -> PriorSource:
    """A prior file as a :class:`PriorSource` (numpy only; every field checked).

    Raises:
        InputError: naming the file (and the field): missing, truncated, corrupt, another
            format version (:func:`abrdf_jax.prior.read_prior_file`).
    """
    from .prior._file import read_prior_file

    path = Path(path)
    arrays, meta = read_prior_file(path)
    return _summary(path, _file_sha256(path), arrays, meta, default)


def resolve_prior(spec: str | os.PathLike | None, cache_override=None) -> PriorSource:
    """The prior named by ``--prior``: a file, or ``None``/``"default"`` for the default prior.

    The default prior is read from the cache folder with numpy only when it is there; else it is
    built (JAX, a few seconds) and cached; with the cache off it is built in memory.
    """
    if spec is not None and str(spec) != DEFAULT:
        return read_source(spec)
    from .prior._default import default_prior, default_prior_path

    path = default_prior_path(cache_override)
    if path is not None and path.exists():
        with contextlib.suppress(InputError):  # damaged: rebuilt below (with a warning)
            return read_source(path, default=True)
    prior = default_prior(cache_override)  # builds and caches (warns when it cannot)
    if path is not None and path.exists():
        with contextlib.suppress(InputError):
            return read_source(path, default=True)
    return _in_memory(prior)


def _in_memory(prior) -> PriorSource:
    """A prior that has no file (the default prior with the cache off)."""
    from ._operator_entry import digest

    from .prior._file import ARRAYS, OPTIONAL

    names = (*ARRAYS, *OPTIONAL)
    arrays = {n: np.asarray(getattr(prior, n)) for n in names if getattr(prior, n) is not None}
    meta = {**prior.metadata, "format": None, "channels": prior.channels, "eps": prior.eps}
    sha = hashlib.sha256((digest(arrays) + json.dumps(meta, sort_keys=True)).encode()).hexdigest()
    src = _summary(None, sha, arrays, meta, default=True)
    return dataclasses.replace(src, memory=prior)


@dataclasses.dataclass(frozen=True)
class LearnedModel:
    """A model that reads a prior, for one budget: what the command line passes to
    :func:`abrdf_jax._engine.reconstruct_many` in place of a :class:`~abrdf_jax.Config`.
    Subclasses say ``name``, ``entry_kind``, ``key_doc()`` and ``build(template, params)``."""

    source: PriorSource
    budget: str

    #: :func:`abrdf_jax._engine.reconstruct_many`: every layout is one operator.
    operator_only = True

    def slice_counts(self, meas) -> np.ndarray:
        return slice_counts(meas, self.budget)

    def operator(self, params, template, store=None, warn=None, before_build=None):
        """The apply function of ``template``'s layout: from ``store``, else built (and stored)."""
        entry, _ = cached_prior_entry(store, template, self, params, warn, before_build)
        return entry.apply


@dataclasses.dataclass(frozen=True)
class PriorModel(LearnedModel):
    """The prior-only model of one budget (see the module docstring)."""

    name = "prior"
    entry_kind = PriorEntry

    def key_doc(self) -> dict:
        """What the entry depends on besides the layout, α and the code (part of its key)."""
        return {"format": ENTRY_FORMAT, "lam": float(self.source.lam)}

    def build(self, template, params) -> PriorEntry:
        counts = self.slice_counts(template)
        src = self.source
        return build_prior_entry(src.load(), template, params.alpha, src.lam, counts)


def slice_counts(meas, budget: str | None) -> np.ndarray:
    """The counts of the slices the prior reads: ``iso102`` leaves the axial ones out."""
    count = np.asarray(meas.count).astype(np.int64)
    if budget == "iso102":
        count = count.copy()
        count[0::2] = 0
    return count


def _code_digest() -> str:
    """The package's numerics (root modules) and the prior package's: a changed module is a new
    key, as for the RBF's entries."""
    from . import _cache

    h = hashlib.sha256(_cache._code_digest().encode())
    for path in sorted((Path(__file__).parent / "prior").glob("*.py")):
        with contextlib.suppress(OSError):
            h.update(path.name.encode() + b"\0" + path.read_bytes())
    return h.hexdigest()


def prior_entry_key(model, meas, params) -> str:
    """The store key of a learned model's entry (:class:`PriorModel`, or the fused model's
    :class:`abrdf_jax._fused_operator.FusedModel`) for ``meas``'s layout at α =
    ``params.alpha``: its kind, the prior file's sha256, the model's own ``key_doc()``, the
    budget, the layout, the slices read, the package version and code, JAX's version."""
    from . import _cache
    from ._grouping import layout_key

    own = model.key_doc()
    doc = {
        "kind": model.entry_kind.KIND,
        "format": [_cache.CACHE_FORMAT, own.pop("format")],
        "version": _cache.package_version(),
        "code": _code_digest(),
        "jax": [_cache._dist_version("jax"), _cache._dist_version("jaxlib")],
        "prior_sha256": model.source.sha256,
        **own,
        "budget": model.budget,
        "alpha": float(np.asarray(params.alpha, np.float64)),
        "layout": layout_key(meas),
        "counts": model.slice_counts(meas).tolist(),
    }
    text = json.dumps(doc, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()


def _ridge_gain(prior, meas, alpha, lam, index):
    """``(ridge operator, x_ref,s, cos θv,s, μ_s)`` on the valid samples ``index`` (traced)."""
    from .prior._reconstruct import ridge_operator, sample_basis

    basis = sample_basis(prior, meas, alpha).take(index)
    return ridge_operator(basis, lam), basis.reference, basis.cos_v, basis.mean


@functools.cache
def _jitted_ridge_gain():
    """:func:`_ridge_gain` jitted: one compile instead of an eager dispatch per operation (the
    exact basis evaluates the prior's training materials)."""
    from ._build_jit import build_jit  # built once per layout: compiled cheaply

    return build_jit(_ridge_gain)


def build_prior_entry(prior, meas, alpha, lam, counts) -> PriorEntry:
    """The :class:`PriorEntry` of ``prior`` at ``meas``'s layout (α in radians), reading the
    samples within ``counts`` per slice; computed in float64 (JAX), stored as float32."""
    import jax.numpy as jnp

    from ._cache import x64_scope

    with x64_scope(True):
        f64 = jnp.float64
        p = prior.astype(f64)
        index, m = float64_template(meas, counts)
        out = _jitted_ridge_gain()(
            p, m, jnp.asarray(alpha, f64), jnp.asarray(lam, f64), jnp.asarray(index)
        )
        r, ref_s, cos_s, mean_s = (np.asarray(a, np.float64) for a in out)
        ref_g, cos_g = (np.asarray(a, np.float64) for a in p.grid_layout())
        mean, comps = np.asarray(p.mean), np.asarray(p.components)
    eps = float(prior.eps)
    return PriorEntry(
        right=f32(r),
        shift=f32(r @ (np.log(ref_s * cos_s + eps) + mean_s)),
        left=f32(comps),
        offset=f32(mean + grid_lift(ref_g, cos_g, eps)),
        **entry_layout(prior, index, meas, cos_s, ref_g, cos_g),
    )


def f32(a) -> np.ndarray:
    """A built entry's array as stored: float32, contiguous."""
    return np.ascontiguousarray(a, np.float32)


def float64_template(meas, counts):
    """``(index, m)`` for building a learned model's entry (inside ``x64_scope(True)``): the
    flat index of the samples within ``counts`` per slice, and ``meas`` as JAX arrays with
    float64 slice parameters and ``counts``."""
    import jax.numpy as jnp

    from ._engine import as_jax

    t = np.asarray(meas.t)
    index = np.flatnonzero(np.arange(t.shape[1])[None, :] < np.asarray(counts)[:, None])
    m = as_jax(meas, None)[0]
    m = m.replace(t=jnp.asarray(t, jnp.float64), count=jnp.asarray(counts, m.count.dtype))
    return index, m


def grid_lift(ref_g, cos_g, eps: float) -> np.ndarray:
    """``ln((x_ref cos θv + ε) / cos θv)`` on the grid: a mapped value plus this is the log the
    learned entries' product yields, ``ln((x cos θv + ε) / cos θv)``."""
    return np.log((ref_g * cos_g + eps) / cos_g)


def entry_layout(prior, index, meas, cos_s, ref_g, cos_g) -> dict:
    """The fields every learned model's entry shares: the map's ``cos θv`` at the samples,
    floor and clip (``top``) on the grid, the template's layout, ε and the width.

    ``top``: the prior's ceiling (:func:`abrdf_jax.prior.below_ceiling`) in the units of the
    entry's product, ``ln((x cos θv + ε) / cos θv)``: ``ceiling + CEILING_MARGIN +
    ln((x_ref cos θv + ε) / cos θv)``; float32's largest value for a prior without one."""
    from .prior._mapping import CEILING_MARGIN

    eps = float(prior.eps)
    if prior.ceiling is None:
        top = np.full(np.shape(cos_g), np.finfo(np.float32).max, np.float32)
    else:
        top = np.asarray(prior.ceiling, np.float64) + CEILING_MARGIN
        top = f32(top + grid_lift(ref_g, cos_g, eps))
    return dict(
        cos_in=f32(cos_s),
        floor=f32(eps / cos_g),
        top=top,
        index=index.astype(np.int64),
        t=f32(np.asarray(meas.t)),
        count=np.asarray(meas.count, np.int32),
        eps=eps,
        width=3 if prior.channels == "joint" else 1,
    )


def cached_prior_entry(store, template, model, params, warn=None, before_build=None):
    """``(entry, hit)``: a learned model's entry for ``template``'s layout, from ``store`` (no
    JAX) when it holds a valid one, else built (``before_build()`` first) and saved."""
    from ._cache import _fits

    key = prior_entry_key(model, template, params)
    if store is not None:
        entry = store.load(key, warn, kind=model.entry_kind)
        if entry is not None and _fits(entry, template):
            return entry, True
    if before_build is not None:
        before_build()
    entry = model.build(template, params)
    if store is not None:
        store.save(key, entry, warn)
    return entry, False
