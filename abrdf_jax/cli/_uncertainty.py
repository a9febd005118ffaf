"""``abrdf-jax reconstruct --model fused|prior --uncertainty``: the predictive standard deviation
of the learned models, written beside the table (``OUT.std.npz`` / ``OUT.std.exr``, the
table's layout: 81 × 81 direction pairs × RGB) and named in the model record. Used through
:mod:`abrdf_jax.cli._common`; no JAX on import (computing the deviation imports it:
:func:`abrdf_jax.prior.reconstruct_with_std`, in float64)."""

from __future__ import annotations

from pathlib import Path

from .._errors import InputError
from .._names import VARIANCE_MODELS
from ._outputs import announce_replace

#: What the file holds (the model record's ``uncertainty.what`` and the EXR header's comment).
STD_WHAT = (
    "latent (noise-free) posterior standard deviation sigma of ln(x cos(theta_v) + eps) per "
    "direction pair and channel, x the table's value, eps the prior's floor: the +-k sigma band "
    "of x is ((x cos(theta_v) + eps) exp(+-k sigma) - eps) / cos(theta_v); row = illumination "
    "index, column = view index (UBO2003 81-direction grid)"
)
HELP = (
    "also write the predictive standard deviation per direction pair and channel beside the "
    "table (OUT.std.npz/.exr, in the model's log space: the band is multiplicative; "
    "docs/prior.md); --model fused or prior, one input file"
)


def std_path(out: Path) -> Path:
    """Where ``--uncertainty`` writes beside the table ``out``: ``OUT.std.npz`` / ``.exr``."""
    out = Path(out)
    return out.with_name(f"{out.stem}.std{out.suffix}")


def check_uncertainty(args, folder_mode: bool) -> None:
    """``--uncertainty`` needs a model with a predictive variance and one output file."""
    if not getattr(args, "uncertainty", False):
        return
    if args.model not in VARIANCE_MODELS:
        given = (
            f"--model {args.model}"
            if args.model not in (None, "auto")
            else ("--preset/--params" if args.preset or args.params else "the automatic choice")
        )
        raise InputError(
            f"--uncertainty needs --model fused or --model prior (a Gaussian process with a "
            f"predictive variance); {given} has none"
        )
    if folder_mode:
        raise InputError("--uncertainty writes one input's deviation; give one input file")


def write_std(item, choice: dict, out: Path, source) -> Path:
    """Compute and write (atomically) the deviation of ``item``'s table beside ``out``; the
    model record's ``uncertainty`` entry says what the file holds."""
    import numpy as np

    from .. import io
    from .._cache import x64_scope
    from .._prior_operator import float64_template
    from ..prior import reconstruct_with_std

    prior, model = source.load(), choice["name"]
    counts = choice["config"].slice_counts(item.meas)  # the slices the model reads
    with x64_scope(True):
        import jax.numpy as jnp

        _, meas = float64_template(item.meas, counts)
        alpha = jnp.asarray(np.deg2rad(item.alpha), jnp.float64)
        _, std = reconstruct_with_std(meas, prior.astype(jnp.float64), model, alpha)
        std = np.asarray(std, np.float64)
    path = std_path(out)
    announce_replace(path)
    io.write_table(path, std, comment="abrdf_jax " + STD_WHAT)
    choice["record"]["uncertainty"] = {
        "file": str(path),
        "what": STD_WHAT,
        "eps": float(prior.eps),
        "scale": "the model's variance scaled to this measurement's samples (maximum evidence)",
        "mean_std": float(np.mean(std)),
        "max_std": float(np.max(std)),
    }
    return path
