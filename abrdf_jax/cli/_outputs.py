"""How the subcommands treat their outputs: checks before any work, the writer's lock, and the
one overwrite policy of every command that writes (:data:`OVERWRITE_POLICY`, quoted in each
writing command's ``--help``; docs/stability.md, "Overwriting outputs"). Used through
:mod:`abrdf_jax.cli._common`."""

from __future__ import annotations

import os
import sys
from pathlib import Path

from .._errors import InputError

#: The overwrite policy, one sentence, the same in every writing command's ``--help``.
OVERWRITE_POLICY = (
    "Existing outputs: an output file that exists is replaced (atomically, and the run says "
    "'replacing FILE'); an output folder or store made with the same settings is resumed or "
    "redone in place, one made with other settings is refused (exit 2) unless --overwrite is "
    "given (docs/stability.md, 'Overwriting outputs')."
)


def _say(message: str) -> None:
    print(f"abrdf-jax: {message}", file=sys.stderr)


def announce_replace(path: Path) -> None:
    """Say, in one line on stderr, that the existing output file ``path`` will be replaced."""
    if Path(path).is_file():
        _say(f"replacing {path}")


def check_output_file(path: Path, suffixes: tuple[str, ...], what: str) -> Path:
    """Fail before any work when ``path`` cannot be an output of the given kind."""
    if path.suffix.lower() not in suffixes:
        use = " or ".join(suffixes)
        raise InputError(f"{path}: unknown {what} extension {path.suffix or '(none)'!r}; use {use}")
    parent = path.parent
    if not parent.is_dir():
        raise InputError(f"{path}: output folder {parent} does not exist")
    if path.is_dir():
        raise InputError(f"{path}: is a folder, expected a file name")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise InputError(f"{path}: output folder {parent} is not writable")
    return path


def check_output_folder(path: Path) -> Path:
    """Fail before any work when the output folder or store ``path`` cannot be written: its
    parent must exist, and the folder (or, for a new one, its parent) must be writable."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise InputError(f"{path}: exists and is not a folder")
    if not path.exists() and not path.parent.is_dir():
        raise InputError(f"{path}: parent folder {path.parent} does not exist")
    where = path if path.exists() else path.parent
    if not os.access(where, os.W_OK | os.X_OK):  # EROFS stops root too; permissions do not
        raise InputError(f"{path}: folder {where} is not writable")
    return path


def check_json_output(path: Path) -> Path:
    """A parameter file name (``.json``) in an existing, writable folder."""
    if path.suffix.lower() != ".json":
        raise InputError(f"{path}: parameter files are JSON; use a .json name")
    return check_output_file(path, (".json",), "parameter file")


def output_lock(out: Path, warn, also=(), announce=True):
    """The lock of an output file, folder or store for the time a command writes it
    (:func:`abrdf_jax.io._lock.output_lock`): a second process writing the same output is
    refused (exit 2, naming the holder); a killed holder's lock is taken over with a warning and
    its temporary files are removed. Taken just before the output is written: an existing
    output file is announced here ("replacing FILE", the policy) unless ``announce`` is false
    (a command that takes the lock before its input checks announces at the write)."""
    from ..io._lock import output_lock as lock

    if announce:
        announce_replace(out)
    return lock(out, warn=warn, also=also)


def refused_store(error: InputError) -> InputError:
    """A store's "holds a different store" refusal (:mod:`abrdf_jax.btf`), naming the CLI's
    ``--overwrite``."""
    text = str(error)
    if text.endswith("overwrite it"):
        return InputError(text[: -len("overwrite it")] + "pass --overwrite to replace it")
    return error


def folder_settings_check(record: Path, settings: dict, overwrite: bool) -> bool:
    """The policy for an output folder with a model record ``record``: True when the folder's
    earlier run had the same ``settings`` (or there is none: nothing to keep), False when it had
    others and ``overwrite`` is given (nothing of it is kept); refused otherwise."""
    import json

    settings = json.loads(json.dumps(settings))  # as the record holds them
    try:
        old = json.loads(record.read_text()).get("settings")
    except (OSError, ValueError, AttributeError):
        return True  # no record (or a torn one): no earlier settings to honour
    if old is None or old == settings:
        return True
    if overwrite:
        _say(f"replacing the tables of {record.name[: -len('.model.json')]} (--overwrite)")
        return False
    diff = sorted(k for k in set(old) | set(settings) if old.get(k) != settings.get(k))
    raise InputError(
        f"{record}: the output folder was written with other settings ({', '.join(diff)} "
        "differ); choose another folder or pass --overwrite to replace it"
    )
