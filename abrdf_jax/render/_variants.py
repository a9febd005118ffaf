"""Choosing a Mitsuba 3 variant for the ABRDF plugin, and finding out whether it works here.

``scalar_rgb`` needs nothing but Mitsuba. The vectorised ``llvm_ad_rgb`` needs a libLLVM that
Dr.Jit can compile with: when ``DRJIT_LIBLLVM_PATH`` is not set, :func:`use_variant` points it
at the newest ``libLLVM`` found in the usual system folders (Dr.Jit's own search may pick an
older one; LLVM 15 aborts the process while compiling Mitsuba's kernels, LLVM 19 works). A
failing LLVM aborts the whole process instead of raising, so a variant other than
``scalar_rgb`` is first tried in a child process (a tiny render through the plugin) and refused
with one line when the child fails.
"""

from __future__ import annotations

import functools
import glob
import os
import re
import subprocess
import sys
from pathlib import Path

from .._errors import InputError
from .._names import RENDER_VARIANTS
from ._mitsuba_bsdf import import_mitsuba

#: Where :func:`llvm_library` looks for ``libLLVM`` (Debian/Ubuntu, LLVM's own packages, /usr/local).
LLVM_GLOBS = (
    "/usr/lib/*-linux-gnu/libLLVM*.so*",
    "/usr/lib/llvm-*/lib/libLLVM*.so*",
    "/usr/local/lib/libLLVM*.so*",
)
_ENV = "DRJIT_LIBLLVM_PATH"
_PROBE = (
    "import sys, numpy as np\n"
    "from abrdf_jax.render import render_table\n"
    "img = render_table(np.full((81, 81, 3), 0.1), size=8, spp=1, variant=sys.argv[1], probe=False)\n"
    "assert np.isfinite(img).all() and img[..., :3].max() > 0\n"
    "print('ok')\n"
)


def llvm_library() -> str | None:
    """The newest ``libLLVM`` shared library in :data:`LLVM_GLOBS` (by major version), or ``None``."""
    found = {}
    for pattern in LLVM_GLOBS:
        for path in glob.glob(pattern):
            m = re.search(r"libLLVM[-.]?(?:so\.)?(\d+)", Path(path).name)
            if m and os.path.isfile(path):
                found.setdefault(int(m.group(1)), path)
    return found[max(found)] if found else None


def _environment(variant: str) -> dict:
    """The environment a variant runs in: ``DRJIT_LIBLLVM_PATH`` set for an LLVM one if unset."""
    env = {}
    if variant.startswith("llvm") and not os.environ.get(_ENV):
        lib = llvm_library()
        if lib is not None:
            env[_ENV] = lib
    return env


@functools.cache
def probe(variant: str) -> str | None:
    """``None`` if ``variant`` renders the plugin in a child process here, else why not (one line)."""
    env = {**os.environ, **_environment(variant)}
    root = str(Path(__file__).resolve().parents[2])
    env["PYTHONPATH"] = root + os.pathsep + env.get("PYTHONPATH", "")
    try:
        out = subprocess.run(
            [sys.executable, "-c", _PROBE, variant],
            env=env,
            capture_output=True,
            text=True,
            timeout=300,
        )
    except subprocess.TimeoutExpired:
        return "a test render did not finish in 300 s"
    if out.returncode == 0 and out.stdout.strip().endswith("ok"):
        return None
    lines = [x.strip() for x in (out.stderr + out.stdout).splitlines() if x.strip()]
    last = next((x for x in reversed(lines) if "error" in x.lower()), None)
    last = last or (lines[-1] if lines else "")
    return f"a test render failed (exit status {out.returncode}): {last[:200]}"


def use_variant(variant: str, check: bool = True):
    """Set Mitsuba's ``variant`` (one of :data:`abrdf_jax._names.RENDER_VARIANTS`) and return
    the ``mitsuba`` module.

    Raises:
        InputError: Mitsuba missing (names the ``abrdf_jax[render]`` extra), a variant not in the
            list or not compiled into this Mitsuba, or (``check``) one whose test render fails
            here, with the reason.
    """
    if variant not in RENDER_VARIANTS:
        raise InputError(f"--variant {variant!r}: choose one of {', '.join(RENDER_VARIANTS)}")
    for key, value in _environment(variant).items():
        os.environ.setdefault(key, value)  # before Dr.Jit starts its LLVM backend
    mi, _ = import_mitsuba()
    if variant not in mi.variants():
        raise InputError(
            f"--variant {variant}: not in this Mitsuba build (it has {', '.join(mi.variants())})"
        )
    if check and variant != "scalar_rgb" and mi.variant() != variant:
        why = probe(variant)
        if why is not None:
            raise InputError(f"--variant {variant} does not work here: {why}")
    mi.set_variant(variant)
    return mi
