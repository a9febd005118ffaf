"""The ``abrdf-jax`` command line: reconstruct, suggest, sample, evaluate, reference, render, demo,
materials, fit, btf, cache, prior.

One module per subcommand, each with ``register(subparsers)``; what they share lives in
:mod:`abrdf_jax.cli._common` (the only module they import from this package's CLI). This module
holds only the parser and the entry point. Building the parser imports no JAX: every choice comes
from :mod:`abrdf_jax._names`, and the numerics are imported inside the commands.

Exit status: 0 success; 2 bad input (an :class:`~abrdf_jax.InputError` or an ``OSError`` naming a
file: one line ``abrdf-jax: error: ...``, ``-v`` adds the traceback; also argparse's usage
errors); 1 an internal error (any other exception: the traceback and a line asking to report it);
130 interrupted. Every output file is written atomically: a failed run leaves no partial file and
does not touch an existing one.
"""

from __future__ import annotations

import argparse
import os
import sys
import traceback
import warnings

from .._errors import InputError
from . import btf, cache, demo, evaluate, fit, materials, prior, reconstruct, reference, render
from . import _malloc, sample, suggest
from ._common import PROG, say, verbose_parent, version, warn

#: The subcommands, in ``--help`` order.
SUBCOMMANDS = (
    reconstruct,
    suggest,
    sample,
    evaluate,
    reference,
    render,
    demo,
    materials,
    fit,
    btf,
    cache,
    prior,
)


class _Version(argparse.Action):
    """``--version``: the installed version, looked up only when asked (the metadata look-up
    costs ~50 ms, which every other call would pay at parser construction)."""

    def __init__(self, option_strings, dest, **kwargs):
        kwargs.setdefault("nargs", 0)
        kwargs.setdefault("default", argparse.SUPPRESS)
        super().__init__(option_strings, dest, **kwargs)

    def __call__(self, parser, namespace, values, option_string=None):
        print(f"{parser.prog} {version()}")  # on stdout, as argparse's own version action
        parser.exit()


def build_parser() -> argparse.ArgumentParser:
    """The ``abrdf-jax`` argument parser (imports no JAX)."""
    about = "Reconstruct a material's full ABRDF (81x81 light x view directions, RGB) from sparse "
    about += "slice measurements (Filip, ICPR 2012)."
    p = argparse.ArgumentParser(prog=PROG, parents=[verbose_parent()], description=about)
    p.add_argument("--version", action=_Version, help="show the version and exit")
    sub = p.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for module in SUBCOMMANDS:
        module.register(sub)
    return p


def _user_error(exc: BaseException) -> str | None:
    """The one-line message of bad input, or ``None`` for an internal error."""
    if isinstance(exc, InputError):
        return str(exc) or type(exc).__name__
    if isinstance(exc, OSError) and exc.filename is not None:
        return f"{exc.filename}: {exc.strerror or exc}"
    return None


_PACKAGE = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _show_warning(message, category, filename, lineno, file=None, line=None):
    """The package's own warnings (a cache it cannot write, a prior rebuilt) as one line
    ``abrdf-jax: warning: ...``, as the commands' own; other libraries' keep Python's format."""
    if os.path.abspath(filename).startswith(_PACKAGE + os.sep):
        warn(" ".join(str(message).split()))
    else:
        (file or sys.stderr).write(
            warnings.formatwarning(message, category, filename, lineno, line)
        )


def main(argv: list[str] | None = None) -> int:
    """Run the command line; returns the exit status (see the module docstring)."""
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as e:  # --help, --version, or a usage error already printed by argparse
        return e.code if isinstance(e.code, int) else (0 if e.code is None else 2)
    try:
        with warnings.catch_warnings():  # restores the hook: main() may run inside a test
            warnings.showwarning = _show_warning
            _malloc.keep_freed_blocks()  # large temporaries reuse freed memory (glibc)
            return int(args.func(args) or 0)
    except KeyboardInterrupt:
        say("interrupted")
        return 130
    except BrokenPipeError:  # the reader of our output went away (``... | head``): not an error
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no second error at exit
        return 141
    except Exception as e:  # noqa: BLE001 - the boundary: every exception ends here, sorted below
        message = _user_error(e)
        if message is None:
            traceback.print_exc()
            say(
                f"internal error ({type(e).__name__}: {e}); this is a bug, not bad input: please "
                f"report it with the traceback above, the command line and '{PROG} {version()}'"
            )
            return 1
        if getattr(args, "verbose", False):
            traceback.print_exc()
        say(f"error: {message}")
        return 2
