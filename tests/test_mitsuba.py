"""The Mitsuba 3 ABRDF plugin: eval equals the table at the grid, a Lambertian sphere is rho*L."""

import numpy as np
import pytest

mi = pytest.importorskip("mitsuba")

from abrdf_jax._grid import to_vector, ubo_grid  # noqa: E402
from abrdf_jax.render._ring_interp import brdf_of, lookup  # noqa: E402


def test_lookup_reproduces_grid():
    t, p = ubo_grid()
    w = np.stack(
        [
            np.sin(np.radians(t)) * np.cos(np.radians(p)),
            np.sin(np.radians(t)) * np.sin(np.radians(p)),
            np.cos(np.radians(t)),
        ],
        -1,
    )
    tab = np.random.default_rng(0).random((81, 81, 3))
    np.testing.assert_allclose(lookup(brdf_of(tab), w[:, None], w[None, :]), tab, atol=1e-12)
    assert to_vector is not None


def test_lambertian_sphere_is_rho_times_l():
    mi.set_variant("scalar_rgb")
    from abrdf_jax.render._mitsuba_bsdf import abrdf_bsdf

    t, _ = ubo_grid()
    rho, L = 0.6, 2.0
    tab = np.broadcast_to((rho / np.pi * np.cos(np.radians(t)))[:, None, None], (81, 81, 3))
    look = mi.ScalarTransform4f().look_at(origin=[0, 0, 4], target=[0, 0, 0], up=[0, 1, 0])
    scene = mi.load_dict(
        {
            "type": "scene",
            "integrator": {"type": "path", "max_depth": 2},
            "sensor": {
                "type": "perspective",
                "fov": 30,
                "to_world": look,
                "film": {"type": "hdrfilm", "width": 16, "height": 16, "rfilter": {"type": "box"}},
                "sampler": {"type": "independent", "sample_count": 16},
            },
            "sphere": {"type": "sphere", "bsdf": abrdf_bsdf(tab.copy())},
            "env": {"type": "constant", "radiance": {"type": "rgb", "value": L}},
        }
    )
    img = np.asarray(mi.render(scene))
    block = img[5:11, 5:11].reshape(-1, 3)  # pixels on the sphere; each a 16-spp mean
    err = 4 * block.std(axis=0) / np.sqrt(len(block)) + 1e-6
    assert np.all(np.abs(block.mean(axis=0) - rho * L) < err), (block.mean(axis=0), err)
