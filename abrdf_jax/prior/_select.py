"""Held-out choice of the prior's hyper-parameters (K, λ; optionally the channel layout and ε).

``folds``-fold cross-validation *within* the training set: material ``j`` is held out in fold
``j % folds``, the prior is trained on the others and the held-out materials are reconstructed
from their slice samples; the grid point with the lowest mean ΔE76 (PROTOCOL.md) wins and the
prior is retrained on every material (:func:`select_prior`). The held-out samples are taken from
the tables (:func:`abrdf_jax.sample_table`) unless exact ones are given (``meas``, e.g. from the
continuous models the tables were made of), and the prior at the sample positions is
interpolated from its tables (``basis="tables"``) or built from the training materials' own
samples (``basis="samples"``, :func:`~abrdf_jax.prior.basis_from_training`).
"""

from __future__ import annotations

import itertools

import jax
import jax.numpy as jnp
import numpy as np

from .._errors import InputError
from .._measurements import Measurements
from .._params import Config
from .._slices import PROTOCOL_ALPHA_DEG
from ._mapping import DEFAULT_CHANNELS, DEFAULT_EPS, grid_cos_view, mapped_rows, pca_components
from ._model import DEFAULT_LAM, assemble_prior, basis_from_training, train_prior
from ._reconstruct import prior_at_samples, project

#: The default grid of :func:`select_prior` (the PCA peer's full grid).
DEFAULT_KS = (8, 16, 32, 44, 64, 96)
DEFAULT_LAMS = (0.003, 0.01, 0.03, 0.1, 0.3, 1.0)
BASES = ("tables", "samples")


@jax.jit
def _metrics(rec, ref):
    from ..metrics import delta_e76, log_error

    return jax.vmap(lambda r, f: (delta_e76(r, f), log_error(r, f)))(rec, ref)


#: ε of the log-domain interpolation of :func:`table_samples`.
SAMPLE_LOG_EPS = 1e-6


def table_samples(tables, budget: str = "iso102", alpha_deg: float = PROTOCOL_ALPHA_DEG):
    """The protocol slice samples of each table, interpolated in the log domain (stacked
    ``Measurements``).

    ``exp(bilinear(ln(x + ε))) − ε`` over both azimuths (ε = :data:`SAMPLE_LOG_EPS`), not the
    linear :func:`abrdf_jax.sample_table`: on the MERL test split it is much closer to the
    exact samples of the neural fits (mean ``|ln((a + 10⁻³)/(b + 10⁻³))|`` 0.080 against 0.211),
    and a MERL-train prior reconstructs from it about as from exact samples (docs/prior.md).
    """
    from .._sampling import interpolate_table, table_corners
    from .._slices import protocol_parameters

    cfg = Config(budget=budget)
    t, count = protocol_parameters(cfg.counts, dtype=jnp.float32)
    corners = table_corners(t, jnp.asarray(np.deg2rad(alpha_deg), jnp.float32), cfg.pairs)
    mask = jnp.arange(t.shape[1])[None, :] < count[:, None]

    @jax.jit
    @jax.vmap
    def one(x):
        y = jnp.exp(interpolate_table(jnp.log(x + SAMPLE_LOG_EPS), corners)) - SAMPLE_LOG_EPS
        return jnp.where(mask[..., None], jnp.maximum(y, 0.0), 0.0)

    y = one(jnp.asarray(tables, jnp.float32))
    n = y.shape[0]
    return Measurements(
        jnp.broadcast_to(t, (n, *t.shape)),
        y,
        jnp.broadcast_to(count, (n, *count.shape)),
        tuple(cfg.pairs),
        any(c > 0 for c in cfg.counts[0::2]),
    )


def _flat(meas):
    """``(N, S·nmax, 3)`` values, ``(S·nmax,)`` mask and ``cos θv`` of stacked measurements."""
    n, s, m = meas.t.shape
    mask = np.asarray(meas.mask[0]).reshape(-1)
    cos = np.repeat(meas.slice_cos_view(), m)
    return np.asarray(meas.y, np.float64).reshape(n, s * m, 3), mask, cos


def _layout(meas):
    return jax.tree_util.tree_map(lambda x: x[0], meas)


