"""The prior as a module: :class:`Prior` (on the 81×81 grid), :class:`SampleBasis` (the same at
sample positions) and :func:`train_prior` (from dense tables)."""

from __future__ import annotations

import hashlib
import json

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._errors import InputError
from ._mapping import (
    DEFAULT_CHANNELS,
    DEFAULT_EPS,
    PCA,
    check_channels,
    grid_cos_view,
    mapped_rows,
    pca_components,
    per_position,
)

#: Default ridge λ when none is chosen (the MERL-train choice of ``benchmarks.pca_peer``).
DEFAULT_LAM = 0.01


class Prior(eqx.Module):
    """A PCA prior of ABRDF tables (Nielsen et al. 2015) on the 81×81 UBO grid.

    A table is ``x = inverse_log_relative(mean + components @ c, reference, cos θv, eps)``
    with weights ``c`` of unit prior variance. Vectors are flat: ``D = 6561·3`` values in
    ``(pair, channel)`` order (``channels="joint"``) or ``D = 6561`` (``"shared"``: one basis for
    the three channels, each fitted on its own).

    Attributes:
        mean: ``(D,)`` mean of the mapped training rows.
        components: ``(D, K)`` scaled principal components.
        reference: ``(6561, 3)`` the reference (median training table, value space) of the map.
        lam: ``()`` the ridge λ to use (chosen on held-out materials, or given).
        eps: ε of the log-relative map (static).
        channels: ``"joint"`` or ``"shared"`` (static).
        meta: JSON text of the metadata (static): what it was trained on (names, sha256 of the
            inputs), the package version, how K and λ were chosen (the file adds its format,
            ``channels`` and ``eps``).
        weights: ``(R, K)`` or ``None``: each component as a combination of the ``R`` centred
            training rows (:class:`~abrdf_jax.prior.PCA`'s ``weights``), kept where the training
            materials can be evaluated at any direction (the default prior's analytic materials):
            the basis at the sample positions is then exact, not interpolated from the grid
            (:func:`~abrdf_jax.prior.sample_basis`).
        ceiling: ``(D,)`` or ``None``: the largest mapped training value of each position; a
            reconstruction is clipped at ``ceiling + CEILING_MARGIN``
            (:func:`~abrdf_jax.prior.below_ceiling`). ``None`` (a prior file written before it
            existed): no clip.
    """

    mean: Float[Array, " D"]
    components: Float[Array, "D K"]
    reference: Float[Array, "6561 3"]
    lam: Float[Array, ""]
    eps: float = eqx.field(static=True)
    channels: str = eqx.field(static=True)
    meta: str = eqx.field(static=True, default="{}")
    weights: Float[Array, "R K"] | None = None
    ceiling: Float[Array, " D"] | None = None

    @property
    def n_components(self) -> int:
        return int(self.components.shape[-1])

    @property
    def metadata(self) -> dict:
        return json.loads(self.meta)

    @property
    def dtype(self):
        return self.components.dtype

    def truncate(self, k: int) -> "Prior":
        """The prior with its first ``k`` components."""
        if not 1 <= k <= self.n_components:
            raise InputError(f"truncate: k must be in [1, {self.n_components}], got {k}")
        out = eqx.tree_at(lambda p: p.components, self, self.components[:, :k])
        if self.weights is None:
            return out
        return eqx.tree_at(lambda p: p.weights, out, self.weights[:, :k])

    def astype(self, dtype) -> "Prior":
        """The prior with its arrays in ``dtype``."""
        arrays = (self.mean, self.components, self.reference, self.lam)
        new = (jnp.asarray(a, dtype) for a in arrays)
        w = None if self.weights is None else jnp.asarray(self.weights, dtype)
        top = None if self.ceiling is None else jnp.asarray(self.ceiling, dtype)
        return Prior(
            *new, eps=self.eps, channels=self.channels, meta=self.meta, weights=w, ceiling=top
        )

    def with_lam(self, lam) -> "Prior":
        return eqx.tree_at(lambda p: p.lam, self, jnp.asarray(lam, self.dtype))

    def grid_layout(self):
        """``(reference, cos θv)`` on the grid in the layout of a row (``(D,)`` each)."""
        cos = np.broadcast_to(grid_cos_view()[:, None], (6561, 3))
        ref = per_position(self.reference, self.channels)
        return ref, jnp.asarray(per_position(cos, self.channels), self.dtype)


