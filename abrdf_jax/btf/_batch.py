"""Streamed, resumable, sharded reconstruction of a whole BTF: measurement store → ABRDF store.

``reconstruct_btf`` reads the measurement store chunk by chunk, maps each chunk with one jitted
:class:`~._chunkfn.ChunkFunction` (sharded over the devices, :mod:`._devices`) and writes each
result as a chunk of the output store (:mod:`._store`). Memory is bounded by a few chunks: while
chunk ``k`` is computed (JAX dispatches asynchronously), chunk ``k - 1`` is copied to the host,
checked and written.

Resume: the output store's manifest records the job (the input's identity, the configuration,
the parameters, the backend, chunk size and dtype). Rerunning the same job on the same folder
skips every chunk whose marker and checksum are valid and computes the rest; a different job on
a folder that holds one is refused unless ``overwrite``.
"""

from __future__ import annotations

import hashlib
import json
import time
from collections import deque
from concurrent.futures import ThreadPoolExecutor, wait

import jax
import jax.numpy as jnp
import numpy as np

from .._errors import InputError
from .._names import BTF_MODELS, DIRECT_MODELS, LEARNED_MODELS
from .._params import Config, Params, preset
from ..select._isotropy import LEVEL, MIN_EFFECT
from ._chunkfn import BACKENDS, N_PAIRS, _alpha_deg, grouping, make_chunk_fn
from ._chunkfn import make_model_choice_fn, texel_isotropy
from ._bivariate import make_bivariate_chunk_fn
from ._learned import make_learned_chunk_fn, prior_identity
from ._devices import DEFAULT_BLOCK, ShardedRunner, resolve_devices
from ._backend import DEFAULT_FORMAT, open_store, store_class
from ._store import ABRDF_GEOMETRY, ChunkedStore, pad_rows, progress_bar

#: Texels per chunk when none is given (about 40 MB of float16 output per chunk).
DEFAULT_CHUNK = 1024
#: Threads that write finished chunks (the file system's copy and fsync run beside the compute),
#: and how many computed chunks may wait for them.
WRITERS = 2
IN_FLIGHT = 3


def default_config(budget: str = "aniso204") -> Config:
    """The BTF default, ``preset("operator", budget)``: the recommended kernel with the log taken of
    the samples.

    ``value_space="logsamples"`` with a linear rule (``"average"`` of the two slices in log
    space, i.e. their geometric mean, for aniso204) makes the whole reconstruction
    ``exp(M · ln(y + ε)) − ε`` with one fixed matrix ``M`` (:mod:`abrdf_jax._operator`): one
    matrix product per chunk. On procedural BTF texels (seed 0, 16 × 16, mean ΔE76) it was also
    the most accurate choice: 12.84 against 12.96 for ``Config.recommended`` (rule ``filip2012``,
    log after the rule, pipeline only), 13.31 with rule ``"crossing"``; mean fill 19.87
    (``python -m benchmarks.btf``, table "configuration", 2026-12-04).
    """
    return preset("operator", budget)


def store_identity(store: ChunkedStore) -> str:
    """A digest of a store's manifest and of every chunk's checksum (its content's identity)."""
    h = hashlib.sha256(json.dumps(store.manifest, sort_keys=True).encode())
    for k in range(store.n_chunks):
        h.update(json.dumps(store._marker(k), sort_keys=True).encode())
    return h.hexdigest()[:32]


_CHUNK_FNS: dict = {}


def _chunk_fn(config, params, geometry, backend, dtype, model="fixed", prior=None):
    """:func:`make_chunk_fn` (``model="auto"``: :func:`make_model_choice_fn`; ``"prior"`` or
    ``"fused"``: :func:`~abrdf_jax.btf._learned.make_learned_chunk_fn` of ``prior``;
    ``"bivariate"``: :func:`~abrdf_jax.btf.make_bivariate_chunk_fn`), remembered
    for the last few settings (building an operator costs a factorisation and a pass of the
    pipeline; a resumed or repeated run reuses it)."""
    key = (repr(config), json.dumps(_params_doc(params)), json.dumps(geometry, sort_keys=True))
    key += (backend, jnp.dtype(dtype).name, model)
    if prior is not None:
        key += (json.dumps(prior_identity(prior), sort_keys=True),)
    if key not in _CHUNK_FNS:
        while len(_CHUNK_FNS) >= 4:
            _CHUNK_FNS.pop(next(iter(_CHUNK_FNS)))
        if model in LEARNED_MODELS:
            template, group = grouping(geometry, config.pairs, _alpha_deg(geometry, params))
            fn = make_learned_chunk_fn(prior, model, template, group, params, config.budget, dtype)
        elif model in DIRECT_MODELS:
            fn = make_bivariate_chunk_fn(geometry, dtype)
        else:
            make = make_model_choice_fn if model == "auto" else make_chunk_fn
            fn = make(config, params, geometry, backend=backend, dtype=dtype)
        _CHUNK_FNS[key] = fn
    return _CHUNK_FNS[key]


