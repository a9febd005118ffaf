"""The held-out errors of the learned models (prior only, fused) as numpy matrices:
``--model auto --prior`` without JAX once the entries are stored.

For fixed hyper-parameters (the prior's λ; the fused model's fixed numbers) the held-out
prediction of fold ``j`` is an affine map of its training samples' log values
(:class:`~abrdf_jax.select._prior.HeldOutMap`: ``gain``, ``offset`` and the ``cos θv`` of the
map at the training and held-out positions), then the inverse map. :class:`LearnedHeldOutEntry`
holds those maps for one layout, α, budget, prior and model, built once in float64 (JAX, the
same :func:`~abrdf_jax.select._prior.prior_map` / :func:`~abrdf_jax.select._fused.fused_map`
that the JAX held-out errors use), stored as float32 in the operator store beside the RBF's
held-out entries (:mod:`abrdf_jax.select._held_out_entry`), and applied here with numpy: the
same folds, residual and ε as every other candidate. Its errors equal the JAX path's to float32
rounding (tests/test_learned_entry.py). This module imports numpy only.
"""

from __future__ import annotations

import dataclasses
import functools
import types

import numpy as np

from .._folds import fold_slots, log_residual
from .._host_eps import sample_eps
from .._operator_entry import check_layout

#: Version of the entry key; bump it when the entry changes meaning.
ENTRY_FORMAT = 1


