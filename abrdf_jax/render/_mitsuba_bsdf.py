"""A Mitsuba 3 BSDF (registered as ``"abrdf"``) that evaluates an ABRDF table or a BTF.

``eval(ctx, si, wo)`` returns the table value at light ``wo`` and view ``si.wi`` (Mitsuba's
``eval`` includes the cosine of ``wo``; a UBO value already holds it, so it is not applied
again): smooth ring interpolation of :mod:`abrdf_jax.render._ring_interp`. A BTF
``(H, W, 81, 81, 3)`` is looked up at the texel of the surface's ``uv`` (nearest texel).
Sampling is cosine-weighted over the hemisphere with its exact pdf ``cos θ / π`` (the
table-built lobe is not done yet, docs/notes.md). The numerics are numpy on the arrays Mitsuba
passes, so the plugin works in ``scalar_rgb`` and, in wavefront mode, in ``llvm_ad_rgb``
(not differentiable through the table).
"""

from __future__ import annotations

import numpy as np

from .._errors import InputError, require
from ._ring_interp import brdf_of, lookup

PLUGIN = "abrdf"


def import_mitsuba():
    """``mitsuba`` and ``drjit``, or a one-line :class:`InputError` naming the extra
    (``abrdf_jax[render]``)."""
    mi = require("mitsuba", "rendering", "abrdf_jax[render]", "Mitsuba 3")
    dr = require("drjit", "rendering", "abrdf_jax[render]", "Mitsuba 3's Dr.Jit")
    return mi, dr


def _vec(v) -> np.ndarray:
    return np.stack(
        [np.asarray(v.x, np.float64), np.asarray(v.y, np.float64), np.asarray(v.z, np.float64)],
        axis=-1,
    )


def _make_class(mi, dr):
    class AbrdfBSDF(mi.BSDF):
        """ABRDF table / BTF BSDF; props: ``table`` (a numpy array set by :func:`abrdf_bsdf`)."""

        def __init__(self, props):
            mi.BSDF.__init__(self, props)
            table = np.asarray(_PENDING.pop(props["key"]))
            self._brdf = brdf_of(table)
            self._btf = table.ndim == 5
            flags = mi.BSDFFlags.GlossyReflection | mi.BSDFFlags.FrontSide
            if self._btf:
                flags = flags | mi.BSDFFlags.SpatiallyVarying
            self.m_components = [flags]
            self.m_flags = flags

        def _value(self, si, wl, wv):
            texel = None
            if self._btf:
                h, w = self._brdf.shape[:2]
                u = np.asarray(si.uv.x, np.float64)
                v = np.asarray(si.uv.y, np.float64)
                texel = (
                    np.clip((v * h).astype(int), 0, h - 1),
                    np.clip((u * w).astype(int), 0, w - 1),
                )
            return lookup(self._brdf, wl, wv, texel)

        def eval(self, ctx, si, wo, active=True):
            val = self._value(si, _vec(wo), _vec(si.wi))
            return mi.Color3f(*(mi.Float(val[..., c]) for c in range(3)))

        def pdf(self, ctx, si, wo, active=True):
            wl, wv = _vec(wo), _vec(si.wi)
            p = np.where((wl[..., 2] > 0) & (wv[..., 2] > 0), wl[..., 2] / np.pi, 0.0)
            return mi.Float(p)

        def eval_pdf(self, ctx, si, wo, active=True):
            return self.eval(ctx, si, wo, active), self.pdf(ctx, si, wo, active)

        def sample(self, ctx, si, sample1, sample2, active=True):
            wo = mi.warp.square_to_cosine_hemisphere(sample2)
            bs = mi.BSDFSample3f()
            bs.wo = wo
            bs.pdf = self.pdf(ctx, si, wo, active)
            bs.eta = 1.0
            bs.sampled_type = mi.UInt32(+mi.BSDFFlags.GlossyReflection)
            bs.sampled_component = mi.UInt32(0)
            val = self._value(si, _vec(wo), _vec(si.wi))
            pdf = np.asarray(bs.pdf, np.float64)
            wgt = np.where(pdf[..., None] > 0, val / np.where(pdf > 0, pdf, 1.0)[..., None], 0.0)
            return bs, mi.Color3f(*(mi.Float(wgt[..., c]) for c in range(3)))

        def to_string(self):
            return f"AbrdfBSDF[{'BTF' if self._btf else 'table'}]"

    return AbrdfBSDF


_PENDING: dict = {}
_REGISTERED: set = set()


def register_plugin() -> None:
    """Register the ``"abrdf"`` BSDF with Mitsuba in the current variant (idempotent)."""
    mi, dr = import_mitsuba()
    variant = mi.variant()
    if variant is None:
        raise InputError("set a Mitsuba variant first, e.g. mitsuba.set_variant('scalar_rgb')")
    if variant not in _REGISTERED:
        if variant.startswith(("llvm", "cuda")):
            dr.set_flag(dr.JitFlag.SymbolicLoops, False)  # numpy in eval: wavefront mode
            dr.set_flag(dr.JitFlag.SymbolicCalls, False)
        cls = _make_class(mi, dr)
        mi.register_bsdf(PLUGIN, lambda props: cls(props))
        _REGISTERED.add(variant)


def abrdf_bsdf(table) -> dict:
    """A scene-dictionary entry ``{"type": "abrdf", ...}`` for a table ``(81, 81, 3)`` or a BTF
    ``(H, W, 81, 81, 3)``; registers the plugin first.

    Raises:
        InputError: wrong shape or non-finite values; Mitsuba missing (names the extra).
    """
    arr = np.asarray(table, dtype=np.float64)
    if arr.shape[-3:] != (81, 81, 3) or arr.ndim not in (3, 5):
        raise InputError(f"table has shape {arr.shape}, expected (81, 81, 3) or (H, W, 81, 81, 3)")
    if not np.all(np.isfinite(arr)):
        raise InputError("table holds NaN or infinite values")
    register_plugin()
    key = f"t{id(arr)}_{len(_PENDING)}"
    _PENDING[key] = arr
    return {"type": PLUGIN, "key": key}
