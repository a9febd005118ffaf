"""Prior files: a versioned ``.npz`` with JSON metadata, written atomically, checked on reading.

Layout (format ``abrdf_jax.prior/1``): one compressed ``.npz`` (``numpy.savez_compressed``)
holding:

- ``metadata``: ``uint8`` bytes of UTF-8 JSON with at least ``format`` (``"abrdf_jax.prior/1"``),
  ``channels`` (``"joint"``/``"shared"``) and ``eps`` (> 0); also what the prior was trained on
  (``trained_on``: name, sha256, source of every input), ``package_version`` and how K and λ
  were chosen; optionally ``fused``, the fused model's fixed hyper-parameters
  (:mod:`abrdf_jax.prior._fused_settings`).
- ``mean`` ``(D,)``, ``components`` ``(D, K)``, ``reference`` ``(6561, 3)``, ``lam`` ``()``: float
  arrays, ``D = 6561·3`` (joint) or ``6561`` (shared), ``K ≥ 1``.
- optionally ``weights`` ``(R, K)``: the components as combinations of the ``R`` training rows
  (the default prior: its training materials are analytic and evaluated at the exact sample
  directions, :func:`~abrdf_jax.prior.sample_basis`).
- optionally ``ceiling`` ``(D,)``: the largest mapped training value of each position (the
  reconstructions' clip, :attr:`~abrdf_jax.prior.Prior.ceiling`); a file without it is read as
  before (no clip).

Reading needs numpy only (no JAX): :func:`read_prior_file` and :func:`prior_info`; every problem
(missing, truncated, corrupt, another format version, missing or inconsistent fields) is an
:class:`~abrdf_jax.InputError` that names the file and the field.
"""

from __future__ import annotations

import json
import os
import zipfile
from pathlib import Path

import numpy as np

from .._errors import InputError, located
from ..io._atomic import _check_readable, atomic_write
from ..io._untrusted import check_npz
from ._fused_settings import check_fused

#: The file format this version writes and reads.
PRIOR_FORMAT = "abrdf_jax.prior/1"
ARRAYS = ("mean", "components", "reference", "lam")
#: Arrays a prior file may hold (older readers ignore them; the format stays the same).
OPTIONAL = ("weights", "ceiling")
_CHANNEL_WIDTH = {"joint": 3, "shared": 1}
_PAIRS = 6561


def save_prior(prior, path: str | os.PathLike) -> Path:
    """Write ``prior`` to ``path`` (``.npz``) atomically; returns the path.

    Raises:
        InputError: not an ``.npz`` name, or the file cannot be written.
    """
    path = Path(path)
    if path.suffix.lower() != ".npz":
        raise InputError(f"{path}: a prior file must end in .npz, got {path.suffix or '(none)'!r}")
    meta = {**prior.metadata, "format": PRIOR_FORMAT, "channels": prior.channels}
    meta["eps"] = float(prior.eps)
    arrays = {name: np.asarray(getattr(prior, name)) for name in ARRAYS}
    for name in OPTIONAL:
        if getattr(prior, name) is not None:
            arrays[name] = np.asarray(getattr(prior, name))
    text = json.dumps(meta, sort_keys=True).encode()
    with atomic_write(path, "wb") as f:
        np.savez_compressed(f, metadata=np.frombuffer(text, np.uint8), **arrays)
    return path


def _fail(path: Path, field: str | None, message: str) -> InputError:
    where = f"field {field!r}: " if field else ""
    return located(f"not a valid prior file: {where}{message}", path)


def read_prior_file(path: str | os.PathLike) -> tuple[dict[str, np.ndarray], dict]:
    """The arrays and metadata of a prior file, every field checked (numpy only).

    Returns:
        ``(arrays, metadata)``: ``arrays`` holds ``mean``, ``components``, ``reference``,
        ``lam`` as stored (dtype kept).

    Raises:
        InputError: naming the file and the field.
    """
    path = Path(path)
    _check_readable(path)
    try:
        check_npz(path)  # member names, sizes and array headers, before anything is inflated
        with zipfile.ZipFile(path) as zf:
            bad = zf.testzip()  # every member's CRC: a truncated or flipped file fails here
            if bad is not None:
                raise _fail(path, bad.removesuffix(".npy"), "corrupt (CRC mismatch)")
            held = {n.removesuffix(".npy") for n in zf.namelist()}
        with np.load(path, allow_pickle=False) as z:
            if "metadata" not in held:
                raise _fail(path, "metadata", "missing (not an abrdf_jax prior file?)")
            raw = {name: np.array(z[name]) for name in held & {"metadata", *ARRAYS, *OPTIONAL}}
    except InputError:
        raise
    except Exception as e:  # noqa: BLE001 - zipfile, zlib and numpy raise many types
        raise located(f"cannot read as a prior .npz (truncated or corrupt?): {e}", path) from e
    meta = _metadata(path, raw.pop("metadata"))
    for name in (*ARRAYS, *OPTIONAL):
        if name not in raw:
            if name in OPTIONAL:
                continue
            raise _fail(path, name, "missing")
        a = raw[name]
        if not np.issubdtype(a.dtype, np.floating):
            raise _fail(path, name, f"dtype {a.dtype}, expected a floating type")
        if not np.all(np.isfinite(a)):
            raise _fail(path, name, "holds NaN or infinite values")
    _check_shapes(path, raw, meta)
    return raw, meta