def _params_doc(params: Params) -> dict:
    widths = [float(w) for w in np.ravel(params.widths)]
    return dict(alpha=float(params.alpha), widths=widths, reg=float(params.reg))


def reconstruct_btf(
    meas_store,
    out_store,
    config: Config | None = None,
    params: Params | None = None,
    *,
    chunk: int = DEFAULT_CHUNK,
    progress: bool = True,
    dtype: str = "float16",
    devices=None,
    block: int = DEFAULT_BLOCK,
    backend: str = "auto",
    compute_dtype: str = "float32",
    overwrite: bool = False,
    stats: dict | None = None,
    model: str = "fixed",
    format: str = DEFAULT_FORMAT,
    prior=None,
) -> ChunkedStore:
    """Reconstruct every texel of a measured BTF into a chunked ABRDF store.

    Args:
        meas_store: a measurement :class:`ChunkedStore` or its folder (``kind="measurements"``).
        out_store: the output folder (created; an existing store of the same job is resumed).
        config: discrete choices; default :func:`default_config` (iso102 data: the
            recommended isotropic settings).
        params: α, widths, λ; default ``Params.default(config)`` at the geometry's α (float32).
        chunk: texels per output chunk (the unit of work, of resume and of memory).
        progress: show a tqdm progress bar on stderr.
        dtype: ``"float16"`` (half the disk, ~3 significant digits) or ``"float32"``.
        devices: ``None`` (all local devices), a count, or a list of devices to shard over.
        block: texels per matrix product on a device (:mod:`._devices`): results are
            bit-identical on ``d`` devices and on one when ``chunk`` is a multiple of
            ``d · block`` (the default 1024 and 128: for 1, 2, 4 or 8 devices).
        backend: ``"auto"``, ``"operator"`` or ``"pipeline"`` (:func:`make_chunk_fn`).
        compute_dtype: ``"float32"`` (fast) or ``"float64"`` (needs ``jax_enable_x64``; the
            float32 pipeline's ill-conditioned RBF solve makes results depend on the batch size
            at the 1e-2 relative level, float64 does not).
        overwrite: replace an output store of a different job.
        model: ``"fixed"`` (``config`` for every texel) or ``"auto"``: per texel, the isotropy
            test of :mod:`abrdf_jax.select` on its axial slices picks the bivariate model (an
            isotropic texel, every sample: :mod:`abrdf_jax.btf._bivariate`) or ``config`` (which
            must be ``aniso204``); see :func:`isotropy_map` for the decisions; ``"bivariate"``:
            every texel with the bivariate model; ``"prior"`` or
            ``"fused"``: every texel with the learned model of ``prior`` (the prior alone, or
            fused with a kernel on its residual at the prior's own hyper-parameters) on the
            slices of ``config``'s budget, one matrix product per chunk
            (:mod:`abrdf_jax.btf._learned`; ``backend`` does not apply).
        format: the output's storage backend, ``"npy"`` (:class:`ChunkedStore`, the default)
            or ``"zarr"`` (a zarr v3 group; ``chunk`` a multiple of the width or a divisor of
            it, so chunks are tiles; see ``docs/btf.md``).
        prior: the :class:`abrdf_jax.prior.Prior` of ``model="prior"|"fused"`` (default the
            package's default prior, :func:`abrdf_jax.prior.default_prior`).
        stats: if given, filled with ``chunks_done``, ``chunks_skipped``, ``seconds`` (the
            whole call), ``first_chunk_seconds`` (compilation included), ``backend``,
            ``devices``, ``batch``, ``build_seconds`` (the chunk map: operator or pipeline
            setup, 0 when reused), and the busy seconds of the three overlapping stages
            ``read_seconds``, ``compute_seconds``, ``write_seconds`` (see :func:`_stream`).

    Returns:
        The output :class:`ChunkedStore` (complete for the chunks this process owns).

    Raises:
        InputError: bad arguments, an input that is not a complete measurement store, an output
            folder that holds something else.
    """
    t_start = time.perf_counter()
    meas, work, config, alpha_deg = _inputs(meas_store, config, compute_dtype)
    if meas.item_shape[1:] != (3,):
        raise InputError(f"{meas.path}: samples must be RGB, item shape is {meas.item_shape}")
    geometry = meas.geometry
    if params is None:
        params = Params.default(config, alpha_deg=alpha_deg, dtype=work)
    if backend not in BACKENDS:
        raise InputError(f"backend must be one of {BACKENDS}, got {backend!r}")
    if model not in BTF_MODELS:
        raise InputError(f"model must be one of {BTF_MODELS}, got {model!r}")
    if prior is not None and model not in LEARNED_MODELS:
        raise InputError(f"prior is read only by model='prior' or 'fused', not {model!r}")
    if model in LEARNED_MODELS and prior is None:
        from ..prior import default_prior

        prior = default_prior()
    if model == "auto" and {config.budget, geometry.get("budget", "aniso204")} != {"aniso204"}:
        raise InputError(
            "model='auto' chooses between iso102 and aniso204 per texel: it needs an aniso204 "
            f"configuration and measurement (got {config.budget!r}); use model='fixed'"
        )
    # The job is what the results depend on; "auto" resolves the same way every time.
    job = dict(input=store_identity(meas), config=repr(config), params=_params_doc(params))
    job.update(backend=backend, compute_dtype=compute_dtype, model=model)
    if model == "auto":  # the isotropic texels' model (the RBF's iso before 2026-12-06)
        job.update(isotropic_model="bivariate")
    if prior is not None:
        job.update(prior=prior_identity(prior))
    attrs = dict(job=job, source=meas.attrs)
    shape = dict(texel_shape=meas.texel_shape, item_shape=(N_PAIRS, 3), dtype=dtype, chunk=chunk)
    out = store_class(format).create(
        out_store, kind="abrdf", geometry=ABRDF_GEOMETRY, attrs=attrs, overwrite=overwrite, **shape
    )
    pid, nproc = jax.process_index(), jax.process_count()
    if nproc == 1:
        out.remove_temporary()
    mine = list(range(pid, out.n_chunks, nproc))
    todo = [k for k in mine if not out.is_done(k, verify=True)]
    devices = resolve_devices(devices)
    info = dict(chunks_done=0, chunks_skipped=len(mine) - len(todo), devices=len(devices))
    info.update(backend=None, batch=None, first_chunk_seconds=0.0)
    info.update(build_seconds=0.0, read_seconds=0.0, compute_seconds=0.0, write_seconds=0.0)
    if todo:  # build (or reuse) the chunk map only when there is work
        t = time.perf_counter()
        chunk_fn = _chunk_fn(config, params, geometry, backend, work, model, prior)
        info["build_seconds"] = time.perf_counter() - t
        runner = ShardedRunner(chunk_fn, devices, np.dtype(dtype), block)
        info.update(backend=chunk_fn.backend, batch=runner.batch_size(chunk))

    total = out.texels(mine)
    with progress_bar("btf reconstruct", total, progress, initial=total - out.texels(todo)) as bar:
        if todo:
            _stream(meas, out, todo, runner, work, info, bar)
    out.finish()  # zarr: consolidated metadata once the last chunk is in (also on a rerun)
    info["seconds"] = time.perf_counter() - t_start
    if stats is not None:
        stats.update(info)
    return out


