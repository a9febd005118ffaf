"""Radial basis kernels, written as functions of the squared scaled distance ``r²``.

Scaling is done before the kernel: ``r² = Σ_k ((x_k − y_k) / ℓ_k)²`` with per-dimension widths
``ℓ`` (traced, differentiable). Kernels follow scipy's ``RBFInterpolator`` conventions (its
``epsilon`` corresponds to ``1/ℓ``) so that scipy serves as the test oracle.

Every kernel is written so that its value *and gradient* are finite at ``r = 0`` (the Gram
diagonal): a kernel in ``r`` (not ``r²``) uses the double-``where`` trick of optax's ``safe_norm``.
"""

from __future__ import annotations

import numpy as np

from ._names import check_registry, check_trait
from ._xp import namespace

# kernel -> (function of r², minimum polynomial degree, positive definite)
_KERNELS = {}


def _register(name, min_degree, pd):
    def deco(fn):
        _KERNELS[name] = (fn, min_degree, pd)
        return fn

    return deco


def _safe(r2, xp):
    pos = r2 > 0
    return pos, xp.where(pos, r2, 1.0)


@_register("gaussian", -1, True)
def gaussian(r2, xp=None):
    return namespace(xp).exp(-r2)


@_register("inverse_multiquadric", -1, True)
def inverse_multiquadric(r2, xp=None):
    return 1.0 / namespace(xp).sqrt(1.0 + r2)


@_register("inverse_quadratic", -1, True)
def inverse_quadratic(r2, xp=None):
    return 1.0 / (1.0 + r2)


@_register("multiquadric", 0, False)
def multiquadric(r2, xp=None):
    return -namespace(xp).sqrt(1.0 + r2)


@_register("thin_plate_spline", 1, False)
def thin_plate_spline(r2, xp=None):
    # r² log r = ½ r² log r²; 0 at r = 0 with a finite (zero) gradient.
    xp = namespace(xp)
    if xp is np:  # the host build: three passes in place, no gradient to guard (r² = 0: 0·log tiny)
        out = np.log(np.maximum(r2, np.finfo(r2.dtype).tiny))
        out *= r2
        out *= 0.5  # exact: (s log s) / 2 = (s / 2) log s
        return out
    pos, s = _safe(r2, xp)
    return xp.where(pos, 0.5 * s * xp.log(s), 0.0)


@_register("cubic", 1, False)
def cubic(r2, xp=None):
    xp = namespace(xp)
    pos, s = _safe(r2, xp)
    return xp.where(pos, s * xp.sqrt(s), 0.0)


@_register("linear", 0, False)
def linear(r2, xp=None):
    xp = namespace(xp)
    pos, s = _safe(r2, xp)
    return xp.where(pos, -xp.sqrt(s), 0.0)


KERNELS = tuple(_KERNELS)
check_registry("KERNELS", KERNELS)
check_trait("KERNEL_MIN_DEGREE", {n: v[1] for n, v in _KERNELS.items()})


def kernel_fn(name: str):
    """The kernel function ``fn(r², xp=None)`` for ``name`` (one of :data:`KERNELS`; ``xp``:
    ``jax.numpy`` by default, or ``numpy``)."""
    try:
        return _KERNELS[name][0]
    except KeyError:
        raise ValueError(f"kernel must be one of {KERNELS}, got {name!r}") from None


def min_degree(name: str) -> int:
    """Smallest polynomial-tail degree that makes the kernel's system solvable (-1: none)."""
    kernel_fn(name)
    return _KERNELS[name][1]


def is_positive_definite(name: str) -> bool:
    """Whether the kernel's Gram matrix is positive definite (Cholesky applies)."""
    kernel_fn(name)
    return _KERNELS[name][2]


def scaled_sqdist(x, y, widths, xp=None):
    """``r²[a, b] = Σ_k ((x[a,k] − y[b,k]) / widths[k])²`` by direct differences.

    Direct differences (not ``|x|² + |y|² − 2x·y``) keep ``r² ≥ 0`` exactly and zero on the
    diagonal, which the kernels' safe branches rely on.
    """
    # A sum of 2D terms (d is small) fuses into one pass: no (n, m, d) temporary in memory.
    xp = namespace(xp)
    widths = xp.broadcast_to(widths, (x.shape[-1],))
    r2 = xp.zeros((x.shape[0], y.shape[0]), xp.result_type(x, y, widths))
    if xp.__name__ == "numpy":  # the same operations in place: no temporaries on the host
        diff = np.empty_like(r2)
        for k in range(x.shape[-1]):
            np.subtract(x[:, k, None], y[None, :, k], out=diff)
            diff /= widths[k]
            diff *= diff
            r2 += diff
        return r2
    for k in range(x.shape[-1]):
        diff = (x[:, k, None] - y[None, :, k]) / widths[k]
        r2 = r2 + diff * diff
    return r2


#: Rows of a kernel block made at a time in numpy: the temporaries (``rows × m`` float64) stay
#: in cache instead of streaming a 55 MB array through memory a dozen times. 32 rows (330 kB
#: temporaries at the 1,296 centres) made the 5,265 × 1,296 block of an operator's build in
#: 105 ms, 256 rows in 134 ms, 512 in 163 ms (scratch, docs/notes.md, 31st session).
HOST_ROWS = 32


def kernel_block(x, y, widths, kernel: str, xp=None):
    """``kernel(scaled_sqdist(x, y, widths))``, ``(n, m)``. In numpy made ``HOST_ROWS`` rows
    at a time into one array: the same operations per element, so the same bits, without the
    full-size temporaries (the 6,561 × 1,296 block of an operator's build)."""
    xp = namespace(xp)
    fn = kernel_fn(kernel)
    if xp.__name__ != "numpy" or x.shape[0] <= HOST_ROWS:
        return fn(scaled_sqdist(x, y, widths, xp), xp)
    out = np.empty((x.shape[0], y.shape[0]), np.result_type(x, y, widths))
    for a in range(0, x.shape[0], HOST_ROWS):
        out[a : a + HOST_ROWS] = fn(scaled_sqdist(x[a : a + HOST_ROWS], y, widths, np), np)
    return out
