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

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, PyTree

from .._errors import InputError
from ..metrics._color import LUMA_WEIGHTS, srgb_to_lab, tonemap
from .._params import Config, Params
from .._pipeline import _reconstruct_core, prepare
from .._measurements import Measurements, Samples
from .._names import FOLD_KINDS, LOSSES
from .._folds import held_out_directions, log_residual, sample_folds
from .._slices import slice_vectors
from .._values import measurement_eps

WIDTH_MODES = ("per_dim", "shared", "fixed")

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
    log_width_bounds: tuple[float, float] = eqx.field(
        static=True, default=(float(np.log(0.02)), float(np.log(20.0)))
    )
    log_reg_bounds: tuple[float, float] = eqx.field(
        static=True, default=(float(np.log(1e-9)), float(np.log(10.0)))
    )

    def __check_init__(self):
        if self.widths not in WIDTH_MODES:
            raise InputError(f"ParamSpace.widths must be one of {WIDTH_MODES}, got {self.widths!r}")
        lo, hi = self.alpha_bounds_deg
        if not 0 < lo < hi < 90:
            raise InputError(
                f"ParamSpace.alpha_bounds_deg must satisfy 0 < lo < hi < 90, got {self.alpha_bounds_deg}"
            )
        if self.widths == "fixed" and not self.reg and not self.alpha:
            raise InputError("ParamSpace has no free parameter: free the widths, reg or alpha")

    # -- the map ---------------------------------------------------------------------------
    def init(self, params: Params) -> dict[str, Array]:
        """Unconstrained coordinates of ``params`` (clipped into the bounds)."""
        theta = {}
        if self.widths != "fixed":
            lw = jnp.log(params.widths)
            lw = lw if self.widths == "per_dim" else jnp.mean(lw)[None]  # shared: geometric mean
            theta["log_widths"] = jnp.clip(lw, *self.log_width_bounds)
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

    def at_bounds(self, params: Params, margin: float = 0.01) -> list[str]:
        """The free parameters of ``params`` that lie at a bound of this space (within
        ``margin`` of its log range for widths and λ, or of α's range), one phrase each: a fit
        that ends there was stopped by the box, not by the data."""
        out = []

        def check(name, value, lo, hi):
            span = hi - lo
            if value <= lo + margin * span:
                out.append(f"{name} at its lower bound")
            elif value >= hi - margin * span:
                out.append(f"{name} at its upper bound")

        if self.widths != "fixed":
            lw = np.log(np.asarray(params.widths, np.float64))
            lw = lw if self.widths == "per_dim" else lw[:1]
            for i, v in enumerate(lw):
                label = (
                    f"widths[{i}] = {np.exp(v):.3g}"
                    if self.widths == "per_dim"
                    else (f"widths = {np.exp(v):.3g}")
                )
                check(label, v, *self.log_width_bounds)
        if self.reg:
            reg = float(np.asarray(params.reg))
            check(f"reg = {reg:.3g}", np.log(reg), *self.log_reg_bounds)
        if self.alpha:
            check(f"alpha = {params.alpha_deg:.3g} deg", params.alpha_deg, *self.alpha_bounds_deg)
        return out

    def bounds(self, theta: dict[str, Array]) -> tuple[dict[str, Array], dict[str, Array]]:
        """Box bounds on ``theta`` (for ``jaxopt.LBFGSB``); α's logit gets ±12 (0.0006% of the range)."""
        box = dict(
            log_widths=self.log_width_bounds, log_reg=self.log_reg_bounds, alpha=(-12.0, 12.0)
        )
        lo = {k: jnp.full_like(v, box[k][0]) for k, v in theta.items()}
        return lo, {k: jnp.full_like(v, box[k][1]) for k, v in theta.items()}


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
            raise InputError(
                "self-calibration cannot fit alpha: the measured samples fix it (ParamSpace(alpha=False))"
            )
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
        prob = cls(
            config=config, space=space, folds=folds, k=k, pairs=tuple(map(tuple, meas.pairs))
        )
        return prob, prob.make_data(meas, params), params

    def make_data(self, meas: Measurements, params: Params) -> dict:
        """The data pytree of a measurement (arrays only: new data never recompiles)."""
        if tuple(map(tuple, meas.pairs)) != self.pairs:
            raise InputError(
                f"measurement pairs {meas.pairs} differ from the problem's {self.pairs}"
            )
        data = {"alpha": jnp.asarray(params.alpha, meas.y.dtype), "base": params}
        if self.folds == "pairs":
            counts = np.asarray(meas.count)
            for p in range(len(self.pairs)):
                if counts[2 * p + 1] == 0:
                    raise InputError(
                        f"elevation pair {self.pairs[p]} has no diagonal slice: cannot self-calibrate"
                    )
            data["meas"] = meas
        else:
            train, tt, ty, tm = sample_folds(meas, self.k)
            data.update(meas=meas, train=train, test_t=tt, test_y=ty, test_mask=tm)
        return data

    def residuals(self, theta, data):
        TRACE_COUNT["residuals"] += 1
        params = self.space.to_params(theta, data["base"])
        meas = data["meas"]
        eps = measurement_eps(meas, self.config.log_eps)
        alpha = data["alpha"]
        out = []
        P = len(self.pairs)
        # Only slices that are measured are predicted (an iso102 axial slice is empty).
        if self.folds == "pairs":
            for p in range(P):
                sub = meas.select_slices(tuple(q for q in range(P) if q != p))
                cfg = dataclasses.replace(self.config, pairs=sub.pairs)
                for kind in (0, 1) if meas.has_axial else (1,):
                    s = 2 * p + kind
                    wi, wv = slice_vectors(meas.t[s], kind, self.pairs[p], alpha)
                    pred = _reconstruct_core(sub, cfg, params, targets=(wi, wv))
                    out.append(
                        log_residual(pred, meas.y[s], eps, meas.mask[s][:, None]).reshape(-1)
                    )
        else:
            for j in range(self.k):
                train = jax.tree_util.tree_map(lambda x: x[j], data["train"])
                wi, wv = held_out_directions(data["test_t"][j], self.pairs, alpha)
                pred = _reconstruct_core(train, self.config, params, targets=(wi, wv))
                y = data["test_y"][j].reshape(-1, 3)
                mask = data["test_mask"][j].reshape(-1, 1)
                out.append(log_residual(pred, y, eps, mask).reshape(-1))
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
            raise InputError(
                f"population references must have shape (B, 81, 81, 3), got {ref.shape}"
            )
        return {"source": source, "ref": ref, "base": params}

    def residuals(self, theta, data):
        from .._sampling import sample

        TRACE_COUNT["residuals"] += 1
        params = self.space.to_params(theta, data["base"])
        src = data["source"]

        def one(s, ref):
            meas = sample(s, self.config, params, as_measurements=True)
            rec = _reconstruct_core(meas, self.config, params)
            return _protocol_terms(rec, ref.astype(rec.dtype), self.loss_kind)

        r = jax.vmap(one)(src, data["ref"])
        return r.reshape(-1)
