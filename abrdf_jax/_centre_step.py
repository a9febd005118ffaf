"""The first stage of a two-stage host operator: each material's subspaces restored at the RBF
centres, in numpy (issue 13: ``--model aniso`` without JAX).

A subspace rule that is not linear in the samples makes the reconstruction two maps: the rule
per material (the toroidal subspaces at the RBF centres, eq. 2–5), then one matrix from the
centres to the grid (:func:`abrdf_jax.compile_operator` with ``nonlinear="two_stage"``). For the
rule ``"filip2012"`` on the log of the samples (the recommended anisotropic model, ``--model
aniso``) the first map is affine in the slice terms with coefficients read off each material's
slice extremes (:mod:`abrdf_jax._rules`), so it runs in numpy as the pipeline runs it in JAX
(:func:`abrdf_jax._subspace.centre_subspaces` with ``xp=numpy``): the operator store holds such
an operator as an entry (:class:`abrdf_jax._operator_entry.OperatorEntry` with a
:class:`CentreStep`), and the command line applies it without importing JAX. A dense capture
(hundreds or thousands of samples a slice, denser RBF centres) takes two stages with any affine
rule: its second stage does not depend on where the samples lie, so one stored matrix serves
every dense capture of the same elevation pairs and setting. Other nonlinear settings (a log
after the rule, the linear value space's centre cap) stay on the pipeline.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ._grid import centre_count
from ._rules import AFFINE
from ._subspace import RULES, centre_subspaces


def host_two_stage(config, meas=None) -> bool:
    """Whether the operator store holds ``config``'s operator (on ``meas``'s layout, if given)
    as a two-stage numpy entry: a subspace rule affine in the slice terms on the log of the
    samples that is not linear in them (``filip2012``, module docstring), or any such rule on a
    dense layout (``meas.centre_azimuths`` set: thousands of samples, whose one-stage matrix
    would have a column per sample; its second stage is shared by every dense capture of the
    same elevation pairs, ``abrdf_jax._cache.cached_entry``)."""
    if not affine_on_log(config):
        return False
    dense = meas is not None and getattr(meas, "centre_azimuths", None) is not None
    return dense or not RULES[config.subspace_rule].linear


def affine_on_log(config) -> bool:
    """Whether ``config``'s reconstruction can take the two-stage numpy form on any layout: a
    subspace rule affine in the slice terms (:data:`abrdf_jax._rules.AFFINE`) on the log of the
    samples. Besides :func:`host_two_stage`'s settings, a folder's sample layouts that are too
    many to build an operator each (jittered captures: a layout a file) take it
    (:mod:`abrdf_jax._engine`): one second stage for all of them."""
    return config.value_space == "logsamples" and config.subspace_rule in AFFINE


def nonlinear_mode(config, meas=None) -> str:
    """``compile_operator``'s ``nonlinear`` argument for ``config``'s operator (on ``meas``'s
    layout): ``"two_stage"`` where :func:`host_two_stage` holds, else ``"raise"``."""
    return "two_stage" if host_two_stage(config, meas) else "raise"


@dataclasses.dataclass(frozen=True)
class CentreStep:
    """The rule at the centres of one sample layout (module docstring): the elevation pairs,
    the centres' azimuth count (``None``: the UBO grid's), α (radians), the rule and the slice
    interpolation."""

    pairs: tuple
    azimuths: int | None
    alpha: float
    rule: str
    interp: str

    @classmethod
    def of(cls, config, params, template) -> "CentreStep":
        """The step of ``config`` with parameters ``params`` on ``template``'s layout."""
        pairs = tuple(tuple(float(v) for v in p) for p in template.pairs)
        alpha = float(np.asarray(params.alpha))
        return cls(pairs, template.centre_azimuths, alpha, config.subspace_rule, config.interp)

    @property
    def n_centres(self) -> int:
        return centre_count(self.pairs, self.azimuths)

    def __call__(self, z, index, t, count) -> np.ndarray:
        """Compact values ``z`` ``(B, n_in, C)`` (the valid samples at the flat slots ``index``
        of the padded layout ``t`` ``(S, nmax)``, ``count``) → their subspaces at the centres
        ``(B, n_c, C)`` float32: every material and channel one column of one call."""
        b, n_in, c = z.shape
        s, nmax = t.shape
        full = np.zeros((s * nmax, b * c), np.float32)
        full[index] = np.transpose(z, (1, 0, 2)).reshape(n_in, b * c)
        vals = centre_subspaces(
            t.astype(np.float32), full.reshape(s, nmax, b * c), count, self.pairs,
            self.azimuths, np.float32(self.alpha), self.rule, self.interp, xp=np,
        )  # fmt: skip
        # numpy's where() of two Python floats is float64: parts of the interpolation run in
        # float64 here (float32 in JAX), which only rounds less; the features go on in float32
        return np.transpose(vals.reshape(-1, b, c), (1, 0, 2)).astype(np.float32)

    def to_json(self) -> dict:
        return dataclasses.asdict(self) | {"pairs": [list(p) for p in self.pairs]}

    @classmethod
    def from_json(cls, doc) -> "CentreStep":
        """Raises ``ValueError`` (or ``TypeError``, ``KeyError``) for a malformed record."""
        step = cls(
            pairs=tuple((float(a), float(b)) for a, b in doc["pairs"]),
            azimuths=None if doc["azimuths"] is None else int(doc["azimuths"]),
            alpha=float(doc["alpha"]),
            rule=str(doc["rule"]),
            interp=str(doc["interp"]),
        )
        if step.rule not in AFFINE or not step.pairs or not np.isfinite(step.alpha):
            raise ValueError(f"not a centre step: {doc!r}")
        return step
