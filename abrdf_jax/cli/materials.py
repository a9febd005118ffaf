"""``abrdf-jax materials``: the built-in materials, one a line, with what is known about each."""

from __future__ import annotations

from . import _common as common


def register(sub) -> None:
    common.command(sub, "materials", run, "list the built-in materials")


def run(args) -> int:
    from .. import materials

    names = list(materials.material_names())
    width = max((len(n) for n in names), default=4)
    for name in names:
        info = materials.material_info(name)
        kind = "isotropic" if info["isotropic"] else "anisotropic"
        print(f"{name:<{width}}  {kind}  {info['description']}".rstrip())
    print("(also nbrdf:<merl-name> for the neural MERL fits in the shared data)")
    return 0
