"""Texel-axis sharding over the devices of a host, and ``jax.distributed`` across hosts.

On one host, a chunk of texels is split over the local devices along its texel axis: a 1-D
``jax.sharding.Mesh`` named ``"texels"``, the input and the output sharded as
``NamedSharding(mesh, P("texels"))``, the chunk map's constants (grouping matrix, operator,
parameters) replicated, and the chunk map run per device by ``jax.shard_map`` under one
``jax.jit``. Texels are independent, so the program communicates nothing.

Identical results on any device count: each device runs its share as a loop
(``jax.lax.map``) over *blocks* of a fixed number of texels, so every matrix product has the
same shape whatever the device count, and XLA picks the same kernels and summation order. A
chunk of ``C`` texels therefore gives bit-identical results on ``d`` devices and on one when
``C`` is a multiple of ``d · block`` (tested with 8 simulated CPU devices). Without the blocks
the product's row count would change with ``d`` and float32 results differ in the last bits.

Across hosts, :func:`init_distributed` starts ``jax.distributed`` (only when asked). Each process
then owns the chunks ``k`` with ``k % process_count == process_index`` and shards them over its
own devices; the store folder must be on a file system all hosts share. Chunks are files of their
own, so processes never write the same file, and a resumed run (with any number of processes)
skips every finished chunk. Processes do not exchange data: a slow or failed host delays only its
own chunks, which a rerun picks up.
"""

from __future__ import annotations

from functools import partial

import equinox as eqx
import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from .._errors import InputError

AXIS = "texels"


def init_distributed(
    coordinator_address: str | None = None,
    num_processes: int | None = None,
    process_id: int | None = None,
    **kwargs,
) -> tuple[int, int]:
    """Start ``jax.distributed`` for a multi-host run; returns ``(process_index, process_count)``.

    Call it once per process, before any other JAX call. With no arguments JAX detects the
    cluster (SLURM, Open MPI, Kubernetes, cloud TPU); otherwise give all three, e.g. on two hosts::

        # host 0                                    # host 1
        init_distributed("10.0.0.1:1234", 2, 0)     init_distributed("10.0.0.1:1234", 2, 1)

    or from the command line ``abrdf-jax btf reconstruct ... --coordinator 10.0.0.1:1234
    --num-processes 2 --process-id K``.

    Raises:
        InputError: only some of the three arguments given; ``jax.distributed`` refused to start
            (already started, JAX already in use, or no cluster detected without arguments).
    """
    given = [a is not None for a in (coordinator_address, num_processes, process_id)]
    if any(given) and not all(given):
        raise InputError(
            "init_distributed: give coordinator_address, num_processes and process_id together, or none"
        )
    try:
        jax.distributed.initialize(coordinator_address, num_processes, process_id, **kwargs)
    except (RuntimeError, ValueError) as e:  # called twice, after JAX started, or no cluster found
        raise InputError(f"jax.distributed could not start: {e}") from e
    return jax.process_index(), jax.process_count()


def resolve_devices(devices=None) -> list:
    """The devices to shard over: ``None`` → all local devices; an int ``n`` → the first ``n``."""
    local = jax.local_devices()
    if devices is None:
        return list(local)
    if isinstance(devices, (int, np.integer)):
        if not 1 <= devices <= len(local):
            raise InputError(f"devices must be in 1..{len(local)} (local devices), got {devices}")
        return list(local[:devices])
    out = list(devices)
    if not out:
        raise InputError("devices: empty list")
    return out


#: Texels per matrix product on a device (see the module docstring); 1024-texel chunks on 1, 2,
#: 4 or 8 devices all run blocks of this size.
DEFAULT_BLOCK = 128


