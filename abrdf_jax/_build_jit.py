"""``build_jit``: the jit of computations that run once per cache entry, compiled cheaply.

Building a reconstruction operator (``_operator._build``) or the held-out matrices of the
automatic model choice (``select._select.held_out_terms``) runs once per sample layout; its
result is stored (``abrdf_jax._cache``) and applied many times without JAX. On a cold call the
XLA compile of that one-off program is most of the time, its run a small part: so it is
compiled at XLA's lowest backend optimisation level, without LLVM's expensive passes and with
the CPU backend's older (non-MLIR) fusion emitters (a cold ``abrdf-jax reconstruct`` of one
iso102 file: ``python -m benchmarks.cli``). The numbers are
those of the optimised program to rounding: the same operations, in the same order, without
the optimiser's fusions (tests/test_build_jit.py compares them). A jaxlib that does not know
an option compiles with the others (:data:`FAST_COMPILE` is tried first, then
:data:`SAFE_COMPILE`).

Semantics as ``equinox.filter_jit``: arrays (JAX or numpy) are traced, everything else is
static (hashed; a new static value compiles again).
"""

from __future__ import annotations

import functools

import equinox as eqx
import jax

#: XLA debug options of a build-once program (``jax.jit(..., compiler_options=...)``).
SAFE_COMPILE = {"xla_backend_optimization_level": 0, "xla_llvm_disable_expensive_passes": True}
FAST_COMPILE = {**SAFE_COMPILE, "xla_cpu_use_fusion_emitters": False}
#: Whether this jaxlib took :data:`FAST_COMPILE` (``None``: not tried yet).
_FAST_OK: list[bool | None] = [None]


def _unknown_option(err: Exception) -> bool:
    return "compile option" in str(err).lower() or "xla_cpu_use_fusion_emitters" in str(err)


class _Static:
    """The static part of a call as a hashable key: its tree structure and its leaves."""

    def __init__(self, tree):
        self.leaves, self.treedef = jax.tree_util.tree_flatten(tree)
        self._key = (self.treedef, tuple(self.leaves))

    def __hash__(self) -> int:
        return hash(self._key)

    def __eq__(self, other) -> bool:
        return isinstance(other, _Static) and self._key == other._key

    def tree(self):
        return jax.tree_util.tree_unflatten(self.treedef, self.leaves)


def _top_level() -> bool:
    """Whether no JAX transformation is tracing (compiler options apply to top-level jits only:
    inside a user's ``jit``/``grad`` the build is part of the user's program)."""
    try:
        from jax._src.core import trace_state_clean
    except ImportError:  # another JAX: the plain jit, correct and compiled as usual
        return False
    return trace_state_clean()


def build_jit(fun):
    """``fun`` compiled once per static signature with :data:`FAST_COMPILE` at the top level
    (see the module docstring), as a plain jit inside a transformation; call it as ``fun``."""

    def body(arrays, static: _Static):
        args, kwargs = eqx.combine(arrays, static.tree())
        return fun(*args, **kwargs)

    fast = jax.jit(body, static_argnums=1, compiler_options=FAST_COMPILE)
    safe = jax.jit(body, static_argnums=1, compiler_options=SAFE_COMPILE)
    plain = jax.jit(body, static_argnums=1)

    @functools.wraps(fun)
    def call(*args, **kwargs):
        arrays, static = eqx.partition((args, kwargs), eqx.is_array)
        if not _top_level():
            return plain(arrays, _Static(static))
        if _FAST_OK[0] is False:
            return safe(arrays, _Static(static))
        try:
            out = fast(arrays, _Static(static))
        except Exception as err:  # noqa: BLE001 - only an unknown option falls back
            if _FAST_OK[0] or not _unknown_option(err):
                raise
            _FAST_OK[0] = False
            return safe(arrays, _Static(static))
        _FAST_OK[0] = True
        return out

    return call
