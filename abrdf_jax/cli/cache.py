"""``abrdf-jax cache``: where the caches are, whether they are on, how big; ``--clear`` empties them.

The folder is ``$ABRDF_JAX_CACHE_DIR``, else ``$XDG_CACHE_HOME/abrdf_jax``, else
``~/.cache/abrdf_jax``; ``ABRDF_JAX_NO_CACHE=1`` turns the caches off (docs/cache.md). Imports
no JAX.
"""

from __future__ import annotations

from . import _common as common

HELP = {
    "help": "show or clear the compilation and operator caches",
    "description": "Print the cache folder, whether the caches are on, and the size and number of "
    "entries of JAX's compilation cache (xla/) and of the built reconstruction operators "
    "(operators/). The folder is $ABRDF_JAX_CACHE_DIR, else $XDG_CACHE_HOME/abrdf_jax, else "
    "~/.cache/abrdf_jax; ABRDF_JAX_NO_CACHE=1 turns the caches off.",
    "--cache-dir": "the cache folder to show or clear (default: as above)",
    "--clear": "remove both caches (xla/ and operators/; nothing else in the folder)",
}
WHAT = {
    "xla": "JAX compilation cache",
    "operators": "built reconstruction operators",
    "priors": "the default prior (built on first use)",
}


def register(sub) -> None:
    p = common.command(sub, "cache", run, HELP["help"], HELP["description"])
    add = common.adder(p, HELP)
    add("--cache-dir", metavar="DIR")
    add("--clear", action="store_true")


def _size(n: float) -> str:
    for unit in ("B", "kB", "MB"):
        if n < 1000:
            return f"{n:.0f} {unit}" if unit == "B" else f"{n:.1f} {unit}"
        n /= 1000
    return f"{n:.1f} GB"


def run(args) -> int:
    from .. import _cache

    folder = _cache.cache_location(args.cache_dir)
    off = _cache.cache_disabled(args.cache_dir)
    if folder is None:
        print("cache folder: none (no home folder; set ABRDF_JAX_CACHE_DIR)")
        return 0
    state = f"off: {off}" if off else "on"
    print(f"cache folder: {folder} ({state})")
    if args.clear:
        before = _cache.cache_summary(folder)
        _cache.clear_cache(folder)
        freed = sum(v["bytes"] for v in before.values())
        print(f"cleared: {_size(freed)} removed")
    for name, info in _cache.cache_summary(folder).items():
        entries = f"{info['entries']} entr{'y' if info['entries'] == 1 else 'ies'}"
        print(f"  {name + '/':<11} {_size(info['bytes']):>9}  {entries:<12}  {WHAT[name]}")
    return 0