def padded_batch(chunk: int, n_devices: int, block: int = DEFAULT_BLOCK) -> int:
    """The batch a chunk of ``chunk`` texels is padded to on ``n_devices`` devices: the next
    multiple of ``n_devices × b``, with ``b`` the block or, for a small chunk,
    ``ceil(chunk / n_devices)`` (:meth:`ShardedRunner.batch_size`)."""
    step = n_devices * min(block, -(-chunk // n_devices))
    return -(-chunk // step) * step


def _local(arrays, y, static, block, out_dtype):
    """One device's share: the chunk map over blocks of ``block`` texels (one shape, any count)."""
    fn = eqx.combine(arrays, static)
    blocks = y.reshape(y.shape[0] // block, block, *y.shape[1:])
    out = jax.lax.map(lambda b: fn(b).astype(out_dtype), blocks)
    return out.reshape(y.shape[0], *out.shape[2:])


def _run(static, arrays, y, mesh, block, out_dtype):
    local = partial(_local, static=static, block=block, out_dtype=out_dtype)
    spec = PartitionSpec(AXIS)
    return jax.shard_map(
        local, mesh=mesh, in_specs=(PartitionSpec(), spec), out_specs=spec, check_vma=False
    )(arrays, y)


# One jitted function per (devices, block, dtype): the chunk map's structure is a static
# argument, so a new ChunkFunction of the same configuration (new parameter values, a new run)
# reuses the compiled program instead of compiling again.
_JITS: dict = {}


def _sharded_jit(devices: tuple, block: int, out_dtype: str):
    key = (devices, block, out_dtype)
    if key not in _JITS:
        mesh = Mesh(np.asarray(devices), (AXIS,))
        data, replicated = (
            NamedSharding(mesh, PartitionSpec(AXIS)),
            NamedSharding(mesh, PartitionSpec()),
        )
        fn = jax.jit(
            partial(_run, mesh=mesh, block=block, out_dtype=np.dtype(out_dtype)),
            static_argnums=0,
            in_shardings=(replicated, data),
            out_shardings=data,
        )
        _JITS[key] = (fn, data, replicated)
    return _JITS[key]


class ShardedRunner:
    """``runner(y) -> tables``: a chunk map run with its texel axis sharded over ``devices``.

    The input ``y`` and the output are ``NamedSharding(Mesh(devices, ("texels",)),
    P("texels"))``; the chunk map's arrays are replicated; each device loops over blocks of
    ``block`` texels. Compiled once per chunk-map structure, device set, block, dtype and batch.

    Args:
        chunk_fn: the pure chunk map (an ``eqx.Module``; its non-array fields must be hashable).
        devices: list of devices (see :func:`resolve_devices`).
        out_dtype: dtype of the returned tables (the cast happens on the devices).
        block: texels per matrix product on a device (:data:`DEFAULT_BLOCK`); a chunk smaller
            than ``devices · block`` runs one smaller block per device.
    """

    def __init__(self, chunk_fn, devices, out_dtype, block: int = DEFAULT_BLOCK):
        if not isinstance(block, (int, np.integer)) or block < 1:
            raise InputError(f"block must be a positive integer, got {block!r}")
        self.devices, self.block = list(devices), int(block)
        self._out_dtype = np.dtype(out_dtype).name
        arrays, self._static = eqx.partition(chunk_fn, eqx.is_array)
        self._arrays = jax.device_put(
            arrays, _sharded_jit(tuple(self.devices), self.block, self._out_dtype)[2]
        )

    def batch_size(self, chunk: int) -> int:
        """The padded batch of a chunk (:func:`padded_batch` on these devices and block)."""
        return padded_batch(chunk, len(self.devices), self.block)

    def __call__(self, y: np.ndarray):
        """Dispatch one padded batch ``(B, n, 3)`` (from :meth:`batch_size`); returns a (still
        computing) JAX array."""
        per_device, rem = divmod(y.shape[0], len(self.devices))
        block = min(self.block, per_device)
        if rem or block == 0 or per_device % block:
            raise ValueError(
                f"batch of {y.shape[0]} texels is not a multiple of {len(self.devices)} devices "
                f"x blocks of {block}; pad it to batch_size()"
            )
        run, data, _ = _sharded_jit(tuple(self.devices), block, self._out_dtype)
        return run(self._static, self._arrays, jax.device_put(y, data))