class SampleBasis(eqx.Module):
    """The prior at ``P`` sample positions, in the layout of a row (``P·3`` or ``P`` values).

    Attributes:
        mean, reference, cos_v: ``(P·C,)`` (``C = 3`` joint, 1 shared).
        components: ``(P·C, K)``.
        weight: ``(P·C,)`` 1 at a sample, 0 at padding (masked out of the fit).
        width: ``C`` (static).
    """

    mean: Array
    reference: Array
    cos_v: Array
    components: Array
    weight: Array
    width: int = eqx.field(static=True)

    def rows(self, positions) -> Array:
        """The row indices (into ``P·C``) of some positions (indices into ``P``, numpy or
        traced), in that order."""
        pos = jnp.asarray(positions)
        return (pos[:, None] * self.width + jnp.arange(self.width)).reshape(-1)

    def take(self, positions) -> "SampleBasis":
        """The basis at some of its positions (indices into ``P``, numpy or traced), in that
        order."""
        rows = self.rows(positions)
        return SampleBasis(
            self.mean[rows],
            self.reference[rows],
            self.cos_v[rows],
            self.components[rows],
            self.weight[rows],
            self.width,
        )

    def truncate(self, k: int) -> "SampleBasis":
        """The basis with its first ``k`` components."""
        return eqx.tree_at(lambda b: b.components, self, self.components[:, :k])

    def astype(self, dtype) -> "SampleBasis":
        arrays = (self.mean, self.reference, self.cos_v, self.components, self.weight)
        return SampleBasis(*(jnp.asarray(a, dtype) for a in arrays), self.width)


def _sha256(array) -> str:
    a = np.ascontiguousarray(array)
    return hashlib.sha256(a.tobytes()).hexdigest()


def assemble_prior(
    reference,
    pca: PCA,
    *,
    eps,
    channels,
    lam,
    meta: dict,
    dtype,
    weights: bool = False,
    ceiling=None,
) -> Prior:
    """A :class:`Prior` from a reference ``(6561, 3)`` and a :class:`PCA` of the mapped rows
    (with ``weights``: the PCA's weights kept, for training materials that can be evaluated at
    any direction; ``ceiling``: the mapped rows' maximum per position, :attr:`Prior.ceiling`)."""
    return Prior(
        mean=jnp.asarray(pca.mean, dtype),
        components=jnp.asarray(pca.components, dtype),
        reference=jnp.asarray(np.broadcast_to(reference, (6561, 3)), dtype),
        lam=jnp.asarray(lam, dtype),
        eps=float(eps),
        channels=channels,
        meta=json.dumps(meta, sort_keys=True),
        weights=jnp.asarray(pca.weights, dtype) if weights else None,
        ceiling=None if ceiling is None else jnp.asarray(ceiling, dtype),
    )


