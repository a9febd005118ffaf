"""How few samples per slice does a material need? The device designer's curve.

A device records the slices continuously; how densely it must sample them is a design choice.
:func:`sample_count_curve` answers it for one material: for each number ``N`` of samples per
measured slice (uniform positions ``φ = k · 2π / N`` on the elevation pairs of the
configuration), reconstruct and measure the error, then report the smallest ``N`` that meets a
target error.

Two kinds of source:

- **ground truth** — a continuous model ``model(wi, wv)`` (exact samples at any angle) or a dense
  81×81 table (azimuthally interpolated samples): the error is a PROTOCOL.md metric of the
  reconstruction against the dense table (``metric="de76"``, ``"logerr"``, ...);
- **a measurement** (:class:`Samples` / :class:`Measurements`) — no ground truth: each slice is
  thinned to ``N`` evenly spread samples, and the error is the RMS log error at the samples left
  out (``metric="held_out"``), so only ``N`` below the measured count can be assessed.

All counts share one compiled reconstruction (slices are padded to the largest count).
"""

from __future__ import annotations

import dataclasses

import jax.numpy as jnp
import numpy as np

from .._errors import InputError
from .._params import Config, Params
from .._pipeline import _reconstruct_jit, prepare
from .._folds import log_rms
from .._measurements import Measurements, Samples
from .._values import measurement_eps
from .._sampling import sample_model, sample_table

DEFAULT_COUNTS = (6, 8, 10, 12, 16, 20, 25, 32)
GROUND_TRUTH_METRICS = ("de76", "de2000", "rmse8", "logerr")


@dataclasses.dataclass(frozen=True)
class SampleCountCurve:
    """Error against samples per slice (:func:`sample_count_curve`).

    Attributes:
        counts: samples per measured slice, ascending.
        totals: total samples of each count (all measured slices of all pairs).
        errors: the error at each count (``metric`` units).
        metric: ``"de76"``, ``"logerr"``, ... (against ground truth) or ``"held_out"``.
        target: the target error, if one was given.
        needed: the smallest count from which every larger tested count meets ``target``
            (``None``: no target, or never met).
        budget: the configuration's budget (which slices are measured).
    """

    counts: tuple
    totals: tuple
    errors: tuple
    metric: str
    target: float | None
    needed: int | None
    budget: str

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


def _needed(counts, errors, target):
    if target is None:
        return None
    ok = [e <= target for e in errors]
    return next((int(c) for i, c in enumerate(counts) if all(ok[i:])), None)


def _pad(meas: Measurements, nmax: int) -> Measurements:
    extra = nmax - meas.t.shape[1]
    if extra <= 0:
        return meas
    return meas.replace(
        t=jnp.pad(meas.t, ((0, 0), (0, extra))), y=jnp.pad(meas.y, ((0, 0), (0, extra), (0, 0)))
    )


def _slice_counts(config: Config, n: int) -> tuple[int, ...]:
    axial = n if config.budget == "aniso204" else 0
    return tuple(c for _ in config.pairs for c in (axial, n))


def _thin(meas: Measurements, n: int):
    """Keep ``n`` evenly spread samples of every measured slice; return kept and left-out parts."""
    t, y, cnt = np.asarray(meas.t), np.asarray(meas.y), np.asarray(meas.count)
    S, nmax = t.shape
    kt, ky, kc = np.zeros_like(t), np.zeros_like(y), np.zeros(S, np.int32)
    held = []
    for s in range(S):
        m = int(cnt[s])
        if m == 0:
            continue
        keep = np.unique(np.round(np.linspace(0, m, n, endpoint=False)).astype(int))
        kt[s, : len(keep)], ky[s, : len(keep)], kc[s] = t[s, keep], y[s, keep], len(keep)
        rest = np.setdiff1d(np.arange(m), keep)
        held.append((s, t[s, rest], y[s, rest]))
    kept = meas.replace(t=jnp.asarray(kt), y=jnp.asarray(ky), count=jnp.asarray(kc))
    return kept, held