def _metadata(path: Path, raw: np.ndarray) -> dict:
    if raw.dtype != np.uint8 or raw.ndim != 1:
        raise _fail(path, "metadata", f"expected uint8 JSON bytes, got {raw.dtype} {raw.shape}")
    try:
        meta = json.loads(raw.tobytes().decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise _fail(path, "metadata", f"not JSON text ({e})") from e
    if not isinstance(meta, dict):
        raise _fail(path, "metadata", "not a JSON object")
    fmt = meta.get("format")
    if fmt != PRIOR_FORMAT:
        raise _fail(path, "format", f"{fmt!r}; this version reads {PRIOR_FORMAT!r}")
    if meta.get("channels") not in _CHANNEL_WIDTH:
        raise _fail(path, "channels", f"{meta.get('channels')!r}, expected 'joint' or 'shared'")
    eps = meta.get("eps")
    if not isinstance(eps, (int, float)) or isinstance(eps, bool) or not eps > 0:
        raise _fail(path, "eps", f"{eps!r}, expected a number > 0")
    if "fused" in meta:  # optional: the fused model's fixed hyper-parameters
        problem = check_fused(meta["fused"])
        if problem:
            raise _fail(path, "fused", problem)
    return meta


def _check_shapes(path: Path, a: dict, meta: dict) -> None:
    d = _PAIRS * _CHANNEL_WIDTH[meta["channels"]]
    expected = {"mean": (d,), "reference": (_PAIRS, 3), "lam": ()}
    for name, shape in expected.items():
        if a[name].shape != shape:
            raise _fail(
                path,
                name,
                f"shape {a[name].shape}, expected {shape} (channels {meta['channels']!r})",
            )
    comps = a["components"]
    if comps.ndim != 2 or comps.shape[0] != d or comps.shape[1] < 1:
        raise _fail(path, "components", f"shape {comps.shape}, expected ({d}, K) with K >= 1")
    w = a.get("weights")
    if w is not None and (w.ndim != 2 or w.shape[1] != comps.shape[1] or w.shape[0] < 2):
        raise _fail(path, "weights", f"shape {w.shape}, expected (R, {comps.shape[1]}), R >= 2")
    top = a.get("ceiling")
    if top is not None and (top.shape != (d,) or not np.all(np.isfinite(top))):
        raise _fail(path, "ceiling", f"shape {top.shape}, expected ({d},) finite values")
    if not float(a["lam"]) >= 0:
        raise _fail(path, "lam", f"{float(a['lam'])}, expected >= 0")
    if np.any(a["reference"] < 0):
        raise _fail(path, "reference", "holds negative values")


def load_prior(path: str | os.PathLike):
    """Read a :class:`~abrdf_jax.prior.Prior` from a file written by :func:`save_prior`.

    The arrays keep their stored dtype, bit for bit.

    Raises:
        InputError: naming the file and the field (see :func:`read_prior_file`).
    """
    import jax.numpy as jnp

    from ._model import Prior

    arrays, meta = read_prior_file(path)
    eps, channels = float(meta.pop("eps")), meta.pop("channels")
    meta.pop("format")
    return Prior(
        **{k: jnp.asarray(v) for k, v in arrays.items()},
        eps=eps,
        channels=channels,
        meta=json.dumps(meta, sort_keys=True),
    )


def prior_info(path: str | os.PathLike) -> dict:
    """A summary of a prior file (numpy only): format, layout, K, λ, ε, what it was trained on."""
    arrays, meta = read_prior_file(path)
    trained = meta.get("trained_on", [])
    return {
        "file": str(path),
        "format": meta["format"],
        "channels": meta["channels"],
        "eps": meta["eps"],
        "n_components": int(arrays["components"].shape[1]),
        "lam": float(arrays["lam"]),
        "dtype": str(arrays["components"].dtype),
        "n_materials": len(trained),
        "package_version": meta.get("package_version"),
        "trained_on": trained,
        **{k: meta[k] for k in ("provenance", "selection", "licence", "fused") if k in meta},
    }