def train_prior(
    tables,
    names=None,
    *,
    k: int | None = None,
    lam: float = DEFAULT_LAM,
    channels: str = DEFAULT_CHANNELS,
    eps: float = DEFAULT_EPS,
    sources=None,
    extra_meta: dict | None = None,
    dtype=jnp.float32,
    weights: bool = False,
) -> Prior:
    """Train a prior from dense ABRDF tables (steps 1–3 of :mod:`abrdf_jax.prior._mapping`).

    Args:
        tables: ``(N, 81, 81, 3)`` non-negative tables (``N ≥ 2``); see
            :func:`~abrdf_jax.prior.read_training_tables` for files.
        names: ``N`` material names for the metadata (default ``table-0``, ...).
        k: number of components (default: all, the rank of the centred rows); choose it with
            :func:`~abrdf_jax.prior.select_prior`.
        lam: the ridge λ stored with the prior (the default of :func:`reconstruct_prior`).
        channels: ``"shared"`` (default) or ``"joint"``.
        eps: ε of the log-relative map.
        sources: ``N`` dicts (``name``, ``sha256``, ``source``) describing the inputs (files);
            default: the sha256 of each table's float32 bytes.
        extra_meta: more metadata (e.g. how ``k`` and ``λ`` were chosen, provenance).
        dtype: dtype of the prior's arrays (training itself runs in float64).
        weights: keep the PCA's weights (:attr:`Prior.weights`): for training materials that
            can be evaluated at any direction (the default prior's analytic ones).

    Raises:
        InputError: wrong shape, fewer than 2 tables, non-finite or negative-everywhere input,
            ``k`` outside ``[1, rank]``, a bad ``channels``, ``eps ≤ 0`` or ``lam < 0``.
    """
    from .. import __version__

    check_channels(channels)
    x = np.asarray(tables)
    if x.ndim != 4 or x.shape[1:] != (81, 81, 3):
        raise InputError(f"train_prior: tables must have shape (N, 81, 81, 3), got {x.shape}")
    if len(x) < 2:
        raise InputError(f"train_prior: needs at least 2 tables, got {len(x)}")
    if not np.all(np.isfinite(x)):
        raise InputError("train_prior: tables hold NaN or infinite values")
    if not eps > 0 or not lam >= 0:
        raise InputError(f"train_prior: eps must be > 0 and lam >= 0, got eps={eps}, lam={lam}")
    names = [f"table-{i}" for i in range(len(x))] if names is None else [str(n) for n in names]
    if len(names) != len(x):
        raise InputError(f"train_prior: {len(names)} names for {len(x)} tables")
    if sources is None:
        sources = [
            {"name": n, "sha256": _sha256(t.astype(np.float32)), "source": "array"}
            for n, t in zip(names, x)
        ]
    x = np.asarray(x, np.float64).reshape(len(x), -1, 3)
    ref, rows = mapped_rows(x, grid_cos_view(), channels, eps)
    pca = pca_components(rows, k)
    meta = {
        "package_version": __version__,
        "rank": pca.rank,
        "n_materials": len(names),
        "trained_on": list(sources),
        "explained_variance": [float(v) for v in pca.variances],
        **(extra_meta or {}),
    }
    return assemble_prior(
        ref,
        pca,
        eps=eps,
        channels=channels,
        lam=lam,
        meta=meta,
        dtype=dtype,
        weights=weights,
        ceiling=rows.max(axis=0),
    )


def basis_from_training(pca: PCA, x_s, cos_s, weight, *, channels: str, eps: float, dtype):
    """The components at sample positions as the same combinations of the training materials.

    Given the ``R`` training materials' exact values ``x_s`` ``(N, P, 3)`` at ``P`` positions (from
    continuous models: fits, analytic materials), the component ``k`` there is
    ``(X_s − μ_s)ᵀ weights_k`` and the reference the median of ``x_s``: no interpolation of the
    grid tables (benchmarks' ``basis_at="models"``).

    Args:
        pca: the :class:`PCA` of the grid rows (its ``weights``).
        x_s: ``(N, P, 3)`` training values at the positions.
        cos_s: ``(P,)`` ``cos θv`` there.
        weight: ``(P,)`` 1 at a sample, 0 at padding.
    """
    ref_s, rows_s = mapped_rows(x_s, cos_s, channels, eps)
    mu_s = rows_s.mean(0)
    comps_s = (rows_s - mu_s).T @ pca.weights
    cos = np.broadcast_to(np.asarray(cos_s, np.float64).reshape(-1, 1), ref_s.shape)
    w = np.broadcast_to(np.asarray(weight, np.float64).reshape(-1, 1), ref_s.shape)
    return SampleBasis(
        mean=jnp.asarray(mu_s, dtype),
        reference=jnp.asarray(per_position(ref_s, channels), dtype),
        cos_v=jnp.asarray(per_position(cos, channels), dtype),
        components=jnp.asarray(comps_s, dtype),
        weight=jnp.asarray(per_position(w, channels), dtype),
        width=3 if channels == "joint" else 1,
    )
