"""Shared helpers of the stability benchmark (:mod:`benchmarks.stability`): the four methods, their
reconstruction with the guard on or off, the RBF system's diagnostics, materials and errors.
"""

from __future__ import annotations

import functools
import math
import sys

import jax
import jax.numpy as jnp
import numpy as np

import abrdf_jax as aj
from abrdf_jax.materials import dense_table, get_material
from abrdf_jax.metrics import evaluate_batch

log = functools.partial(print, file=sys.stderr, flush=True)

METHODS = {
    "paper iso102": aj.Config(),
    "recommended iso102": aj.Config.recommended(),
    "paper aniso204": aj.Config(budget="aniso204"),  # eq. (2)-(4), rule filip2012
    "recommended aniso204": aj.Config.recommended("aniso204"),
}


def reconstruct(
    config: aj.Config, meas: aj.Measurements, params: aj.Params, guard: bool = True
) -> np.ndarray:
    """Tables ``(B, 81, 81, 3)`` of stacked measurements; ``guard=False``: the plain RBF solve."""
    return np.asarray(aj.reconstruct_batch(meas, config, params, guard=guard))


def params_for(config, dtype, width=None, reg=None, alpha_deg=aj.PROTOCOL_ALPHA_DEG):
    """``Params.default`` of ``config`` in ``dtype``, with an optional common width and λ."""
    p = aj.Params.default(config, alpha_deg=alpha_deg, dtype=dtype)
    w = p.widths if width is None else jnp.full(4, width, dtype)
    r = p.reg if reg is None else jnp.asarray(reg, dtype)
    return aj.Params(p.alpha, w, r)


def sample_stack(models, config, params):
    return aj.stack_measurements(
        [aj.sample(m, config, params, as_measurements=True) for m in models]
    )


def de76(rec, ref):
    """Per-material ΔE76; NaN where the reconstruction is not finite."""
    rec, ref = np.asarray(rec, np.float64), np.asarray(ref, np.float64)
    finite = np.all(np.isfinite(rec.reshape(len(rec), -1)), axis=1)
    out = np.full(len(rec), np.nan)
    if finite.any():
        out[finite] = np.asarray(
            evaluate_batch(
                jnp.asarray(rec[finite], jnp.float32), jnp.asarray(ref[finite], jnp.float32)
            )["de76"]
        )
    return out


def nonfinite(rec) -> int:
    return int(np.sum(~np.isfinite(np.asarray(rec))))


def centres(config, dtype):
    """The RBF centres of ``config``'s reconstruction in its pair coordinates, ``(n, 4)``."""
    return aj.pair_coordinates(*aj.centre_vectors(config.pairs, dtype), config.parameterization)


@functools.lru_cache(maxsize=None)
def _info_fn(kernel, degree, guard):
    def f(xc, widths, reg):
        zeros = jnp.zeros((xc.shape[0], 1), xc.dtype)
        return aj.fit_rbf_info(xc, zeros, widths, kernel, reg, degree, guard=guard)[1]

    return jax.jit(f)


def solve_diag(config, dtype, width, reg, guard):
    """The guard's diagnostics (:class:`abrdf_jax.SolveInfo`) of ``config``'s RBF system, as a dict."""
    info = _info_fn(config.kernel, config.degree, guard)(
        centres(config, dtype), jnp.full(4, width, dtype), jnp.asarray(reg, dtype)
    )
    return {
        k: float(v) if k in ("reg", "cond") else int(v)
        for k, v in (
            ("reg", info.reg),
            ("cond", info.cond),
            ("ok", info.ok),
            ("retries", info.retries),
        )
    }


def exact_cond(config, width, reg):
    """Exact 1-norm condition number of the float64 system (numpy), to check the estimator."""
    a = np.asarray(
        aj.rbf_system(
            centres(config, jnp.float64),
            jnp.full(4, width, jnp.float64),
            config.kernel,
            reg,
            config.degree,
        )
    )
    with np.errstate(all="ignore"):
        try:
            return float(np.linalg.cond(a, 1))
        except np.linalg.LinAlgError:
            return math.inf


def materials_iso(data_dir, count):
    """Isotropic materials with references: analytic ones plus MERL/Nielsen test networks."""
    names = ["lambert-clay", "ggx-plastic"]
    models = [get_material(n) for n in names]
    if count:
        try:
            from abrdf_jax.materials import load_tables81

            t = load_tables81(data_dir)
            test = [str(n) for n, s in zip(t["names"], t["split"]) if s == "test"]
            pick = test[:: max(1, len(test) // count)][:count]
            for n in pick:
                models.append(get_material("nbrdf:" + n, data_dir))
                names.append("nbrdf:" + n)
        except Exception as exc:  # no shared data: analytic materials only
            log(f"MERL networks unavailable ({exc}); analytic materials only")
    refs = np.stack([dense_table(m, np.float64) for m in models])
    return names, models, refs