@dataclasses.dataclass(frozen=True, eq=False)
class LearnedHeldOutEntry:
    """One learned model's held-out folds on one layout as affine maps (module docstring).

    Attributes:
        gain: ``(k, q·w, S·nmax·w)`` float32: fold ``j``'s map from the log values at its
            training slots to the mapped prediction at its held-out slots (``w``: 1 for a
            ``shared`` prior, one row per channel; 3 for ``joint``).
        offset: ``(k, q·w)``; cos_train: ``(k, S·nmax·w)``; cos_test: ``(k, q·w)`` float32.
        train, test: ``(k, S, nmax)`` / ``(k, S, q/S)`` int64 flat slots of the samples each fold
            trains on / holds out (``abrdf_jax._folds.fold_slots``; ``-1``: none).
        t, count: the template's layout (checked against the inputs).
        eps: ε of the prior's map; width: ``w``; res_log_eps: the ε of the held-out residual.
    """

    gain: np.ndarray
    offset: np.ndarray
    cos_train: np.ndarray
    cos_test: np.ndarray
    train: np.ndarray
    test: np.ndarray
    t: np.ndarray
    count: np.ndarray
    eps: float
    width: int
    res_log_eps: float

    KIND = "learned-held-out"
    ARRAYS = ("gain", "offset", "cos_train", "cos_test", "train", "test", "t", "count")

    def errors(self, y) -> np.ndarray:
        """RMS held-out log errors ``(B,)`` of stacked sample values ``(B, S, nmax, 3)``."""
        y = np.asarray(y, np.float32)
        s, nmax = self.t.shape
        b = y.shape[0]
        flat = y.reshape(b, s * nmax, 3)
        valid = (np.arange(nmax)[None, :] < self.count[:, None]).reshape(-1)
        res_eps = sample_eps(flat[:, valid], self.res_log_eps, axis=1)[:, None, :]  # (B, 1, 3)
        eps, w = np.float32(self.eps), self.width
        total, n = np.zeros(b), 0
        for j in range(self.gain.shape[0]):
            train = self.train[j].reshape(-1)
            x = np.where((train >= 0)[None, :, None], flat[:, np.maximum(train, 0)], 0)
            # rows of the map: (n_train·w, B·R), R = 3 right sides (shared) or 1 (joint)
            x = x.reshape(b, -1, 3 // w).transpose(1, 0, 2).reshape(x.shape[1] * w, -1)
            x = np.log(np.maximum(x, 0) * self.cos_train[j][:, None] + eps)
            m = self.gain[j] @ x + self.offset[j][:, None]
            pred = np.maximum((np.exp(m) - eps) / self.cos_test[j][:, None], 0)
            pred = pred.reshape(-1, b, 3 // w).transpose(1, 0, 2).reshape(b, -1, 3)
            test = self.test[j].reshape(-1)
            held = flat[:, np.maximum(test, 0)]
            mask = (test >= 0)[None, :, None]
            r = log_residual(pred, held, res_eps, mask, xp=np)
            total += np.sum(np.square(r, dtype=np.float64), axis=(1, 2))
            n += int(mask.sum()) * 3
        return np.sqrt(total / max(n, 1))

    def arrays(self) -> dict[str, np.ndarray]:
        return {name: getattr(self, name) for name in self.ARRAYS}

    def meta(self) -> dict:
        return {
            "eps": float(self.eps),
            "width": int(self.width),
            "res_log_eps": float(self.res_log_eps),
        }

    @classmethod
    def from_stored(cls, arrays: dict[str, np.ndarray], meta: dict) -> "LearnedHeldOutEntry":
        return cls(**arrays, eps=meta["eps"], width=meta["width"], res_log_eps=meta["res_log_eps"])

    @staticmethod
    def check(arrays: dict[str, np.ndarray], meta: dict) -> str | None:
        """What is wrong with stored arrays and scalars (``None``: nothing)."""
        w, eps, res = meta.get("width"), meta.get("eps"), meta.get("res_log_eps")
        if w not in (1, 3) or not isinstance(eps, float) or not eps > 0:
            return "malformed (no prior map)"
        if not isinstance(res, float):
            return "malformed (no residual ε)"
        g, o, ct, cs = (arrays[n] for n in ("gain", "offset", "cos_train", "cos_test"))
        train, test, t = arrays["train"], arrays["test"], arrays["t"]
        if t.ndim != 2 or train.ndim != 3 or test.ndim != 3:
            return "malformed (inconsistent array shapes)"
        index = np.flatnonzero(np.arange(t.shape[-1])[None, :] < arrays["count"][:, None])
        problem = check_layout({**arrays, "index": index}, index.size)
        k, n_tr, n_te = g.shape[0] if g.ndim == 3 else -1, t.size * w, test[0].size * w
        if (
            problem
            or any(a.dtype != np.float32 for a in (g, o, ct, cs))
            or g.shape != (k, n_te, n_tr)
            or o.shape != (k, n_te)
            or ct.shape != (k, n_tr)
            or cs.shape != (k, n_te)
            or train.shape != (k, *t.shape)
            or test.shape[:2] != (k, t.shape[0])
            or max(train.max(initial=-1), test.max(initial=-1)) >= t.size
        ):
            return problem or "malformed (inconsistent array shapes)"
        if not all(np.isfinite(a).all() for a in (g, o, ct, cs)) or not (cs > 0).all():
            return "malformed (non-finite values)"
        return None


@dataclasses.dataclass(frozen=True)
class _HeldOutKind:
    """What :func:`abrdf_jax._prior_operator.prior_entry_key` reads of a model, for the
    held-out entry of a learned ``model`` with ``k`` folds."""

    model: object
    k: int
    entry_kind = LearnedHeldOutEntry

    @property
    def source(self):
        return self.model.source

    @property
    def budget(self):
        return self.model.budget

    def slice_counts(self, meas):
        return self.model.slice_counts(meas)

    def key_doc(self) -> dict:
        own = self.model.key_doc()
        return {**own, "format": [ENTRY_FORMAT, own["format"]], "k": self.k, "of": self.model.name}


def build_entry(model, meas, alpha_deg: float, k: int) -> LearnedHeldOutEntry:
    """Build the held-out entry of a learned ``model`` (``PriorModel`` or ``FusedModel``) on
    ``meas``'s layout (imports JAX; the maps in float64, stored as float32)."""
    import jax.numpy as jnp

    from .. import _cache
    from .._config import Config
    from .._engine import as_jax
    from .._prior_operator import f32
    from ._prior import prior_fold_data

    meas, _ = as_jax(meas, None)
    prior = model.source.load()
    with _cache.x64_scope(True):
        f64 = jnp.float64
        p = prior.astype(f64)
        m64 = meas.replace(t=jnp.asarray(meas.t, f64), y=jnp.asarray(meas.y, f64))
        data = prior_fold_data(m64, np.deg2rad(alpha_deg), k, model.budget)
        folds = (data["train"], data["test"])
        if model.name == "fused":
            from ..prior._covariance import FusedHyper

            settings = model.source.fused_settings()
            hyper = FusedHyper.from_settings(settings, f64)
            hm = _jitted_maps()(p, hyper, folds, data["alpha"], settings["reference"])
        else:
            lam = jnp.asarray(model.source.lam, f64)
            hm = _jitted_maps()(p, lam, folds, data["alpha"], None)
        gain, offset, cos_train, cos_test = (np.asarray(a, np.float64) for a in hm)
    slots_train, slots_test = fold_slots(np.asarray(meas.count), meas.t.shape[-1], k)
    return LearnedHeldOutEntry(
        gain=f32(gain),
        offset=f32(offset),
        cos_train=f32(cos_train),
        cos_test=f32(cos_test),
        train=slots_train,
        test=slots_test,
        t=np.asarray(meas.t, np.float32),
        count=np.asarray(meas.count, np.int32),
        eps=float(prior.eps),
        width=3 if prior.channels == "joint" else 1,
        res_log_eps=float(Config().log_eps),
    )


def _maps(prior, numbers, folds, alpha, ref):
    """Every fold's :class:`~abrdf_jax.select._prior.HeldOutMap` (stacked): the fused model's
    (``numbers`` a ``FusedHyper``, ``ref`` its reference) or the prior's (``numbers`` λ). One
    fold after the other (``lax.map``: see :func:`abrdf_jax.prior._fused.each`)."""
    import jax

    from ._fused import fused_map
    from ._prior import prior_map

    def one(f):
        if ref is None:
            return prior_map(prior, f[0], f[1], numbers, alpha)
        return fused_map(prior, numbers, f[0], f[1], alpha, ref)

    return jax.lax.map(one, folds)


@functools.cache
def _jitted_maps():
    from .._build_jit import build_jit  # built once per layout: compiled cheaply

    return build_jit(_maps)


def cached_entry(store, model, meas, alpha_deg: float, k: int, warn, before_build=None):
    """The held-out entry of learned ``model`` on ``meas``'s layout from ``store`` (no JAX), else
    built (``before_build()`` first) and stored."""
    from .._prior_operator import prior_entry_key

    key = None
    if store is not None:
        at = types.SimpleNamespace(alpha=np.deg2rad(np.float64(alpha_deg)))
        key = prior_entry_key(_HeldOutKind(model, k), meas, at)
        entry = store.load(key, warn, kind=LearnedHeldOutEntry)
        if entry is not None and entry.t.shape == tuple(np.shape(meas.t)):
            return entry
    if before_build is not None:
        before_build()
    entry = build_entry(model, meas, alpha_deg, k)
    if store is not None:
        store.save(key, entry, warn)
    return entry


def learned_model(name: str, source, budget: str):
    """The command line's learned model ``name`` (``"prior"`` or ``"fused"``) of ``source`` (a
    :class:`abrdf_jax._prior_operator.PriorSource`) on ``budget``'s slices."""
    from .._fused_operator import FusedModel
    from .._prior_operator import PriorModel

    return {"prior": PriorModel, "fused": FusedModel}[name](source, budget)