def _stream(meas, out, todo, runner, work, info, bar) -> None:
    """Read, compute and write the chunks ``todo``, the three overlapping.

    One thread reads (and checks) the next input chunk while the current one is computed;
    :data:`WRITERS` threads copy finished chunks to the host, check and write them. At most
    :data:`IN_FLIGHT` results wait for a writer (memory stays a few chunks). ``info`` gets the
    busy seconds of each stage (``read_seconds``, ``compute_seconds``: dispatch to result,
    compilation of the first chunk included; ``write_seconds``: summed over the writers), which
    overlap, so they add up to more than the wall time. A failed write stops the run after the
    writes already started have finished (their chunks stay valid).
    """

    def read(k):
        t = time.perf_counter()
        y = pad_rows(meas.read(*out.chunk_range(k)).astype(work), info["batch"])
        return y, time.perf_counter() - t

    def write(k, result):
        t = time.perf_counter()
        a, b = out.chunk_range(k)
        out.write_chunk(k, np.asarray(result)[: b - a])
        return b - a, time.perf_counter() - t

    def settle(job):
        n, seconds = job.result()
        info["write_seconds"] += seconds
        info["chunks_done"] += 1
        bar.update(n)

    with ThreadPoolExecutor(1) as reader, ThreadPoolExecutor(WRITERS) as writers:
        jobs: deque = deque()
        try:
            nxt = reader.submit(read, todo[0])
            for n, k in enumerate(todo):
                y, seconds = nxt.result()
                info["read_seconds"] += seconds
                if n + 1 < len(todo):
                    nxt = reader.submit(read, todo[n + 1])
                t0 = time.perf_counter()
                # the last texel repeated up to the batch: one shape, one compilation
                result = runner(y).block_until_ready()
                info["compute_seconds"] += time.perf_counter() - t0
                if n == 0:
                    info["first_chunk_seconds"] = time.perf_counter() - t0  # compilation included
                jobs.append(writers.submit(write, k, result))
                del result
                while len(jobs) > IN_FLIGHT or (jobs and jobs[0].done()):
                    settle(jobs.popleft())
            while jobs:
                settle(jobs.popleft())
        finally:
            for job in jobs:
                job.cancel()
            wait(jobs)


