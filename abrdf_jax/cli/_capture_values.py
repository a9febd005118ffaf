"""What a capture's values hold that its reconstruction cannot show, said before any work
(``abrdf-jax reconstruct``; docs/stability.md, "Bad input"): negative values, no positive value
at all, or none in one or two of the channels. No JAX: the readers call it; numpy is imported
when called (the command line imports this module at start-up, before numpy: cli/_blas.py)."""

from __future__ import annotations


def value_warnings(path, samples) -> list[str]:
    """The warnings of one capture (``samples.rgb`` ``(n, 3)``), each naming ``path``: negative
    values (dark-frame noise; kept, the output is clamped at 0), no positive value at all (a
    dark frame, a capped lens, a wrong column: the reconstruction is a table of zeros), or none
    in one or two of the channels (a monochrome camera writing one column: those channels of
    the reconstruction are zero). An empty capture gives none (the reader refuses it first)."""
    import numpy as np

    rgb = np.asarray(samples.rgb)
    lit = (rgb > 0).any(axis=0) if len(rgb) else np.ones(3, bool)
    if not lit.any():
        return [
            f"{path}: every sample is 0 or below ({len(rgb)} samples, max {rgb.max():.3g}): "
            "the reconstruction is zero everywhere (to rounding); a dark frame, a capped lens, "
            "the wrong columns?"
        ]
    out = []
    if not lit.all():
        dark = [c for c, on in zip("rgb", lit) if not on]
        if len(dark) == 2:
            what, which = f"channels {dark[0]} and {dark[1]} are", "those channels of the"
            which += " reconstruction are"
        else:
            what, which = f"channel {dark[0]} is", "that channel of the reconstruction is"
        out.append(
            f"{path}: {what} 0 or below in every sample: {which} zero everywhere; a monochrome "
            "capture, the wrong columns?"
        )
    neg = (rgb < 0).any(axis=1)
    if neg.any():
        out.append(
            f"{path}: {int(neg.sum())} of {len(rgb)} samples have negative values (min "
            f"{rgb.min():.3g}, first in data row {int(np.argmax(neg)) + 1}); kept as measured, "
            "the reconstruction is clamped at 0"
        )
    return out
