"""Spatially varying data: whole BTFs (one ABRDF per texel), generated, stored, reconstructed.

- :func:`procedural_btf` / :func:`generate_btf`: a procedural BTF (height field with per-texel
  materials, self-shadowing, masking and tilted normals; anisotropic, non-reciprocal texels) with
  dense ground truth and slice measurements, deterministic from a seed, written chunk by chunk.
- :class:`ChunkedStore`: a folder with a JSON manifest and one checksummed ``.npy`` per chunk of
  texels, written atomically (a crash never leaves a chunk that looks valid); :data:`CHECKSUMS`,
  :data:`CHECKSUM`: the markers' checksums (CRC-32C written, zlib's CRC-32 of older stores read).
- :class:`ZarrStore` / :func:`export_zarr`: the same store as a zarr v3 group (``[zarr]``
  extra; read by xarray, dask, napari); :func:`open_store` opens either format.
- :func:`write_exr_pairs` / :func:`read_image_pairs`: one image per direction pair, the layout of
  the UBO2003 and UTIA BTF databases: EXR written; PNG, JPEG (sRGB) or EXR read, from a folder
  or a zip archive, in a configurable azimuth convention (:func:`capture_angles`).
- :func:`reconstruct_btf`: measurement store → ABRDF store, streamed in bounded memory with a
  progress bar, resumable, the texel axis sharded over all devices (:func:`init_distributed`
  for several hosts); ``model="auto"`` chooses the isotropic or the anisotropic model per texel
  (:func:`isotropy_map`: the decisions).
- :func:`texel_metrics`, :func:`texel_metrics_many`, :func:`save_error_map`: per-texel accuracy maps.

See ``docs/btf.md`` for the store layout, the resume semantics, sharding and measured numbers.
"""

from .._lazy import lazy_exports

# public name -> private module that defines it; loaded on first use
_EXPORTS = {
    "_batch": ("DEFAULT_CHUNK", "default_config", "isotropy_map", "reconstruct_btf"),
    "_bivariate": ("BivariateChunkFunction", "make_bivariate_chunk_fn"),
    "_checksum": ("CHECKSUM", "CHECKSUMS"),
    "_chunkfn": (
        "ChunkFunction",
        "ModelChoiceChunkFunction",
        "make_chunk_fn",
        "make_model_choice_fn",
    ),
    "_dataset": ("generate_btf", "measurement_store_of"),
    "_devices": ("ShardedRunner", "init_distributed"),
    "_evaluate": ("mean_fill", "save_error_map", "texel_metrics", "texel_metrics_many"),
    "_exr": (
        "capture_angles",
        "pair_filename",
        "parse_pair_filename",
        "read_exr_pairs",
        "read_image_pairs",
        "write_exr_pairs",
    ),
    "_generate": (
        "ProceduralBTF",
        "dense_texel_table",
        "measurement_geometry",
        "procedural_btf",
        "texel_chunk",
    ),
    "_store": ("ChunkedStore",),
    "_backend": ("FORMATS", "DEFAULT_FORMAT", "open_store"),
    "_zarr": ("ZarrStore",),
    "_zarr_export": ("export_zarr",),
    "_texel": ("TexelModel",),
}
__getattr__, __dir__, __all__ = lazy_exports(__name__, globals(), _EXPORTS)
