"""A built single-stage reconstruction operator as numpy arrays: applied without JAX (issue 13).

:class:`OperatorEntry` is what the operator cache (``abrdf_jax._cache``) stores and loads; its
:meth:`~OperatorEntry.apply` is the map of :class:`abrdf_jax.ReconstructionOperator` (single
stage, ``abrdf_jax._operator._apply``) in numpy float32, with the value space's ``ε`` exactly as
``abrdf_jax._values.value_eps`` computes it.
"""

from __future__ import annotations

import dataclasses
import functools

import numpy as np

from ._centre_step import CentreStep
from ._errors import InputError
from ._host_eps import sample_eps
from ._names import LOG_SAMPLES
from ._smoothing import smooth_compact, smoothing_from_json, smoothing_to_json
from ._spikes import cap_samples

GRID = (81, 81)


@dataclasses.dataclass(frozen=True, eq=False)
class OperatorEntry:
    """A built single-stage reconstruction operator as numpy arrays (no JAX needed to apply it).

    Attributes:
        matrix: ``(6561, n_in)`` float32: the linear map of ``compile_operator``.
        index: ``(n_in,)`` flat index ``s · nmax + k`` of each valid sample of the template.
        t: ``(S, nmax)`` float32 slice parameters of the template (padding zero).
        count: ``(S,)`` valid samples per slice.
        keep: output rows where the restored subspaces are kept (``ReconstructionOperator.keep``).
        log_samples: whether the map works on ``ln(max(y, 0) + ε)`` (``value_space="logsamples"``)
            or on the values themselves (``"linear"``).
        log_eps: ``Config.log_eps``: ``ε = log_eps · mean |y| + sqrt(tiny)`` per material and
            channel over the valid samples (``_values.value_eps``).
        spike_cap: ``Config.spike_cap`` (``None`` or ``(quantile, margin)``): with
            ``log_samples`` the map applies the spike cap (``_spikes.py``) as the JAX operator.
        slice_smoothing: ``Config.slice_smoothing``: with ``log_samples`` the log samples are
            smoothed first (``_smoothing.py``), as the JAX operator does.
        subspace: ``None`` (one stage: ``matrix`` reads the samples), or the per-material first
            stage of a two-stage operator (:class:`~abrdf_jax._centre_step.CentreStep`: the
            subspaces at the RBF centres, which ``matrix`` ``(6561, n_c)`` then reads).
    """

    matrix: np.ndarray
    index: np.ndarray
    t: np.ndarray
    count: np.ndarray
    keep: np.ndarray
    log_samples: bool
    log_eps: float
    spike_cap: tuple | None = None
    slice_smoothing: float | tuple | None = None
    subspace: CentreStep | None = None

    #: The entry kind in the store's metadata (entries written before kinds existed are this).
    KIND = "rbf"
    #: The arrays an entry file holds.
    ARRAYS = ("matrix", "index", "t", "count", "keep")

    @property
    def n_inputs(self) -> int:
        return int(self.index.shape[0])

    def apply(self, y) -> np.ndarray:
        """Reconstruct from stacked sample values: ``(..., S, nmax, C)`` → ``(..., 81, 81, C)``.

        The map of :class:`abrdf_jax.ReconstructionOperator` (single stage), in float32:
        ``max(post(M · pre(x)), 0)`` over the valid samples ``x``, with ``pre``/``post`` the
        identity (linear) or ``ln(max(x, 0) + ε)`` / ``exp(z) − ε``.

        Raises:
            InputError: when ``y`` does not have the template's slice shape.
        """
        (out,) = self.apply_many([self], [y])
        return out

    __call__ = apply

    @staticmethod
    def apply_many(entries, ys) -> list[np.ndarray]:
        """``[e.apply(y) for e, y in zip(entries, ys)]`` with one matrix product for all: the
        entries share one ``matrix`` (a setting's shared second stage read by many layouts,
        :meth:`for_layout`), each with its own first stage. A capture's rows of the product do
        not depend on the other rows (OpenBLAS computes each output row alike whatever the
        rows beside it: ``tests/test_engine.py`` checks the tables bit for bit), while one
        product per capture read the whole matrix (27 MB past the kept rows at the UBO centres:
        5,265 × 1,296 float32) for three rows."""
        first = entries[0]
        if any(e.matrix is not first.matrix or e.keep is not first.keep for e in entries):
            raise ValueError("apply_many needs entries that share one matrix and kept rows")
        parts = [e._features(e._compact(y)) for e, y in zip(entries, ys)]

        def joined(i):  # one entry's rows as they are (apply: no copy), else stacked
            rows = [p[i] for p in parts]
            return None if rows[0] is None else rows[0] if len(rows) == 1 else np.concatenate(rows)

        rx, rxc = joined(0), joined(1)
        out = first._product(rx, rxc)
        tables, at = [], 0
        for e, y, (r, _, eps, shape) in zip(entries, ys, parts):
            rows = out[at : at + r.shape[0]]
            at += r.shape[0]
            lead = np.shape(y)[:-3]
            tables.append(_finish(rows, eps, shape).reshape(*lead, *GRID, shape[1]))
        return tables

    def apply_compact(self, x) -> np.ndarray:
        """The same from the valid samples only, ``(B, n_in, C)`` → ``(B, 81, 81, C)``."""
        rx, rxc, eps, shape = self._features(x)
        return _finish(self._product(rx, rxc), eps, shape)

    def _compact(self, y) -> np.ndarray:
        """The valid samples ``(B, n_in, C)`` of stacked values ``(..., S, nmax, C)``."""
        y = np.asarray(y, np.float32)
        s, nmax = self.t.shape
        if y.ndim < 3 or y.shape[-3:-1] != (s, nmax):
            raise InputError(f"values must have shape (..., {s}, {nmax}, C), got {y.shape}")
        return y.reshape(-1, s * nmax, y.shape[-1])[:, self.index, :]

    def _features(self, x) -> tuple:
        """What the matrix reads of the valid samples ``x`` ``(B, n_in, C)``: every material and
        channel a row (``(B·C, n)``: one GEMM, as ``_operator``), the spike-capped rows
        (``None`` without the cap), ``ε`` ``(B, C)`` (``None`` on linear values) and ``(B, C)``."""
        x = np.asarray(x, np.float32)
        b, _, c = x.shape
        eps = xc = None
        if self.log_samples:
            eps = sample_eps(x, self.log_eps, axis=1)  # (B, C)
            x = np.log(np.maximum(x, np.float32(0.0)) + eps[:, None, :])
            x = smooth_compact(self.slice_smoothing, x, self.index, self.t, self.count, np)
            x = x.astype(np.float32)
            if self.spike_cap:
                xc = cap_samples(x, self.spike_cap, xp=np).astype(np.float32)
        if self.subspace is not None:  # two stages: the restored and the fitted subspaces,
            both = x if xc is None else np.concatenate([x, xc])  # one call: columns independent
            both = self.subspace(both, self.index, self.t, self.count)
            x, xc = (both, None) if xc is None else (both[:b], both[b:])

        def rows(v):
            return np.ascontiguousarray(np.transpose(v, (0, 2, 1))).reshape(b * c, v.shape[1])

        return rows(x), None if xc is None else rows(xc), eps, (b, c)

    def _product(self, rx, rxc) -> np.ndarray:
        """The matrix on the rows of :meth:`_features` (``rxc``: the capped rows, whose kept
        output rows take the uncapped values), ``(rows, 6561)`` float32."""
        picked = None if rxc is None else self._picked
        if picked is not None:  # kept rows that read one value each (a two-stage entry's)
            return _picked_rows(picked, rxc, rx, self.matrix.shape[0])
        out = (rx if rxc is None else rxc) @ self.matrix.T
        if rxc is not None and self.keep.size:
            kept, runs = self._kept
            fix = (rx - rxc) @ kept.T
            if runs is None:
                out[:, self.keep] += fix
            for first, stop, at in runs or ():  # in place, run by run: the same float32 sums
                out[:, first:stop] += fix[:, at : at + stop - first]
        return out

    @functools.cached_property
    def _kept(self) -> tuple[np.ndarray, list[tuple[int, int, int]] | None]:
        """The matrix's kept rows (copied once, not per batch) and ``keep`` as runs of
        consecutive rows ``(first, stop, offset in keep)`` (``None`` if a row repeats: the
        fancy-indexed update then)."""
        keep = np.asarray(self.keep)
        if np.unique(keep).size != keep.size:
            return self.matrix[keep], None
        return self.matrix[keep], _runs(keep)

    @functools.cached_property
    def _picked(self) -> tuple | None:
        """Where every kept row is one-hot with weight 1 (a two-stage entry's: the restored
        subspace value at a centre that is a grid pair, ``_operator.keep_centres``), the
        product need not run over them: ``(columns the kept rows pick, the other rows'
        matrix (copied once), the other rows' runs, the kept rows' runs)``; else ``None``."""
        keep = np.asarray(self.keep)
        if keep.size == 0:  # off the UBO rings no centre is a grid pair: nothing is kept
            return None
        kept, runs = self._kept
        hot = kept != 0
        if runs is None or not (np.all(hot.sum(axis=1) == 1) and np.all(kept[hot] == 1)):
            return None
        rest = np.setdiff1d(np.arange(self.matrix.shape[0]), keep)
        return np.argmax(hot, axis=1), self.matrix[rest], _runs(rest), runs

    def for_layout(self, config, params, meas) -> "OperatorEntry":
        """This two-stage entry (its matrix from the RBF centres, any sample layout's and any
        rule's) for the samples of ``meas`` and ``config``: its first stage (the values it
        reads, :class:`CentreStep` with ``params``' α) and layout arrays are theirs; the matrix,
        and the views of it that applying it makes once (``_kept``, ``_picked``), are shared
        (``abrdf_jax._cache.cached_entry``)."""
        from ._host_build import sample_index, template_layout

        t, count = template_layout(meas)
        made = dataclasses.replace(
            self,
            index=sample_index(t, count).astype(np.int64),
            t=np.asarray(t, np.float32),
            count=np.asarray(count, np.int32),
            log_samples=config.value_space in LOG_SAMPLES,
            log_eps=float(config.log_eps),
            spike_cap=config.spike_cap,
            slice_smoothing=config.slice_smoothing,
            subspace=CentreStep.of(config, params, meas),
        )
        self._picked  # noqa: B018 - made once here, then handed on
        for name in ("_kept", "_picked"):  # cached properties of the matrix and kept rows only
            if name in self.__dict__:
                made.__dict__[name] = self.__dict__[name]
        return made

    def arrays(self) -> dict[str, np.ndarray]:
        """The arrays by name (what the cache stores)."""
        return {name: getattr(self, name) for name in self.ARRAYS}

    def meta(self) -> dict:
        """The entry's scalars (stored in its metadata beside the arrays)."""
        cap = None if self.spike_cap is None else [float(v) for v in self.spike_cap]
        return {
            "log_samples": bool(self.log_samples),
            "log_eps": float(self.log_eps),
            "spike_cap": cap,
            "slice_smoothing": smoothing_to_json(self.slice_smoothing),
            **({} if self.subspace is None else {"subspace": self.subspace.to_json()}),
        }

    @classmethod
    def from_stored(cls, arrays: dict[str, np.ndarray], meta: dict) -> "OperatorEntry":
        cap = meta.get("spike_cap")
        cap = None if cap is None else tuple(cap)
        step = meta.get("subspace")
        return cls(
            **arrays,
            log_samples=meta["log_samples"],
            log_eps=meta["log_eps"],
            spike_cap=cap,
            slice_smoothing=smoothing_from_json(meta.get("slice_smoothing")),
            subspace=None if step is None else CentreStep.from_json(step),
        )

    @staticmethod
    def check(arrays: dict[str, np.ndarray], meta: dict) -> str | None:
        """What is wrong with stored arrays and scalars (``None``: nothing)."""
        m = arrays["matrix"]
        if not (m.dtype == np.float32 and m.ndim == 2 and m.shape[0] == GRID[0] * GRID[1]):
            return "malformed (inconsistent array shapes)"
        keep = arrays.get("keep")
        if (
            keep is None
            or keep.ndim != 1
            or (keep.size and not 0 <= keep.min() <= keep.max() < m.shape[0])
        ):
            return "malformed (no kept rows)"
        n_in, step = m.shape[1], meta.get("subspace")
        if step is not None:  # two stages: the step reads the samples, the matrix the centres
            try:
                step = CentreStep.from_json(step)
            except (ValueError, TypeError, KeyError):
                return "malformed (no centre step)"
            if m.shape[1] != step.n_centres:
                return "malformed (inconsistent array shapes)"
            n_in = arrays["index"].shape[0]
        problem = check_layout(arrays, n_in)
        if problem or int(arrays["count"].sum()) != n_in:  # every valid sample is read
            return problem or "malformed (inconsistent array shapes)"
        if not isinstance(meta.get("log_samples"), bool) or not isinstance(
            meta.get("log_eps"), float
        ):
            return "malformed (no value space)"
        return None


