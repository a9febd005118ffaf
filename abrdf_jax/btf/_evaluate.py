"""Per-texel accuracy of a reconstructed BTF: protocol metrics as maps, and the error-map image."""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from .._errors import InputError
from ..io._atomic import write_figure
from ..metrics._metrics import (
    _de76_pairs,
    _log_error_from_y,
    _mean_over_pairs,
    expose,
    srgb_to_lab,
    tonemap,
)
from ._backend import open_store
from ._store import pad_rows

METRICS = ("de76", "logerr")


def _one_texel(recs, ref, names):
    """PROTOCOL ΔE76 / LogErr of several reconstructions of one texel against its reference.

    The same formulas as :func:`abrdf_jax.metrics.delta_e76` and ``log_error`` (their private
    parts), with the reference's exposure (a median over 6561 pairs) and CIELAB computed once
    for all reconstructions instead of once per metric and reconstruction: 2.5× less work for
    a reconstruction and a baseline.
    """
    e = expose(ref)
    y_ref = ref * e
    lab_ref = srgb_to_lab(tonemap(y_ref)) if "de76" in names else None
    metric = dict(
        de76=lambda y, same: _mean_over_pairs(_de76_pairs(srgb_to_lab(tonemap(y)), lab_ref), same),
        logerr=lambda y, same: _log_error_from_y(y, y_ref, same),
    )
    return [{k: metric[k](rec * e, rec == ref) for k in names} for rec in recs]


@partial(jax.jit, static_argnames="names")
def _chunk_metrics(recs, ref, names):
    return jax.vmap(lambda r, f: _one_texel(r, f, names))(recs, ref)


def _reader(x):
    """``(n_texels, texel_shape or None, read(a, b))`` of an array or a store."""
    if isinstance(x, np.ndarray):
        return len(x), None, lambda a, b: x[a:b]
    s = open_store(x)
    return s.n_texels, s.texel_shape, s.read


def texel_metrics_many(
    recs: dict, ref, metrics=METRICS, batch: int = 256
) -> dict[str, dict[str, np.ndarray]]:
    """PROTOCOL metrics of every texel of several reconstructions (e.g. ours and a baseline).

    Each texel is one material: exposed by its own reference (PROTOCOL.md), compared over its 6561
    direction pairs. The reference's exposure and colours are computed once per texel for all.

    Args:
        recs: ``{name: reconstruction}``, each an ``"abrdf"`` store, its folder, or an array
            ``(T, 6561, 3)``.
        ref: the dense reference, same layout (a store gives the maps their shape).
        metrics: names among ``"de76"``, ``"logerr"``.
        batch: texels evaluated per call (one compilation for any size).

    Returns:
        ``{name: {metric: (rows, columns) float64 map}}`` (``(1, T)`` when no input is a store).

    Raises:
        InputError: an unknown metric, no reconstruction, or texel counts that differ.
    """
    names = tuple(metrics)
    unknown = [n for n in names if n not in METRICS]
    if unknown or not names:
        raise InputError(f"unknown metric(s) {unknown or names}; choose from {METRICS}")
    if not recs:
        raise InputError("texel_metrics_many: no reconstruction given")
    n, shape, read_ref = _reader(ref)
    readers = {}
    for key, rec in recs.items():
        m, sh, read = _reader(rec)
        if m != n:
            raise InputError(f"reconstruction {key!r} has {m} texels, the reference {n}")
        shape = shape or sh
        readers[key] = read
    shape = shape or (1, n)
    batch = max(1, min(batch, n))
    out = {key: {k: np.empty(n) for k in names} for key in recs}

    for a in range(0, n, batch):
        b = min(a + batch, n)
        y, *xs = (
            jnp.asarray(pad_rows(np.asarray(read(a, b), np.float32), batch))
            for read in (read_ref, *readers.values())
        )
        vals = _chunk_metrics(xs, y, names)
        for key, v in zip(readers, vals):
            for k in names:
                out[key][k][a:b] = np.asarray(v[k])[: b - a]
    return {key: {k: v.reshape(shape) for k, v in d.items()} for key, d in out.items()}


def texel_metrics(rec, ref, metrics=METRICS[:1], batch: int = 256) -> dict[str, np.ndarray]:
    """PROTOCOL metrics of every texel of one reconstruction: :func:`texel_metrics_many` of
    ``{"rec": rec}``, i.e. ``{metric: (rows, columns) float64 map}``."""
    return texel_metrics_many({"rec": rec}, ref, metrics, batch)["rec"]


def mean_fill(meas, start: int = 0, stop: int | None = None) -> np.ndarray:
    """The trivial reconstruction of texels ``[start, stop)``: every pair is the mean sample.

    Returns:
        ``(n, 6561, 3)`` float32.
    """
    y = open_store(meas).read(start, stop).astype(np.float32)
    return np.broadcast_to(y.mean(axis=1, keepdims=True), (y.shape[0], 81 * 81, 3)).copy()


def save_error_map(
    values: np.ndarray,
    path,
    *,
    title: str = "",
    label: str = "ΔE76",
    vmax: float | None = None,
    extra: dict | None = None,
) -> None:
    """Save a per-texel error map as a PNG (with a colour bar and the mean in the title).

    Args:
        values: ``(rows, columns)`` map.
        path: the ``.png`` file.
        title: figure title (the mean and the 95th percentile are appended).
        label: colour-bar label.
        vmax: colour scale maximum (default: the 99th percentile).
        extra: further maps ``{title: (rows, columns) array}`` drawn beside it (e.g. albedo).
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    values = np.asarray(values, float)
    head = f"{title} mean {values.mean():.2f}, p95 {np.percentile(values, 95):.2f}".strip()
    panels = [(head, values), *(extra or {}).items()]
    fig, axes = plt.subplots(1, len(panels), figsize=(4.6 * len(panels), 4.2), squeeze=False)
    for ax, (name, img) in zip(axes[0], panels):
        img = np.asarray(img)
        if img.ndim == 3:  # an RGB map (e.g. albedo), shown gamma-encoded
            img = np.clip(img / max(img.max(), 1e-6), 0, 1) ** (1 / 2.2)
            ax.imshow(img, interpolation="nearest")
        else:
            vm = vmax if img is values and vmax is not None else float(np.percentile(img, 99))
            im = ax.imshow(img, cmap="magma", vmin=0, vmax=vm, interpolation="nearest")
            fig.colorbar(im, ax=ax, fraction=0.046, label=label if img is values else "")
        ax.set_title(name, fontsize=9)
        ax.set(xticks=[], yticks=[])
    fig.tight_layout()
    try:
        write_figure(fig, path, dpi=110)
    finally:
        plt.close(fig)