def _inputs(meas_store, config, compute_dtype):
    """The (complete) measurement store, the working dtype, the configuration (default: the BTF
    default for the store's budget) and the slice offset α in degrees."""
    meas = open_store(meas_store, "measurements", complete=True)
    if compute_dtype not in ("float32", "float64"):
        raise InputError(f"compute_dtype must be 'float32' or 'float64', got {compute_dtype!r}")
    if compute_dtype == "float64" and not jax.config.read("jax_enable_x64"):
        raise InputError("compute_dtype='float64' needs 64-bit JAX (JAX_ENABLE_X64=1)")
    config = default_config(meas.geometry.get("budget", "aniso204")) if config is None else config
    return meas, jnp.dtype(compute_dtype), config, float(meas.geometry.get("alpha_deg", 15.0))


def isotropy_map(
    meas_store,
    *,
    chunk: int = DEFAULT_CHUNK,
    config: Config | None = None,
    compute_dtype: str = "float32",
) -> dict:
    """The per-texel isotropy decisions that ``reconstruct_btf(..., model="auto")`` makes.

    Args:
        meas_store: a measurement :class:`ChunkedStore` or its folder (aniso204 geometry).
        chunk: texels per step (memory only; the decisions do not depend on it).
        config: the anisotropic configuration (default :func:`default_config`).
        compute_dtype: ``"float32"`` (what the reconstruction uses) or ``"float64"``.

    Returns:
        ``{"isotropic": bool (rows, cols), "statistic": (rows, cols), "effect": (rows, cols),
        "fraction_isotropic": float}`` (statistic: χ²/dof; effect: RMS log variation of the axial
        slices, see :func:`abrdf_jax.select.isotropy_test`).
    """
    meas, work, config, alpha_deg = _inputs(meas_store, config, compute_dtype)
    # Only the slice layout is needed (no operator): the same grouping the chunk map uses.
    template, group = grouping(meas.geometry, config.pairs, alpha_deg)
    t, count = np.asarray(template.t, np.float64), np.asarray(template.count)
    g = jnp.asarray(group, work)
    test = jax.jit(lambda g, y: texel_isotropy(g, t, count, y, level=LEVEL, min_effect=MIN_EFFECT))
    n, parts = meas.n_texels, []
    for a in range(0, n, chunk):
        y = pad_rows(meas.read(a, min(a + chunk, n)).astype(work), min(chunk, n))
        parts.append([np.asarray(v)[: n - a] for v in test(g, y)])
    iso, stat, eff = (np.concatenate(p).reshape(meas.texel_shape) for p in zip(*parts))
    return dict(isotropic=iso, statistic=stat, effect=eff, fraction_isotropic=float(iso.mean()))