def _finish(out: np.ndarray, eps, shape: tuple) -> np.ndarray:
    """The tables ``(B, 81, 81, C)`` of the product's rows ``out`` ``(B·C, 6561)`` (in place):
    ``exp(z) − ε`` on log samples (``eps`` ``(B, C)``), clamped at 0, channels last."""
    b, c = shape
    out = out.reshape(b, c, -1)
    if eps is not None:
        np.exp(out, out=out)
        out -= eps[:, :, None]
    np.maximum(out, np.float32(0.0), out=out)
    # channel last: one strided copy per channel (faster than one of the transposed array)
    return np.stack([out[:, k] for k in range(c)], axis=-1).reshape(b, *GRID, c)


def _runs(rows: np.ndarray) -> list[tuple[int, int, int]]:
    """Distinct increasing ``rows`` as runs of consecutive rows ``(first, stop, offset)``."""
    if rows.size == 0:
        return []
    cuts = [0, *(np.flatnonzero(np.diff(rows) != 1) + 1).tolist(), rows.size]
    return [(int(rows[a]), int(rows[a]) + (z - a), a) for a, z in zip(cuts[:-1], cuts[1:])]


def _picked_rows(picked: tuple, capped: np.ndarray, restored: np.ndarray, q: int) -> np.ndarray:
    """The ``(n, q)`` product of :meth:`OperatorEntry.apply_compact` where the kept rows are
    one-hot (``OperatorEntry._picked``): the other rows' product on the ``capped`` features, the
    kept rows the ``restored`` (uncapped) features they pick, as the JAX operator sets them
    (a fifth fewer rows in the product for a two-stage entry, and no product for the kept
    rows' correction)."""
    cols, rest, rest_runs, kept_runs = picked
    part = capped @ rest.T
    out = np.empty((capped.shape[0], q), np.float32)
    for first, stop, at in rest_runs:
        out[:, first:stop] = part[:, at : at + stop - first]
    values = restored[:, cols]
    for first, stop, at in kept_runs:
        out[:, first:stop] = values[:, at : at + stop - first]
    return out


