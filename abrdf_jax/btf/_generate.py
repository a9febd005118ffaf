"""A procedural BTF: per-texel materials on a shadowing, masking height field.

:class:`ProceduralBTF` is a pure function of ``(size, seed)``: every texel's model, dense ground
truth and slice measurement is computed on demand for any range of texels, in float32, so a
whole BTF is produced chunk by chunk in bounded memory and the same seed gives the same bits on
any machine. Texels are numbered row-major: texel ``t`` is row ``t // size`` (patch ``y``),
column ``t % size`` (patch ``x``).
"""

from functools import partial

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._errors import InputError
from .._grid import to_vector, ubo_grid
from .._params import Config, Params
from .._measurements import Measurements
from .._sampling import sample_model
from ._store import ANGLES
from ._surface import MIN_RASTER, FourierField, Surface, horizon_map, make_surface, raster
from ._texel import TexelModel

_F32 = jnp.float32
#: Sizes the generator accepts (texels per side).
MIN_SIZE, MAX_SIZE = 2, 4096
GENERATOR_VERSION = 1

# Material classes: 0 matte (Lambertian), 1 brushed metal (Ward), 2 lacquer (GGX).
_MATTE = np.array([[0.55, 0.45, 0.35], [0.36, 0.38, 0.42], [0.62, 0.32, 0.22], [0.48, 0.50, 0.40]])
_METAL = np.array([[0.60, 0.60, 0.62], [0.72, 0.45, 0.26], [0.75, 0.62, 0.32]])
_LACQUER = np.array(
    [[0.10, 0.22, 0.50], [0.45, 0.08, 0.10], [0.14, 0.34, 0.16], [0.05, 0.05, 0.06]]
)


class ProceduralBTF(eqx.Module):
    """A procedural spatially varying material of ``size × size`` texels (see the module doc).

    Build it with :func:`procedural_btf`. All arrays are float32.

    Attributes:
        size: texels per side (static).
        surface: the analytic height field.
        heights: its raster (for the horizon march).
        fields: ``(9,)`` smooth noise fields: 3 class logits, 3 albedo variations, roughness,
            anisotropy ratio, anisotropy angle.
        fill_field: noise field of the shadow fill.
        palette: ``(3, 3)`` base colours of the matte, metal and lacquer classes.
        metal: ``(3,)`` specular colour of the metal class.
    """

    size: int = eqx.field(static=True)
    surface: Surface
    heights: Float[Array, "R R"]
    fields: tuple
    fill_field: FourierField
    palette: Float[Array, "3 3"]
    metal: Float[Array, " 3"]

    @property
    def n_texels(self) -> int:
        return self.size * self.size

    def positions(self, idx) -> Float[Array, "n 2"]:
        """Patch coordinates of texel centres ``idx`` (row-major numbering)."""
        idx = jnp.asarray(idx)
        row, col = idx // self.size, idx % self.size
        return (jnp.stack([col, row], -1).astype(_F32) + 0.5) / self.size

    def texels(self, idx) -> TexelModel:
        """The texel models of texel indices ``idx`` (shape ``(n,)``), stacked (leading axis n)."""
        xy = self.positions(idx)
        f = [field(xy) for field in self.fields]
        weights = jax.nn.softmax(3.0 * jnp.stack(f[0:3], -1), axis=-1)
        var = jnp.stack(f[3:6], -1)
        base = weights @ self.palette  # colour of the mixture
        albedo = jnp.clip(base * (1 + 0.2 * var), 0.02, 0.95)
        metal = jnp.clip(self.metal * (1 + 0.1 * var), 0.05, 0.95)
        roughness = 0.08 + 0.22 * jax.nn.sigmoid(1.5 * f[6])
        aniso = 1.0 + 3.0 * jax.nn.sigmoid(2.0 * f[7])
        angle = jnp.pi * jax.nn.sigmoid(1.2 * f[8])
        fill = 0.15 + 0.25 * jax.nn.sigmoid(self.fill_field(xy))
        normal, horizon = self.surface.normals(xy), horizon_map(self.heights, xy)
        return TexelModel(normal, weights, albedo, metal, roughness, aniso, angle, fill, horizon)

    def maps(self, idx) -> dict[str, Array]:
        """Per-texel parameter maps of ``idx``: height, normal, class weights, albedo, ..."""
        t = self.texels(idx)
        names = ("normal", "weights", "albedo", "roughness", "aniso", "angle", "fill", "horizon")
        return dict(height=self.surface(self.positions(idx)), **{k: getattr(t, k) for k in names})