def sample_count_curve(
    source,
    counts: tuple[int, ...] = DEFAULT_COUNTS,
    *,
    config: Config | None = None,
    params: Params | None = None,
    metric: str | None = None,
    target: float | None = None,
    alpha_deg: float | None = None,
) -> SampleCountCurve:
    """Error of the reconstruction against the number of samples per slice.

    Args:
        source: a continuous model, a dense ``(81, 81, 3)`` table, or a measurement
            (:class:`Samples`/:class:`Measurements`; see the module docstring).
        counts: samples per measured slice to try (each ≥ 3).
        config: the model and the sampled slices (budget, elevation pairs); default
            ``Config.recommended`` with ``aniso204`` for a ground-truth source, the measurement's
            own budget otherwise.
        params: α, widths, λ; default :meth:`Params.default` (α = 15° or the measurement's).
        metric: a key of :func:`abrdf_jax.metrics.evaluate` for ground truth (default
            ``"de76"``); ``"held_out"`` (the only choice) for a measurement.
        target: the error to meet; the curve's ``needed`` is the smallest count that meets it.
        alpha_deg: slice offset for grouping :class:`Samples`.

    Returns:
        A :class:`SampleCountCurve`.

    Raises:
        InputError: counts below 3, an unknown metric, or (for a measurement) no count below the
            measured one.
    """
    from ..metrics._metrics import evaluate
    from .._slices import slice_vectors

    counts = tuple(sorted({int(c) for c in counts}))
    if not counts or counts[0] < 3:
        raise InputError(f"counts must be integers >= 3, got {counts}")
    measured = isinstance(source, (Samples, Measurements))
    if measured:
        if metric not in (None, "held_out"):
            raise InputError(
                f"a measurement has no ground truth: metric must be 'held_out', got {metric!r}"
            )
        metric = "held_out"
        p0 = None if alpha_deg is None else Params.default(Config(), alpha_deg=alpha_deg)
        meas, cfg_auto, p = prepare(source, None, p0)
        config = config or Config.recommended(cfg_auto.budget, pairs=meas.pairs)
        params = params or Params.default(config, alpha_deg=p.alpha_deg, dtype=meas.y.dtype)
        meas, config, params = prepare(meas, config, params)
        top = int(np.max(np.asarray(meas.count)[1::2]))
        counts = tuple(c for c in counts if c < top)
        if not counts:
            raise InputError(
                f"every count is at least the measured {top} samples per slice: nothing to hold out"
            )
    else:
        metric = metric or "de76"
        if metric not in GROUND_TRUTH_METRICS:
            raise InputError(
                f"metric must be one of {GROUND_TRUTH_METRICS} (lower is better) for a ground-truth source, got {metric!r}"
            )
        config = config or Config.recommended("aniso204")
        params = params or Params.default(
            config, alpha_deg=15.0 if alpha_deg is None else alpha_deg
        )
        is_table = hasattr(source, "shape") and not callable(source)
        ref = jnp.asarray(source) if is_table else None
        if ref is None:
            from ..materials import dense_table

            wide = params.alpha.dtype == jnp.float64
            ref = jnp.asarray(dense_table(source, np.float64 if wide else np.float32))
    errors, totals = [], []
    nmax = int(8 * np.ceil(max(counts) / 8))
    for n in counts:
        if measured:
            kept, held = _thin(meas, n)
            rec_in = _pad(kept, meas.t.shape[1])
            dt, a = meas.t.dtype, params.alpha.astype(meas.t.dtype)
            dirs = [
                slice_vectors(jnp.asarray(ts, dt), s % 2, meas.pairs[s // 2], a)
                for s, ts, _ in held
            ]
            pred = _reconstruct_jit(rec_in, config, params, tuple(map(jnp.concatenate, zip(*dirs))))
            y = jnp.asarray(np.concatenate([ys for _, _, ys in held]), pred.dtype)
            errors.append(float(log_rms(pred, y, measurement_eps(meas, config.log_eps), True)))
            totals.append(int(np.sum(np.asarray(kept.count))))
        else:
            cnts = _slice_counts(config, n)
            dt = params.alpha.dtype
            if is_table:
                m = sample_table(ref, cnts, params.alpha, config.pairs, dtype=dt)
            else:
                m = sample_model(source, cnts, params.alpha, config.pairs, dtype=dt)
            rec = _reconstruct_jit(_pad(m, nmax), config, params, None)
            errors.append(float(evaluate(rec, ref.astype(rec.dtype))[metric]))
            totals.append(int(sum(cnts)))
    needed = _needed(counts, errors, target)
    return SampleCountCurve(
        counts, tuple(totals), tuple(errors), metric, target, needed, config.budget
    )