def check_layout(arrays: dict[str, np.ndarray], n_in: int) -> str | None:
    """The template's layout arrays (``index``, ``t``, ``count``) of an entry reading ``n_in``
    valid samples: consistent shapes and an index inside the slices (``None``: fine)."""
    index, t, count = (arrays[n] for n in ("index", "t", "count"))
    if not (
        index.shape == (n_in,)
        and t.ndim == 2
        and count.shape == (t.shape[0],)
        and int(count.sum()) >= n_in
        and (index.size == 0 or 0 <= int(index.min()) <= int(index.max()) < t.size)
    ):
        return "malformed (inconsistent array shapes)"
    return None


def digest(arrays: dict[str, np.ndarray]) -> str:
    """CRC-32C (hex) of named arrays: names, dtypes, shapes and bytes, read in place. The
    store's check on load against a truncated or corrupted file: the BTF store's checksum
    (``abrdf_jax.btf._checksum``; sha256 over a copy was a large part of loading a 34 MB
    two-stage entry)."""
    from .btf._checksum import CHECKSUM, checksum

    parts = []
    for name in sorted(arrays):
        a = np.ascontiguousarray(arrays[name])
        parts += [f"{name}:{a.dtype.str}:{a.shape};".encode(), memoryview(a).cast("B")]
    return f"{checksum(*parts)[CHECKSUM]:08x}"
