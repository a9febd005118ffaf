"""File input and output (public API): atomic writes, measurement CSV, ABRDF tables, MERL files.

The names are loaded on first use (PEP 562, as in :mod:`abrdf_jax`), so ``from abrdf_jax import io``
imports no JAX: reading a table or checking a measurement CSV needs numpy only (the CSV reader
imports the :class:`~abrdf_jax.Samples` class once a file has passed every check), while the MERL
helpers import JAX when first touched.
"""

from __future__ import annotations

from .._lazy import lazy_exports

# public name -> private module that defines it (the one place this package's API is listed)
_EXPORTS = {
    "_atomic": ("atomic_write", "is_temp"),
    "_csv": ("CSV_COLUMNS", "read_sample_columns", "read_samples_csv", "write_samples_csv"),
    "_tables": ("NPZ_KEY", "TABLE_SHAPE", "read_table", "write_table", "write_tables"),
    "_merl": (
        "MERL_SCALE",
        "MERL_SHAPE",
        "MERLMaterial",
        "merl_bin_indices",
        "merl_lookup",
        "read_merl_binary",
        "write_merl_binary",
    ),
}
__getattr__, __dir__, __all__ = lazy_exports(__name__, globals(), _EXPORTS)
