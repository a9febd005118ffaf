"""Spatially varying data: whole BTFs (one ABRDF per texel), generated, stored, reconstructed.

- :func:`procedural_btf` / :func:`generate_btf`: a procedural BTF (height field with per-texel
  materials, self-shadowing, masking and tilted normals; anisotropic, non-reciprocal texels) with
  dense ground truth and slice measurements, deterministic from a seed, written chunk by chunk.
- :class:`ChunkedStore`: a folder with a JSON manifest and one checksummed ``.npy`` per chunk of
  texels, written atomically (a crash never leaves a chunk that looks valid).
- :func:`write_exr_pairs` / :func:`read_exr_pairs`: one OpenEXR image per direction pair, the
  layout of the UBO2003 and UTIA BTF databases.
- :func:`reconstruct_btf`: measurement store → ABRDF store, streamed in bounded memory with a
  progress bar, resumable, the texel axis sharded over all devices (:func:`init_distributed`
  for several hosts); ``model="auto"`` chooses the isotropic or the anisotropic model per texel
  (:func:`isotropy_map`: the decisions).
- :func:`texel_metrics`, :func:`texel_metrics_many`, :func:`save_error_map`: per-texel accuracy maps.

See ``docs/btf.md`` for the store layout, the resume semantics, sharding and measured numbers.
"""

from ._batch import DEFAULT_CHUNK as DEFAULT_CHUNK
from ._batch import default_config as default_config
from ._batch import isotropy_map as isotropy_map
from ._batch import reconstruct_btf as reconstruct_btf
from ._chunkfn import ChunkFunction as ChunkFunction
from ._chunkfn import ModelChoiceChunkFunction as ModelChoiceChunkFunction
from ._chunkfn import make_chunk_fn as make_chunk_fn
from ._chunkfn import make_model_choice_fn as make_model_choice_fn
from ._dataset import generate_btf as generate_btf
from ._dataset import measurement_store_of as measurement_store_of
from ._devices import ShardedRunner as ShardedRunner
from ._devices import init_distributed as init_distributed
from ._evaluate import mean_fill as mean_fill
from ._evaluate import save_error_map as save_error_map
from ._evaluate import texel_metrics as texel_metrics
from ._evaluate import texel_metrics_many as texel_metrics_many
from ._exr import pair_filename as pair_filename
from ._exr import parse_pair_filename as parse_pair_filename
from ._exr import read_exr_pairs as read_exr_pairs
from ._exr import write_exr_pairs as write_exr_pairs
from ._generate import ProceduralBTF as ProceduralBTF
from ._generate import dense_texel_table as dense_texel_table
from ._generate import measurement_geometry as measurement_geometry
from ._generate import procedural_btf as procedural_btf
from ._generate import texel_chunk as texel_chunk
from ._store import ChunkedStore as ChunkedStore
from ._texel import TexelModel as TexelModel

__all__ = [
    "ChunkFunction", "ChunkedStore", "ModelChoiceChunkFunction", "DEFAULT_CHUNK", "ProceduralBTF", "ShardedRunner", "TexelModel",
    "default_config", "dense_texel_table", "generate_btf", "init_distributed", "isotropy_map", "make_chunk_fn", "make_model_choice_fn",
    "mean_fill", "measurement_geometry", "measurement_store_of", "pair_filename", "parse_pair_filename",
    "procedural_btf", "read_exr_pairs", "reconstruct_btf", "save_error_map", "texel_chunk",
    "texel_metrics", "texel_metrics_many", "write_exr_pairs",
]
