"""Tuning problems: the continuous parameters as an unconstrained vector, and the held-out losses.

Two problems, one interface (:class:`AbstractProblem`): ``residuals(theta, data)`` is a pure
function of the unconstrained parameters ``theta`` and of a pytree of arrays ``data``; every
static choice lives on the problem. Jitting it once therefore serves every data set of the same
shapes and every parameter value (``tests/test_tuning.py`` counts the traces).

- :class:`SelfCalibration`: one material, its own measurements only. Each fold leaves one
  elevation pair out (``folds="pairs"``, both of its slices) or every ``k``-th sample of every
  slice (``folds="samples"``), reconstructs from the rest and compares the prediction with the
  held-out samples in log space. No dense ground truth needed.
- :class:`Population`: many training materials with dense references (continuous models, so
  that sampling is differentiable in α, or 81×81 tables interpolated over azimuth). The residuals
  are the PROTOCOL.md colour differences (CIELAB of the exposed, tone-mapped values: the squared
  residuals sum to ΣΔE76²) and/or log differences of the exposed values (as LogErr).

The map from ``theta`` to :class:`~abrdf_jax.Params` is :class:`ParamSpace`: widths and λ through
``exp`` (positive), α through a logistic map into a bounded interval of degrees.
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, PyTree

from ._errors import InputError
from ._metrics import LUMA_WEIGHTS, srgb_to_lab, tonemap
from ._params import Config, Params
from ._pipeline import _reconstruct_core, prepare
from ._samples import Samples
from ._slices import KINDS, Measurements, slice_angles
from ._grid import to_vector

WIDTH_MODES = ("per_dim", "shared", "fixed")
FOLD_KINDS = ("pairs", "samples")
LOSSES = ("lab", "log", "lab+log")

#: Number of traces of any problem's ``residuals`` (the trace-count test reads it).
TRACE_COUNT = {"residuals": 0}


class ParamSpace(eqx.Module):
    """Which parameters are free, and their unconstrained coordinates.

    ``theta`` is a dict of arrays: ``"log_widths"`` (4 or 1 entries), ``"log_reg"`` and ``"alpha"``
    (a logit of α in ``alpha_bounds_deg``), each present only when free. Parameters that are not
    free are taken from the ``base`` :class:`Params`.

    Attributes:
        widths: ``"per_dim"`` (one width per coordinate), ``"shared"`` (one for all) or ``"fixed"``.
        reg: whether λ is free.
        alpha: whether α is free (population tuning only: a measured material's α is fixed).
        alpha_bounds_deg: the open interval α may take.
        theta_bounds: box bounds on ``log_widths`` and ``log_reg`` (natural-log units) for solvers
            that take bounds; also the clip applied before use, so no solver can leave the
            domain where the RBF system is solvable.
    """

    widths: str = eqx.field(static=True, default="per_dim")
    reg: bool = eqx.field(static=True, default=True)
    alpha: bool = eqx.field(static=True, default=False)
    alpha_bounds_deg: tuple[float, float] = eqx.field(static=True, default=(2.0, 88.0))
    log_width_bounds: tuple[float, float] = eqx.field(static=True, default=(float(np.log(0.02)), float(np.log(20.0))))
    log_reg_bounds: tuple[float, float] = eqx.field(static=True, default=(float(np.log(1e-9)), float(np.log(10.0))))

    def __check_init__(self):
        if self.widths not in WIDTH_MODES:
            raise InputError(f"ParamSpace.widths must be one of {WIDTH_MODES}, got {self.widths!r}")
        lo, hi = self.alpha_bounds_deg
        if not 0 < lo < hi < 90:
            raise InputError(f"ParamSpace.alpha_bounds_deg must satisfy 0 < lo < hi < 90, got {self.alpha_bounds_deg}")
        if self.widths == "fixed" and not self.reg and not self.alpha:
            raise InputError("ParamSpace has no free parameter: free the widths, reg or alpha")

    # -- the map ---------------------------------------------------------------------------
    def init(self, params: Params) -> dict[str, Array]:
        """Unconstrained coordinates of ``params`` (clipped into the bounds)."""
        theta = {}
        if self.widths == "per_dim":
            theta["log_widths"] = jnp.clip(jnp.log(params.widths), *self.log_width_bounds)
        elif self.widths == "shared":
            theta["log_widths"] = jnp.clip(jnp.log(jnp.exp(jnp.mean(jnp.log(params.widths))))[None], *self.log_width_bounds)
        if self.reg:
            theta["log_reg"] = jnp.clip(jnp.log(params.reg), *self.log_reg_bounds)
        if self.alpha:
            lo, hi = np.deg2rad(self.alpha_bounds_deg)
            u = jnp.clip((params.alpha - lo) / (hi - lo), 1e-6, 1 - 1e-6)
            theta["alpha"] = jnp.log(u) - jnp.log1p(-u)
        # One dtype for every entry (the parameters'), as jaxopt requires.
        return {k: jnp.asarray(v, params.alpha.dtype) for k, v in theta.items()}

    def to_params(self, theta: dict[str, Array], base: Params) -> Params:
        """The :class:`Params` at ``theta``; fixed entries from ``base``."""
        widths, reg, alpha = base.widths, base.reg, base.alpha
        if "log_widths" in theta:
            lw = jnp.clip(theta["log_widths"], *self.log_width_bounds)
            widths = jnp.broadcast_to(jnp.exp(lw), (4,)).astype(base.widths.dtype)
        if "log_reg" in theta:
            reg = jnp.exp(jnp.clip(theta["log_reg"], *self.log_reg_bounds)).astype(base.reg.dtype)
        if "alpha" in theta:
            lo, hi = np.deg2rad(self.alpha_bounds_deg)
            alpha = (lo + (hi - lo) * jax.nn.sigmoid(theta["alpha"])).astype(base.alpha.dtype)
        return Params(alpha, widths, reg)

    def bounds(self, theta: dict[str, Array]) -> tuple[dict[str, Array], dict[str, Array]]:
        """Box bounds on ``theta`` (for ``jaxopt.LBFGSB``); α's logit gets ±12 (0.0006% of the range)."""
        lo, hi = {}, {}
        for k, v in theta.items():
            b = {"log_widths": self.log_width_bounds, "log_reg": self.log_reg_bounds, "alpha": (-12.0, 12.0)}[k]
            lo[k], hi[k] = jnp.full_like(v, b[0]), jnp.full_like(v, b[1])
        return lo, hi


class AbstractProblem(eqx.Module):
    """A tuning problem: residuals of held-out predictions as a pure function of ``theta``."""

    config: Config = eqx.field(static=True)
    space: ParamSpace = eqx.field(static=True)

    def residuals(self, theta: dict[str, Array], data: PyTree) -> Float[Array, " n"]:
        raise NotImplementedError

    def loss(self, theta: dict[str, Array], data: PyTree) -> Float[Array, ""]:
        """Half the mean squared residual (the scalar minimisers' objective)."""
        r = self.residuals(theta, data)
        return 0.5 * jnp.mean(r * r)


# ------------------------------------------------------------------------------------------------
# Self-calibration


def _select_pairs(meas: Measurements, keep: tuple[int, ...]) -> Measurements:
    rows = np.asarray([r for p in keep for r in (2 * p, 2 * p + 1)])
    return Measurements(meas.t[rows], meas.y[rows], meas.count[rows], tuple(meas.pairs[p] for p in keep), meas.has_axial)


def _slice_vectors(t, kind_index: int, pair, alpha):
    pi_, pv = slice_angles(KINDS[kind_index], t, alpha)
    ti, tv = np.deg2rad(pair[0]), np.deg2rad(pair[1])
    return to_vector(jnp.full_like(pi_, ti), pi_), to_vector(jnp.full_like(pv, tv), pv)


def _sample_folds(meas: Measurements, k: int):
    """``k`` folds: fold ``j`` holds out samples ``j, j+k, ...`` of every slice (numpy, concrete)."""
    t, y, cnt = np.asarray(meas.t), np.asarray(meas.y), np.asarray(meas.count)
    S, nmax = t.shape
    train_t, train_y, train_c, test_t, test_y, test_m = [], [], [], [], [], []
    ntest = -(-nmax // k)
    for j in range(k):
        tt, yy, cc = np.zeros_like(t), np.zeros_like(y), np.zeros(S, np.int32)
        et, ey, em = np.zeros((S, ntest), t.dtype), np.zeros((S, ntest, 3), y.dtype), np.zeros((S, ntest), bool)
        for s in range(S):
            n = int(cnt[s])
            idx = np.arange(n)
            held = idx[idx % k == j]
            kept = idx[idx % k != j]
            if n and len(kept) < 3:
                raise InputError(f"folds='samples' with k={k}: slice {s} has only {n} samples; use fewer folds")
            tt[s, : len(kept)], yy[s, : len(kept)], cc[s] = t[s, kept], y[s, kept], len(kept)
            if n:
                et[s, : len(held)], ey[s, : len(held)], em[s, : len(held)] = t[s, held], y[s, held], True
        train_t.append(tt), train_y.append(yy), train_c.append(cc)
        test_t.append(et), test_y.append(ey), test_m.append(em)
    train = Measurements(
        jnp.asarray(np.stack(train_t)), jnp.asarray(np.stack(train_y)), jnp.asarray(np.stack(train_c)),
        meas.pairs, meas.has_axial,
    )
    return train, jnp.asarray(np.stack(test_t)), jnp.asarray(np.stack(test_y)), jnp.asarray(np.stack(test_m))


class SelfCalibration(AbstractProblem):
    """Held-out error of one material's own measurements (k-fold, no ground truth).

    ``folds="pairs"``: fold ``p`` reconstructs from every elevation pair but ``p`` (a
    :class:`Config` with those pairs) and predicts pair ``p``'s samples; this is the test that
    matters for the RBF, whose job is to fill the elevations that were never measured.
    ``folds="samples"``: fold ``j`` drops every ``k``-th sample of every slice and predicts them
    (tests the slice interpolation and the subspace rule more than the RBF).

    Residual: ``ln(rec + ε) − ln(y + ε)`` per held-out sample and channel, ``ε = log_eps · mean
    sample`` (scale free, like the PROTOCOL's LogErr; ``log_eps`` from the config).

    Build it with :meth:`from_samples`, which also returns the ``data`` pytree.
    """

    folds: str = eqx.field(static=True, default="pairs")
    k: int = eqx.field(static=True, default=4)
    pairs: tuple = eqx.field(static=True, default=())

    def __check_init__(self):
        if self.folds not in FOLD_KINDS:
            raise InputError(f"folds must be one of {FOLD_KINDS}, got {self.folds!r}")
        if self.space.alpha:
            raise InputError("self-calibration cannot fit alpha: the measured samples fix it (ParamSpace(alpha=False))")
        if self.folds == "pairs" and len(self.pairs) < 2:
            raise InputError("folds='pairs' needs at least 2 measured elevation pairs")

    @classmethod
    def from_samples(
        cls,
        samples: Samples | Measurements,
        config: Config | None = None,
        params: Params | None = None,
        *,
        space: ParamSpace | None = None,
        folds: str = "pairs",
        k: int = 4,
    ) -> tuple["SelfCalibration", dict, Params]:
        """The problem, its data and the starting parameters for one material's measurements."""
        meas, config, params = prepare(samples, config, params)
        space = space or ParamSpace()
        prob = cls(config=config, space=space, folds=folds, k=k, pairs=tuple(map(tuple, meas.pairs)))
        return prob, prob.make_data(meas, params), params

    def make_data(self, meas: Measurements, params: Params) -> dict:
        """The data pytree of a measurement (arrays only: new data never recompiles)."""
        if tuple(map(tuple, meas.pairs)) != self.pairs:
            raise InputError(f"measurement pairs {meas.pairs} differ from the problem's {self.pairs}")
        data = {"alpha": jnp.asarray(params.alpha, meas.y.dtype), "base": params}
        if self.folds == "pairs":
            counts = np.asarray(meas.count)
            for p in range(len(self.pairs)):
                if counts[2 * p + 1] == 0:
                    raise InputError(f"elevation pair {self.pairs[p]} has no diagonal slice: cannot self-calibrate")
            data["meas"] = meas
        else:
            train, tt, ty, tm = _sample_folds(meas, self.k)
            data.update(meas=meas, train=train, test_t=tt, test_y=ty, test_mask=tm)
        return data

    def _eps(self, meas: Measurements):
        valid = (jnp.arange(meas.y.shape[1])[None, :] < meas.count[:, None])[..., None]
        mean = jnp.sum(jnp.where(valid, jnp.abs(meas.y), 0.0), axis=(0, 1)) / jnp.maximum(jnp.sum(meas.count), 1)
        return self.config.log_eps * mean + jnp.finfo(meas.y.dtype).tiny ** 0.5

    def residuals(self, theta, data):
        TRACE_COUNT["residuals"] += 1
        params = self.space.to_params(theta, data["base"])
        meas = data["meas"]
        eps = self._eps(meas)
        alpha = data["alpha"]
        out = []
        P = len(self.pairs)
        # Only slices that are measured are predicted (an iso102 axial slice is empty).
        if self.folds == "pairs":
            for p in range(P):
                keep = tuple(q for q in range(P) if q != p)
                sub = _select_pairs(meas, keep)
                cfg = dataclasses.replace(self.config, pairs=sub.pairs)
                for kind in ((0, 1) if meas.has_axial else (1,)):
                    s = 2 * p + kind
                    wi, wv = _slice_vectors(meas.t[s], kind, self.pairs[p], alpha)
                    pred = _reconstruct_core(sub, cfg, params, targets=(wi, wv))
                    mask = (jnp.arange(meas.t.shape[1]) < meas.count[s])[:, None]
                    r = jnp.log(pred + eps) - jnp.log(jnp.maximum(meas.y[s], 0.0) + eps)
                    out.append(jnp.where(mask, r, 0.0).reshape(-1))
        else:
            S = meas.t.shape[0]
            for j in range(self.k):
                train = jax.tree_util.tree_map(lambda x: x[j], data["train"])
                wis, wvs = [], []
                for s in range(S):
                    wi, wv = _slice_vectors(data["test_t"][j, s], s % 2, self.pairs[s // 2], alpha)
                    wis.append(wi), wvs.append(wv)
                wi, wv = jnp.concatenate(wis), jnp.concatenate(wvs)
                pred = _reconstruct_core(train, self.config, params, targets=(wi, wv))
                y = data["test_y"][j].reshape(-1, 3)
                mask = data["test_mask"][j].reshape(-1, 1)
                r = jnp.log(pred + eps) - jnp.log(jnp.maximum(y, 0.0) + eps)
                out.append(jnp.where(mask, r, 0.0).reshape(-1))
        return jnp.concatenate(out)


# ------------------------------------------------------------------------------------------------
# Population tuning


def _protocol_terms(rec, ref, loss: str):
    """Residuals whose squares sum to ΣΔE76² (``"lab"``) and/or Σ(ln(1+y_rec) − ln(1+y_ref))²."""
    w = jnp.asarray(LUMA_WEIGHTS, ref.dtype)
    Y = jnp.sum(ref * w, axis=-1).reshape(-1)
    med = jnp.median(Y)
    ym = jnp.where(med > 0, med, jnp.maximum(jnp.mean(Y), jnp.finfo(ref.dtype).tiny))
    e = jax.lax.stop_gradient(0.18 / ym)
    y_rec, y_ref = rec * e, ref * e
    out = []
    if "lab" in loss:
        d = srgb_to_lab(tonemap(y_rec)) - srgb_to_lab(tonemap(y_ref))
        out.append(d.reshape(-1))
    if "log" in loss:
        # Scaled so that a typical log error weighs like a typical ΔE (LogErr ~0.1 vs ΔE ~5).
        d = 50.0 * (jnp.log1p(jnp.maximum(y_rec, 0.0)) - jnp.log1p(jnp.maximum(y_ref, 0.0)))
        out.append(d.reshape(-1))
    return jnp.concatenate(out)


class Population(AbstractProblem):
    """Protocol error of the full reconstruction over many training materials.

    ``data = {"source": models_or_tables, "ref": (B, 81, 81, 3), "base": Params}``. ``source`` is a
    stacked continuous model (e.g. :func:`abrdf_jax.materials.stack_nbrdf`; any eqx.Module whose
    leaves carry a leading material axis and that maps ``(wi, wv) -> (..., 3)``), sampled at the
    slices of ``config`` for the current α (differentiable), or ``(B, 81, 81, 3)`` tables sampled
    by azimuthal interpolation. The residuals are averaged so that ``loss`` is per material.
    """

    loss_kind: str = eqx.field(static=True, default="lab")

    def __check_init__(self):
        if self.loss_kind not in LOSSES:
            raise InputError(f"loss must be one of {LOSSES}, got {self.loss_kind!r}")

    @staticmethod
    def make_data(source, ref, params: Params) -> dict:
        ref = jnp.asarray(ref)
        if ref.ndim != 4 or ref.shape[1:] != (81, 81, 3):
            raise InputError(f"population references must have shape (B, 81, 81, 3), got {ref.shape}")
        return {"source": source, "ref": ref, "base": params}

    def residuals(self, theta, data):
        from ._pipeline import sample

        TRACE_COUNT["residuals"] += 1
        params = self.space.to_params(theta, data["base"])
        src = data["source"]

        def one(s, ref):
            meas = sample(s, self.config, params, as_measurements=True)
            rec = _reconstruct_core(meas, self.config, params)
            return _protocol_terms(rec, ref.astype(rec.dtype), self.loss_kind)

        r = jax.vmap(one)(src, data["ref"])
        return r.reshape(-1)
