"""Per-texel accuracy of a reconstructed BTF: protocol metrics as maps, and the error-map image."""

from __future__ import annotations

from functools import partial

import jax
import jax.numpy as jnp
import numpy as np

from .._errors import InputError
from .._metrics import delta_e76, log_error
from ._store import ChunkedStore

_METRICS = {"de76": delta_e76, "logerr": log_error}


@partial(jax.jit, static_argnames="names")
def _chunk_metrics(rec, ref, names):
    return {n: jax.vmap(_METRICS[n])(rec, ref) for n in names}


def _open(store) -> ChunkedStore:
    return store if isinstance(store, ChunkedStore) else ChunkedStore.open(store)


def texel_metrics(rec, ref, metrics=("de76",), batch: int = 256) -> dict[str, np.ndarray]:
    """PROTOCOL metrics of every texel, as ``(rows, columns)`` maps.

    Each texel is one material: exposed by its own reference (PROTOCOL.md), compared over its 6561
    direction pairs.

    Args:
        rec: the reconstruction (an ``"abrdf"`` store or its folder), or an array ``(T, 6561, 3)``.
        ref: the dense reference, same layout (a store gives the map its shape).
        metrics: names among ``"de76"``, ``"logerr"``.
        batch: texels evaluated per call (one compilation for any size).

    Returns:
        ``{name: (rows, columns) float64 map}`` (``(1, T)`` when neither input is a store).
    """
    names = tuple(metrics)
    unknown = [n for n in names if n not in _METRICS]
    if unknown:
        raise InputError(f"unknown metric(s) {unknown}; choose from {tuple(_METRICS)}")

    def reader(x):
        if isinstance(x, np.ndarray):
            return len(x), None, lambda a, b: x[a:b]
        s = _open(x)
        return s.n_texels, s.texel_shape, lambda a, b: s.read(a, b)

    n, shape_a, read_rec = reader(rec)
    n_ref, shape_b, read_ref = reader(ref)
    if n != n_ref:
        raise InputError(f"reconstruction has {n} texels, reference {n_ref}")
    shape = shape_a or shape_b or (1, n)
    batch = max(1, min(batch, n))
    out = {k: np.empty(n) for k in names}
    for a in range(0, n, batch):
        b = min(a + batch, n)
        x, y = read_rec(a, b), read_ref(a, b)
        if b - a < batch:  # repeat the last texel: one shape, one compilation
            x = np.concatenate([x, np.repeat(x[-1:], batch - (b - a), 0)])
            y = np.concatenate([y, np.repeat(y[-1:], batch - (b - a), 0)])
        vals = _chunk_metrics(jnp.asarray(x, jnp.float32), jnp.asarray(y, jnp.float32), names)
        for k in names:
            out[k][a:b] = np.asarray(vals[k])[: b - a]
    return {k: v.reshape(shape) for k, v in out.items()}


def mean_fill(meas, start: int = 0, stop: int | None = None) -> np.ndarray:
    """The trivial reconstruction of texels ``[start, stop)``: every pair is the mean sample.

    Returns:
        ``(n, 6561, 3)`` float32.
    """
    store = _open(meas)
    y = store.read(start, stop).astype(np.float32)
    return np.broadcast_to(y.mean(axis=1, keepdims=True), (y.shape[0], 81 * 81, 3)).copy()


def save_error_map(values: np.ndarray, path, *, title: str = "", label: str = "ΔE76",
                   vmax: float | None = None, extra: dict | None = None) -> None:
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
    panels = [(f"{title} mean {values.mean():.2f}, p95 {np.percentile(values, 95):.2f}".strip(), values)]
    panels += list((extra or {}).items())
    fig, axes = plt.subplots(1, len(panels), figsize=(4.6 * len(panels), 4.2), squeeze=False)
    for ax, (name, img) in zip(axes[0], panels):
        img = np.asarray(img)
        if img.ndim == 3:  # an RGB map (e.g. albedo), shown gamma-encoded
            ax.imshow(np.clip(img / max(img.max(), 1e-6), 0, 1) ** (1 / 2.2), interpolation="nearest")
        else:
            vm = vmax if img is values and vmax is not None else float(np.percentile(img, 99))
            im = ax.imshow(img, cmap="magma", vmin=0, vmax=vm, interpolation="nearest")
            fig.colorbar(im, ax=ax, fraction=0.046, label=label if img is values else "")
        ax.set_title(name, fontsize=9)
        ax.set_xticks([])
        ax.set_yticks([])
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
