"""The suite's data: sample layouts, the batch handed to a method, and the context of a run.

Part of the speed/accuracy suite (:mod:`benchmarks.suite`).
"""

from __future__ import annotations

import dataclasses
import itertools
import time

import jax
import jax.numpy as jnp
import numpy as np

import abrdf_jax as aj
from abrdf_jax.materials import dense_table, get_material, material_info, material_names

from ._common import merl_split

N_MATERIALS = {"quick": 12, "smoke": 2}  # test materials per run mode (full: the whole test split)


@dataclasses.dataclass(frozen=True)
class Layout:
    """Where the samples are: elevation pairs and samples per slice.

    Attributes:
        name: label of the layout (``"iso102"``, ``"aniso400"``, ...).
        budget: ``Config.budget`` (``"iso102"``: diagonal slices only; ``"aniso204"``: all).
        pairs: elevation pairs ``(θi, θv)`` in degrees.
        per_slice: samples per measured slice; ``None`` for PROTOCOL.md's counts (25, 25, 26, 26).
    """

    name: str
    budget: str
    pairs: tuple = aj.PROTOCOL_PAIRS
    per_slice: int | None = None

    @property
    def counts(self) -> tuple[int, ...]:
        if self.per_slice is None:
            return aj.protocol_counts(self.budget)
        axial = self.per_slice if self.budget == "aniso204" else 0
        return tuple(c for _ in self.pairs for c in (axial, self.per_slice))

    @property
    def n_samples(self) -> int:
        return sum(self.counts)

    def config(self, **kw) -> aj.Config:
        return aj.Config(budget=self.budget, pairs=tuple(self.pairs), **kw)


_PAIRS9 = tuple(itertools.product((30.0, 45.0, 75.0), repeat=2))
LAYOUTS = {
    lay.name: lay
    for lay in (
        Layout("iso102", "iso102"),
        Layout("aniso204", "aniso204"),
        Layout("iso48", "iso102", per_slice=12),
        Layout("iso200", "iso102", per_slice=50),
        Layout("iso400", "iso102", per_slice=100),
        Layout("iso216-9pairs", "iso102", pairs=_PAIRS9, per_slice=24),
        Layout("aniso48", "aniso204", per_slice=6),
        Layout("aniso96", "aniso204", per_slice=12),
        Layout("aniso400", "aniso204", per_slice=50),
    )
}


def sample_models(
    models, layout: Layout, dtype=jnp.float32, alpha_deg: float = aj.PROTOCOL_ALPHA_DEG
) -> aj.Measurements:
    """Slice samples of stacked neural models (exact angles, vmapped) on ``layout``."""
    alpha = jnp.asarray(np.deg2rad(alpha_deg), dtype)
    fn = jax.jit(
        jax.vmap(lambda m: aj.sample_model(m, layout.counts, alpha, layout.pairs, dtype=dtype))
    )
    return fn(models)


def sample_materials(
    materials, layout: Layout, dtype=jnp.float32, alpha_deg: float = aj.PROTOCOL_ALPHA_DEG
) -> aj.Measurements:
    """Slice samples of a list of (different) materials on ``layout``, stacked."""
    alpha = jnp.asarray(np.deg2rad(alpha_deg), dtype)
    return aj.stack_measurements(
        [aj.sample_model(m, layout.counts, alpha, layout.pairs, dtype=dtype) for m in materials]
    )


# ----------------------------------------------------------------------------------------------
# Data handed to a method, and the context of a run


@dataclasses.dataclass
class Batch:
    """The input of one timed call: every test material of a dataset on one layout.

    Attributes:
        meas: stacked :class:`abrdf_jax.Measurements` ``(B, S, nmax)`` in the entry's dtype.
        layout: the :class:`Layout`.
    """

    meas: aj.Measurements
    layout: Layout
    _samples: list | None = None
    _flat: np.ndarray | None = None

    @property
    def size(self) -> int:
        return int(self.meas.y.shape[0])

    def samples(self) -> list:
        """Per-material flat :class:`abrdf_jax.Samples` (numpy; for the scipy peer), cached."""
        if self._samples is None:
            self._samples = [
                jax.tree_util.tree_map(lambda x, k=k: x[k], self.meas).to_samples()
                for k in range(self.size)
            ]
        return self._samples

    def flat(self):
        """Valid sample values ``(B, n, 3)`` in layout order (the PCA peer's input), cached."""
        if self._flat is None:
            from .pca_peer import flat_samples

            self._flat = flat_samples(self.meas)
        return self._flat


class Context:
    """Data and caches of one run: test batches per dataset/layout/dtype, training samples per layout."""

    def __init__(self, mode: str, data_dir=None, log=print):
        self.mode = mode
        self.log = log
        self.data_dir = data_dir
        t = time.perf_counter()
        names, models, ref, _ = merl_split("test", data_dir)
        if mode in N_MATERIALS:
            idx = np.unique(np.linspace(0, len(names) - 1, N_MATERIALS[mode]).round().astype(int))
            models = jax.tree_util.tree_map(lambda x: x[idx], models)
            ref, names = ref[idx], [names[i] for i in idx]
        self.names = {"merl-test": names}
        self._models = {"merl-test": models}
        self.refs = {"merl-test": np.asarray(ref, np.float32)}
        self._batches: dict = {}
        self._train: dict = {}
        self._train_data = None
        self.cache: dict = {}  # free space for entries (e.g. fitted priors per layout)
        self.load_seconds = time.perf_counter() - t

    def _load_analytic(self):
        if "analytic-aniso" not in self.names:  # loaded on first use (full mode only)
            aniso = [n for n in material_names() if not material_info(n)["isotropic"]]
            self.names["analytic-aniso"] = aniso
            self._models["analytic-aniso"] = [get_material(n) for n in aniso]
            self.refs["analytic-aniso"] = np.stack(
                [dense_table(get_material(n)) for n in aniso]
            ).astype(np.float32)

    def batch(self, dataset: str, layout: Layout, dtype) -> Batch:
        if dataset == "analytic-aniso":
            self._load_analytic()
        key = (dataset, layout.name, jnp.dtype(dtype).name)
        if key not in self._batches:
            src = self._models[dataset]
            meas = (
                sample_materials(src, layout, dtype)
                if isinstance(src, list)
                else sample_models(src, layout, dtype)
            )
            self._batches[key] = Batch(jax.block_until_ready(meas), layout)
        return self._batches[key]

    def train(self, layout: Layout):
        """MERL train split: ``(tables (N,81,81,3), exact samples (N,n,3), one layout Measurements)``."""
        if self._train_data is None:
            _, models, ref, _ = merl_split("train", self.data_dir)
            self._train_data = (models, np.asarray(ref, np.float32))
        if layout.name not in self._train:
            from .pca_peer import flat_samples

            models, ref = self._train_data
            meas = sample_models(models, layout, jnp.float32)
            one = jax.tree_util.tree_map(lambda x: x[0], meas)
            self._train[layout.name] = (ref, np.asarray(flat_samples(meas)), one)
        return self._train[layout.name]
