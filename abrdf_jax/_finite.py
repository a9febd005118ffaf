"""Non-finite inputs refused, outside and inside ``jit`` (issue 16): a NaN sample would otherwise
spread over the whole reconstructed table.

Where the values are concrete (numpy, or JAX arrays outside a transformation) a NaN or an
infinity is an :class:`~abrdf_jax.InputError` naming the input and the first bad index, raised
before any numerics. Inside a user's ``jax.jit``/``vmap``/``grad`` the values are tracers: there
the check is :func:`equinox.error_if`: the compiled function, run on a non-finite input, raises
an error carrying the same message (``equinox.EquinoxRuntimeError`` under ``eqx.filter_jit``;
under ``jax.jit`` JAX's ``JaxRuntimeError``, a ``RuntimeError``, or a ``ValueError`` when it
passes through a nested ``filter_jit`` such as the operator's). Equinox's
``EQX_ON_ERROR=nan`` turns the error into NaN outputs instead, ``EQX_ON_ERROR=breakpoint`` stops
in a debugger.

:func:`require_finite` is public: the compiled operator (:class:`abrdf_jax.ReconstructionOperator`)
does not check its inputs on its hot path (``benchmarks/finite_check.py`` measures what a check
costs there); call ``op(aj.require_finite(x))`` where inputs may be bad.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._errors import InputError, non_finite

_WHY = "every sample must be finite (drop or repair the bad samples first)"


def concrete(x):
    """``x`` as numpy when its values are known (not a tracer inside jit/vmap/grad), else None."""
    if isinstance(x, jax.core.Tracer) or x is None:
        return None
    try:
        return np.asarray(x)
    except Exception:  # noqa: BLE001 - an abstract or opaque leaf: nothing to check here
        return None


def check_concrete(x, what: str) -> None:
    """InputError naming ``what`` and the first bad index when concrete values are NaN/inf;
    nothing for tracers, integers or opaque leaves."""
    arr = concrete(x)
    if arr is None or arr.dtype.kind not in "fc":
        return
    found = non_finite(arr)
    if found is not None:
        count, first = found
        raise InputError(
            f"{what} holds {count} NaN or infinite value(s) (first at index {first}); {_WHY}"
        )


def when_traced(x, what: str):
    """``x`` unchanged, or, when it is a tracer, through :func:`equinox.error_if` (a run-time
    error on NaN or inf). For the entry points, whose concrete inputs were checked when made."""
    if not isinstance(x, jax.core.Tracer):
        return x
    return eqx.error_if(x, ~jnp.isfinite(x), f"{what} holds NaN or infinite value(s); {_WHY}")


def require_finite(x, what: str = "values"):
    """``x``, refused when it holds NaN or infinity: at once when its values are concrete
    (:class:`~abrdf_jax.InputError`), at run time under ``jit`` (Equinox's runtime error).

    Args:
        x: an array (numpy or JAX, traced or not) of floating values.
        what: what the message calls ``x``.

    Returns:
        ``x``; under a transformation use the returned array, which carries the check.

    Raises:
        InputError: concrete values that are not all finite.
    """
    check_concrete(x, what)
    return when_traced(x, what)