def procedural_btf(size: int, seed: int = 0) -> ProceduralBTF:
    """Build the procedural BTF of ``size × size`` texels from ``seed`` (deterministic).

    Args:
        size: texels per side (e.g. 64 to 256; 2 to 4096 accepted).
        seed: any non-negative integer.

    Returns:
        A :class:`ProceduralBTF`.

    Raises:
        InputError: on a size or seed out of range.
    """
    if not isinstance(size, (int, np.integer)) or not MIN_SIZE <= int(size) <= MAX_SIZE:
        raise InputError(f"size must be an integer in [{MIN_SIZE}, {MAX_SIZE}], got {size!r}")
    if not isinstance(seed, (int, np.integer)) or int(seed) < 0:
        raise InputError(f"seed must be a non-negative integer, got {seed!r}")
    size, seed = int(size), int(seed)
    rng = np.random.default_rng([seed, GENERATOR_VERSION])
    surface = make_surface(rng)
    fields = tuple(FourierField.random(rng, n=10, kmax=4.0 if k < 3 else 6.0) for k in range(9))
    fill_field = FourierField.random(rng, n=8, kmax=5.0)
    metal = _METAL[rng.integers(len(_METAL))]
    matte, lacquer = _MATTE[rng.integers(len(_MATTE))], _LACQUER[rng.integers(len(_LACQUER))]
    palette = jnp.asarray(np.stack([matte, 0.3 * metal, lacquer]), _F32)
    heights = raster(surface, max(MIN_RASTER, 2 * size))
    return ProceduralBTF(
        size, surface, heights, fields, fill_field, palette, jnp.asarray(metal, _F32)
    )


# --------------------------------------------------------------------------------------------
# Dense ground truth and slice measurements of a range of texels
# --------------------------------------------------------------------------------------------


def dense_texel_table(texel, dtype=_F32) -> Float[Array, "6561 3"]:
    """A texel on all 81 × 81 UBO pairs, flattened ``i * 81 + v``.

    The directions enter as ``(81, 1, 3)`` and ``(1, 81, 3)``: what depends on one direction
    (frames, visibility, occluder normal) is computed 81 times, not 6561 times.
    """
    theta, phi = ubo_grid()
    w = to_vector(jnp.asarray(np.deg2rad(theta), dtype), jnp.asarray(np.deg2rad(phi), dtype))
    return texel(w[:, None, :], w[None, :, :]).reshape(81 * 81, 3)


def measurement_config() -> tuple[Config, Params]:
    """The slice geometry of the generated measurements: PROTOCOL aniso204, α = 15°, float32."""
    config = Config(budget="aniso204")
    return config, Params.default(config, dtype=_F32)


def _measure(model) -> Measurements:
    """The slices of :func:`measurement_config` sampled from ``model``."""
    config, params = measurement_config()
    return sample_model(model, config.counts, params.alpha, config.pairs, dtype=_F32)


@partial(jax.jit, static_argnames=("reference", "measure", "maps"))
def _texel_chunk(
    btf: ProceduralBTF, idx, reference: bool = True, measure: bool = True, maps: bool = False
):
    texels = btf.texels(idx)
    out = {}
    if maps:
        out.update({f"map_{k}": v for k, v in btf.maps(idx).items()})
    if reference:
        out["reference"] = jax.vmap(dense_texel_table)(texels)  # (n, 6561, 3)
    if measure:
        meas = jax.vmap(_measure)(texels)
        # (n, 204, 3): the valid samples, slice by slice (Measurements.to_samples order)
        counts = np.array(measurement_config()[0].counts)
        s_idx, k_idx = np.nonzero(np.arange(meas.y.shape[2]) < counts[:, None])
        out["measurements"] = meas.y[:, s_idx, k_idx]
    return out


def texel_chunk(
    btf: ProceduralBTF,
    start: int,
    stop: int,
    *,
    reference: bool = True,
    measure: bool = True,
    maps: bool = False,
    pad_to: int | None = None,
) -> dict[str, np.ndarray]:
    """Dense ground truth and/or flat slice measurements of texels ``start:stop``.

    Args:
        btf: the procedural BTF.
        start, stop: texel range (row-major numbering).
        reference: include ``"reference"``, ``(n, 6561, 3)`` float32 (``table[i, v]`` flattened
            ``i * 81 + v``).
        measure: include ``"measurements"``, ``(n, 204, 3)`` float32 in the order of
            :func:`measurement_geometry`.
        maps: include the parameter maps of :meth:`ProceduralBTF.maps` as ``"map_<name>"``.
        pad_to: evaluate a batch of this many texels (repeating the last) so that every chunk
            has one shape and compiles once; the result is cut back to ``stop - start``.

    Returns:
        A dict of numpy arrays.
    """
    if not 0 <= start < stop <= btf.n_texels:
        raise InputError(f"texel range {start}:{stop} is outside 0:{btf.n_texels}")
    n = stop - start
    idx = jnp.asarray(
        np.minimum(np.arange(start, start + max(n, pad_to or n)), stop - 1), jnp.int32
    )
    out = _texel_chunk(btf, idx, reference=reference, measure=measure, maps=maps)
    return {k: np.asarray(v[:n]) for k, v in out.items()}


def measurement_geometry() -> dict:
    """The flat sample geometry of :func:`texel_chunk`'s measurements (degrees, per sample)."""
    config, params = measurement_config()
    s = _measure(lambda wi, wv: jnp.zeros(wi.shape, _F32)).to_samples(alpha_deg=params.alpha_deg)
    geometry = {k: np.asarray(getattr(s, k), float).tolist() for k in ANGLES}
    pairs = [list(p) for p in config.pairs]
    return dict(geometry, alpha_deg=float(params.alpha_deg), pairs=pairs, budget=config.budget)
