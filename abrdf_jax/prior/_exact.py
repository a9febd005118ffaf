"""The prior at the sample positions: exact where its training materials can be evaluated there.

A prior's mean and components are known on the 81×81 UBO grid; at a measurement's sample
positions :func:`~abrdf_jax.prior.prior_at_samples` interpolates them over the ring azimuths
(30° apart on the 30° ring). A sharp lobe between two grid azimuths is lost in that
interpolation, while the measured sample still holds it, so the fit bends to explain a peak
the interpolated basis does not have: on the MERL test materials a capture with 200 samples per
slice was reconstructed *worse* than the protocol's 26 (docs/prior.md, "The basis at the
samples"). The components are fixed combinations of the centred training rows
(:attr:`~abrdf_jax.prior.Prior.weights`), so where the training materials are continuous models
(the default prior's analytic draws) the basis at any direction is that same combination of
their values there (:func:`~abrdf_jax.prior.basis_from_training`'s idea, in JAX so that it
traces with the sample positions and α). :func:`~abrdf_jax.prior.sample_basis` chooses: exact
when the prior carries weights and a recipe of analytic training materials, else the grid
interpolation.
"""

from __future__ import annotations

import functools
import json

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._slices import slice_directions
from ._mapping import log_relative, median_reference, per_position, to_rows
from ._model import Prior, SampleBasis


class TrainingModels(eqx.Module):
    """``n`` training materials as stacked analytic parts: material ``i`` is the sum of the
    parts whose ``owner`` is ``i``. One stacked module per part class, evaluated by ``vmap``.
    """

    parts: tuple
    owners: tuple
    n: int = eqx.field(static=True)

    def __call__(self, wi, wv) -> jax.Array:
        """Values ``(n, ..., 3)`` of every material at directions ``wi, wv`` ``(..., 3)``."""
        wv = jnp.asarray(wv, wi.dtype)
        shape = jnp.broadcast_shapes(wi.shape, wv.shape)[:-1]
        out = jnp.zeros((self.n, *shape, 3), wi.dtype)
        for stacked, owner in zip(self.parts, self.owners):
            # the parameters in the directions' dtype, whatever JAX's x64 switch was when the
            # (cached) models were made or is now
            stacked = jax.tree.map(lambda a: jnp.asarray(a, wi.dtype), stacked)
            vals = jax.vmap(lambda m: m(wi, wv))(stacked)
            out = out.at[owner].add(vals.astype(wi.dtype))
        return out


def stack_models(parts_per_material) -> TrainingModels:
    """:class:`TrainingModels` from a list (one per material) of lists of analytic parts."""
    groups: dict[type, tuple[list, list]] = {}
    for i, parts in enumerate(parts_per_material):
        for p in parts:
            mods, owners = groups.setdefault(type(p), ([], []))
            mods.append(p)
            owners.append(i)
    stacked, owner_idx = [], []
    for mods, owners in groups.values():
        # numpy leaves: constants, never tracers of whatever trace first asked (the result is cached)
        stacked.append(
            jax.tree.map(lambda *xs: np.stack([np.asarray(x, np.float64) for x in xs]), *mods)
        )
        owner_idx.append(np.asarray(owners, np.int32))
    return TrainingModels(tuple(stacked), tuple(owner_idx), len(parts_per_material))


@functools.lru_cache(maxsize=4)
def _recipe_models(recipe_json: str) -> TrainingModels:
    from ._default import default_training_models

    # Evaluated now, also when first asked inside a jit trace: the cached result is constants.
    with jax.ensure_compile_time_eval():
        parts, _ = default_training_models(json.loads(recipe_json))
        return stack_models(parts)


@functools.lru_cache(maxsize=16)
def _models_recipe(meta: str) -> str | None:
    """The recipe (canonical JSON) of a prior's metadata text where its basis is ``"models"``;
    parsed once per metadata text, not at every trace."""
    recipe = json.loads(meta).get("recipe")
    if not isinstance(recipe, dict) or recipe.get("basis") != "models":
        return None
    return json.dumps(recipe, sort_keys=True)


def training_models(prior: Prior) -> TrainingModels | None:
    """The prior's training materials as models, or ``None`` where it has none (trained on
    tables) or carries no :attr:`~abrdf_jax.prior.Prior.weights`."""
    if prior.weights is None:
        return None
    recipe = _models_recipe(prior.meta)
    if recipe is None:
        return None
    models = _recipe_models(recipe)
    rows = models.n * (3 if prior.channels == "shared" else 1)
    return models if rows == prior.weights.shape[0] else None


def exact_basis(prior: Prior, models: TrainingModels, meas, alpha) -> SampleBasis:
    """The basis at ``meas``'s ``S·nmax`` padded positions from the training materials' values
    there (traceable in ``meas.t`` and ``alpha``, radians); padding gets weight 0."""
    dt = prior.dtype
    s, n = meas.t.shape
    wi, wv = slice_directions(jnp.asarray(meas.t, dt), meas.pairs, jnp.asarray(alpha, dt))
    mask = jnp.reshape(meas.mask, (s * n,))
    x = models(wi.reshape(-1, 3), wv.reshape(-1, 3))  # (N, P, 3)
    x = jnp.where(mask[None, :, None], x, 1.0)  # padding: any positive value (weight 0)
    cos = jnp.asarray(np.repeat(meas.slice_cos_view(), n)[:, None], dt)  # (P, 1)
    ref = median_reference(x, prior.channels)
    rows = to_rows(log_relative(x, ref, cos, prior.eps), prior.channels)
    mu = jnp.mean(rows, 0)
    comps = (rows - mu).T @ prior.weights.astype(dt)
    c = 3 if prior.channels == "joint" else 1
    w = jnp.broadcast_to(mask[:, None], (s * n, 3)).astype(dt)
    cos3 = jnp.broadcast_to(cos, (s * n, 3))
    return SampleBasis(
        mean=mu,
        reference=per_position(ref, prior.channels),
        cos_v=per_position(cos3, prior.channels),
        components=comps,
        weight=per_position(w, prior.channels),
        width=c,
    )
