"""Error types shared by the package: bad input is reported, never silently accepted."""

from __future__ import annotations


class InputError(ValueError):
    """Bad user input: a malformed file, argument or value.

    The message names the file, line or argument at fault. The command line turns it into a
    one-line message and a non-zero exit status instead of a traceback.
    """


def located(message: str, path=None, line: int | None = None) -> InputError:
    """Build an :class:`InputError` whose message starts with ``path:line:``."""
    where = ""
    if path is not None:
        where = f"{path}"
        if line is not None:
            where += f":{line}"
        where += ": "
    return InputError(where + message)


def require(module: str, purpose: str, requirement: str, name: str | None = None):
    """Import ``module``, or raise an :class:`InputError` naming what needs it (``name``, default
    the requirement's package) and how to install it: a missing optional dependency is one line,
    not a bug."""
    import importlib

    try:
        return importlib.import_module(module)
    except ImportError as e:
        name = name or f"the {requirement.split('>')[0]} package"
        raise InputError(f"{purpose} needs {name} (pip install '{requirement}')") from e


def non_finite(arr) -> tuple[int, tuple[int, ...]] | None:
    """``(how many, index of the first)`` NaN or infinite entries of a numpy array, or ``None``:
    what a message about non-finite input names."""
    import numpy as np

    bad = ~np.isfinite(arr)
    if not bad.any():
        return None
    return int(bad.sum()), tuple(int(i) for i in np.argwhere(bad)[0])