def cross_validate_prior(
    tables,
    meas=None,
    *,
    ks=DEFAULT_KS,
    lams=DEFAULT_LAMS,
    channels=(DEFAULT_CHANNELS,),
    eps_values=(DEFAULT_EPS,),
    folds: int = 6,
    basis: str = "tables",
    budget: str = "iso102",
    alpha_deg: float = PROTOCOL_ALPHA_DEG,
    dtype=jnp.float32,
    log=None,
) -> list[dict]:
    """Cross-validated PROTOCOL means for every ``(channels, eps, K, λ)`` of the grid.

    Args:
        tables: ``(N, 81, 81, 3)`` training tables.
        meas: stacked ``Measurements`` of the same materials in one layout (default: the
            ``budget``'s protocol samples of the tables).
        ks, lams, channels, eps_values: the grid; a K above a fold's rank is clipped to it.
        folds: number of folds (``2 ≤ folds ≤ N``).
        basis: ``"tables"`` or ``"samples"`` (see the module docstring).
        log: optional ``print``-like callable for one line per grid point.

    Returns:
        One dict per grid point: ``channels``, ``eps``, ``n_components``, ``lam``, ``de76``,
        ``logerr`` (means over all held-out materials).
    """
    if basis not in BASES:
        raise InputError(f"basis must be one of {', '.join(BASES)}, got {basis!r}")
    tables = np.asarray(tables, np.float32)
    n = len(tables)
    if not 2 <= folds <= n:
        raise InputError(f"folds must be in [2, {n}] for {n} tables, got {folds}")
    meas = table_samples(tables, budget, alpha_deg) if meas is None else meas
    layout = _layout(meas)
    y, mask, cos_s = _flat(meas)
    x_g = np.asarray(tables, np.float64).reshape(n, -1, 3)
    fold = np.arange(n) % folds
    ref_tables = jnp.asarray(tables)
    rows = []
    for ch, eps in itertools.product(channels, eps_values):
        fits = []
        for f in range(folds):
            ref, train_rows = mapped_rows(x_g[fold != f], grid_cos_view(), ch, eps)
            fits.append((ref, pca_components(train_rows, None)))
        # one K grid for every fold: clipped to the smallest rank of the folds
        kmax = min(max(ks), *(p.rank for _, p in fits))
        grid = sorted({min(k, kmax) for k in ks})
        # per held-out material: (ΔE76, LogErr); every fold fills its own
        per = {key: np.full((2, n), np.nan) for key in itertools.product(grid, lams)}
        for f, (ref, pca) in enumerate(fits):
            tr, te = fold != f, fold == f
            pca = pca._replace(
                components=pca.components[:, :kmax],
                weights=pca.weights[:, :kmax],
                variances=pca.variances[:kmax],
            )
            prior = assemble_prior(
                ref, pca, eps=eps, channels=ch, lam=DEFAULT_LAM, meta={}, dtype=dtype
            )
            if basis == "tables":
                full = prior_at_samples(prior, layout)
            else:
                full = basis_from_training(
                    pca, y[tr], cos_s, mask, channels=ch, eps=eps, dtype=dtype
                )
            for k in grid:
                pk, bk = prior.truncate(k), full.truncate(k)
                for lam in lams:
                    rec = _project(pk, bk, jnp.asarray(lam, dtype), y[te])
                    per[k, lam][:, te] = np.asarray(_metrics(rec, ref_tables[te]))
        for (k, lam), (de76, logerr) in per.items():
            m = dict(de76=float(np.mean(de76)), logerr=float(np.mean(logerr)))
            rows.append(dict(channels=ch, eps=eps, n_components=k, lam=lam, **m))
            if log:
                log(f"  cv {ch} eps={eps:g} K={k} lam={lam:g}: dE76 {m['de76']:.3f}")
    return rows


@jax.jit
def _project(prior, basis, lam, y):
    return project(prior, basis, lam, y.astype(prior.dtype))


def best_row(rows: list[dict]) -> dict:
    """The grid point with the lowest cross-validated mean ΔE76."""
    return min(rows, key=lambda r: r["de76"])


def select_prior(
    tables,
    names=None,
    *,
    ks=DEFAULT_KS,
    lams=DEFAULT_LAMS,
    channels=(DEFAULT_CHANNELS,),
    eps_values=(DEFAULT_EPS,),
    folds: int = 6,
    budget: str = "iso102",
    sources=None,
    extra_meta: dict | None = None,
    dtype=jnp.float32,
    log=None,
):
    """Choose K, λ (and layout, ε) by :func:`cross_validate_prior`, then train on all tables.

    The prior's metadata records the choice (``selection``: budget, folds, grid, the winning
    cross-validated ΔE76 and LogErr). Arguments as in :func:`cross_validate_prior` and
    :func:`~abrdf_jax.prior.train_prior`.
    """
    rows = cross_validate_prior(
        tables,
        ks=ks,
        lams=lams,
        channels=channels,
        eps_values=eps_values,
        folds=folds,
        budget=budget,
        dtype=dtype,
        log=log,
    )
    best = best_row(rows)
    selection = {
        "by": f"{folds}-fold cross-validation within the training tables, mean dE76 from "
        f"{budget} samples interpolated (log domain) from the tables",
        "budget": budget,
        "folds": folds,
        "grid": {"ks": list(ks), "lams": list(lams), "channels": list(channels)},
        "eps": list(eps_values),
        "cv_de76": best["de76"],
        "cv_logerr": best["logerr"],
    }
    return train_prior(
        tables,
        names,
        k=best["n_components"],
        lam=best["lam"],
        channels=best["channels"],
        eps=best["eps"],
        sources=sources,
        extra_meta={"selection": selection, **(extra_meta or {})},
        dtype=dtype,
    )
