"""The restored subspaces at the RBF centres of many slice sets at once (numpy, linear slice
interpolation, the affine rules): :func:`abrdf_jax._subspace.centre_subspaces` of every row of
a batch, bit for bit, in a few dozen array operations instead of a few hundred per row.

Model selection's direct held-out fits (``abrdf_jax.select._dense_held_out``) restore the
subspaces of each fold of each capture (four folds, four pairs, up to four rules): the one-row
functions spent their time in Python on arrays of a few hundred values (1.2 s of a warm call on
200 jittered captures, scratch profile: docs/notes.md, thirtieth session). Here a pair's slices
of every row (every fold of up to 64 captures) are read in one pass: the knots found row by row
(``searchsorted``, as :func:`abrdf_jax._interp1d.periodic_interp`), everything else
elementwise on ``(R, Q, C)`` arrays, in the one-row code's order of operations, so each value
is the same float (``tests/test_centre_batch.py``).
"""

from __future__ import annotations

import numpy as np

from ._grid import centre_layout
from ._interp1d import TWO_PI
from ._rules import AFFINE, combine
from ._subspace import get_rule


def _interp(t, y, n, tq) -> np.ndarray:
    """:func:`abrdf_jax._interp1d.periodic_interp` (``"linear"``) of every row: knots ``t``
    ``(R, nmax)``, values ``y`` ``(R, nmax, C)``, counts ``n`` ``(R,)`` (at least 1), queries
    ``tq`` ``(R, Q)`` → ``(R, Q, C)``."""
    tq = np.mod(tq, TWO_PI)
    valid = np.arange(t.shape[1]) < n[:, None]
    tk = np.where(valid, t, np.inf)
    j = np.stack([np.searchsorted(tk[r], tq[r], side="right") for r in range(len(t))])
    nn = n[:, None]
    jl = np.where(j == 0, nn - 1, j - 1)
    jr = np.where(j >= nn, 0, j)
    row = np.arange(len(t))[:, None]
    tl = t[row, jl] - np.where(j == 0, TWO_PI, 0.0)
    tr = t[row, jr] + np.where(j >= nn, TWO_PI, 0.0)
    h = tr - tl
    ok = h > 0
    hs = np.where(ok, h, 1.0)
    u = np.where(ok, (tq - tl) / hs, 0.0)[..., None]
    return (1.0 - u) * y[row, jl] + u * y[row, jr]


def _at_both(t, y, n, tq) -> np.ndarray:
    """A slice averaged over the two torus preimages ``tq`` and ``tq + π`` (``_slice_at``)."""
    q = tq.shape[1]
    both = _interp(t, y, n, np.concatenate([tq, tq + np.pi], axis=1))
    return 0.5 * (both[:, :q] + both[:, q:])


def _extreme(y, n, lowest: bool) -> np.ndarray:
    """The valid values' minimum or maximum per row and channel, ``(R, 1, C)``."""
    valid = (np.arange(y.shape[1]) < n[:, None])[..., None]
    fn, fill = (np.min, np.inf) if lowest else (np.max, -np.inf)
    return fn(np.where(valid, y, fill), axis=1, keepdims=True)


class _Terms:
    """One pair's slice terms and extremes of every row (what the affine rules read)."""

    def __init__(self, axial, diagonal, alpha, phi_i, phi_v):
        (ta, ya, self.na), (td, yd, self.nd) = axial, diagonal
        na, nd = np.maximum(self.na, 1), np.maximum(self.nd, 1)
        a_alpha = alpha[:, None]
        s, d = phi_i + phi_v, phi_i - phi_v
        self.a = _at_both(ta, ya, na, (s[None, :] + a_alpha) / 2)
        self.b = _at_both(td, yd, nd, (TWO_PI + a_alpha - d[None, :]) / 2)
        zero = 0.0 * a_alpha
        ax = _interp(ta, ya, na, np.concatenate([a_alpha, a_alpha + np.pi], axis=1))
        dg = _interp(td, yd, nd, np.concatenate([zero, zero + np.pi], axis=1))
        self.c = 0.25 * (np.sum(ax, axis=1, keepdims=True) + np.sum(dg, axis=1, keepdims=True))
        self.amin, self.amax = _extreme(ya, na, True), _extreme(ya, na, False)
        self.dmin, self.dmax = _extreme(yd, nd, True), _extreme(yd, nd, False)
        self.xp = np

    def rule(self, name: str) -> np.ndarray:
        """The affine rule ``name`` (:data:`abrdf_jax._rules.AFFINE`) on these terms, with
        :func:`abrdf_jax._subspace.subspace`'s fallback where a slice was not measured."""
        out = combine(AFFINE[name](self), lambda: self.a, lambda: self.b, lambda: self.c)
        if not get_rule(name).needs_axial:  # eq. (5) reads the diagonal slice only
            return out
        has_axial = (self.na > 0)[:, None, None]
        has_diag = (self.nd > 0)[:, None, None]
        return np.where(has_axial, np.where(has_diag, out, self.a), self.b)


def centre_subspaces_many(t, y, count, pairs, azimuths, alpha, rules: tuple) -> np.ndarray:
    """``centre_subspaces(t[r], y[r], count[r], pairs, azimuths, alpha[r], rules, "linear",
    xp=numpy)`` of every row ``r``, ``(R, len(rules), n_centres, C)``, bit for bit: ``t``
    ``(R, S, nmax)``, ``y`` ``(R, S, nmax, C)``, ``count`` ``(R, S)``, ``alpha`` ``(R,)``
    radians (float64 throughout); ``rules``: names of :data:`abrdf_jax._rules.AFFINE`."""
    t, y = np.asarray(t), np.asarray(y)
    count, alpha = np.asarray(count), np.asarray(alpha, y.dtype)
    vals = []
    for p, (pi_, pv) in enumerate(centre_layout(pairs, azimuths)):
        phi_i = np.asarray(np.deg2rad(pi_), y.dtype)
        phi_v = np.asarray(np.deg2rad(pv), y.dtype)
        axial = (t[:, 2 * p], y[:, 2 * p], count[:, 2 * p])
        diagonal = (t[:, 2 * p + 1], y[:, 2 * p + 1], count[:, 2 * p + 1])
        terms = _Terms(axial, diagonal, alpha, phi_i, phi_v)
        vals.append(np.stack([terms.rule(r) for r in rules], axis=1))
    return np.concatenate(vals, axis=-2)
