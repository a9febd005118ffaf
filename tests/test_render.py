"""Figures: ABRDF images, table interpolation at arbitrary directions, lit spheres, comparison PNG."""

import numpy as np
import pytest

from abrdf_jax import metrics
from abrdf_jax._errors import InputError
from abrdf_jax._grid import ubo_grid
from abrdf_jax.render import (
    abrdf_image,
    comparison_figure,
    exposure_of,
    grid_weights,
    interpolate_table,
    render_sphere,
)

LUMA = np.array([0.2126, 0.7152, 0.0722])


def _vec(theta_deg, phi_deg):
    t, p = np.radians(theta_deg), np.radians(phi_deg)
    return np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], axis=-1)


def _grid_vectors():
    return _vec(*ubo_grid())  # float64, (81, 3)


def _lambert(albedo=(0.6, 0.4, 0.3)):
    cos_i = _grid_vectors()[:, 2]
    return np.broadcast_to(np.asarray(albedo) / np.pi * cos_i[:, None, None], (81, 81, 3)).copy()


def _projected(w):
    """Azimuthal-equidistant coordinates (θ in degrees) in which the interpolation is barycentric."""
    theta = np.degrees(np.arccos(np.clip(w[..., 2], -1, 1)))
    r = np.hypot(w[..., 0], w[..., 1])
    s = np.divide(theta, r, out=np.zeros_like(r), where=r > 0)
    return w[..., 0] * s, w[..., 1] * s


# ---------------------------------------------------------------------------------------------
# ABRDF image and tone mapping
# ---------------------------------------------------------------------------------------------


def test_abrdf_image_shape_range_and_scale(rng):
    table = rng.gamma(0.5, 0.2, size=(81, 81, 3))
    img = abrdf_image(table)
    assert img.shape == (81, 81, 3) and img.dtype == np.float32
    assert img.min() >= 0.0 and img.max() <= 1.0
    big = abrdf_image(table, scale=3)
    assert big.shape == (243, 243, 3)
    np.testing.assert_array_equal(big[::3, ::3], img)
    np.testing.assert_array_equal(big[2::3, 1::3], img)


def test_tone_mapping_matches_the_metric(rng):
    """The image shows exactly the 8-bit values that RMSE8 compares (PROTOCOL.md items 1-3)."""
    table = rng.gamma(0.5, 0.2, size=(81, 81, 3))
    table[0, :5] = -0.01  # negatives count as 0
    e = exposure_of(table)
    np.testing.assert_allclose(e, float(metrics.expose(table)), rtol=1e-12)
    expected = np.asarray(metrics.srgb_encode(metrics.tonemap(table * e)))
    np.testing.assert_allclose(abrdf_image(table), expected, atol=2e-6)
    assert np.all(abrdf_image(table)[0, :5] == 0.0)


def test_shared_exposure_and_defaults():
    ref = _lambert()
    # e = 0.18 / median luminance: the median pixel maps to Reinhard(0.18) = 0.18/1.18.
    e = exposure_of(ref)
    assert np.isclose(np.median(ref @ LUMA) * e, 0.18)
    assert exposure_of(np.zeros((81, 81, 3))) == 1.0
    # A reconstruction drawn with the reference's exposure: twice as bright is visibly brighter.
    assert np.all(abrdf_image(2 * ref, e) >= abrdf_image(ref, e))
    assert np.mean(abrdf_image(2 * ref, e)) > np.mean(abrdf_image(ref, e)) + 0.05
    # Its own exposure would hide the difference.
    np.testing.assert_allclose(abrdf_image(2 * ref), abrdf_image(ref), atol=1e-6)
    np.testing.assert_allclose(
        metrics.srgb_encode(metrics.tonemap(np.array([[1.0, 0.0, -1.0]])))[0, 1:], 0.0
    )


@pytest.mark.parametrize(
    "bad", [np.zeros((81, 80, 3)), np.zeros((81, 81)), np.full((81, 81, 3), np.nan)]
)
def test_bad_tables_raise(bad):
    with pytest.raises(InputError):
        abrdf_image(bad)
    with pytest.raises(InputError):
        render_sphere(bad, size=8)


# ---------------------------------------------------------------------------------------------
# Interpolation over the UBO grid
# ---------------------------------------------------------------------------------------------


def test_interpolation_is_exact_at_grid_directions(rng):
    table = rng.random((81, 81, 3))
    w = _grid_vectors()
    idx, wgt, above = grid_weights(w)
    assert above.all()
    np.testing.assert_allclose(wgt.sum(-1), 1.0, atol=1e-12)
    k = np.argmax(wgt, axis=-1)
    np.testing.assert_array_equal(idx[np.arange(81), k], np.arange(81))
    np.testing.assert_allclose(wgt.max(-1), 1.0, atol=1e-12)
    out = interpolate_table(table, w[:, None, :], w[None, :, :])
    np.testing.assert_allclose(out, table, atol=1e-12)


def test_interpolation_reproduces_additive_affine_tables(rng):
    """Barycentric weights reproduce affine functions of the projected coordinates; the product
    weights of a pair then reproduce f(wi) + g(wv) for affine f, g (inside the 75-degree ring)."""
    w = _grid_vectors()
    px, py = _projected(w)
    a, b = rng.normal(size=(2, 3, 3))
    f = a[0] + px[:, None] * a[1] / 90 + py[:, None] * a[2] / 90  # (81, 3)
    g = b[0] + px[:, None] * b[1] / 90 + py[:, None] * b[2] / 90
    table = f[:, None, :] + g[None, :, :]
    q = 200
    ti, tv = rng.uniform(0, 70, q), rng.uniform(0, 70, q)
    wi, wv = _vec(ti, rng.uniform(0, 360, q)), _vec(tv, rng.uniform(0, 360, q))
    (xi, yi), (xv, yv) = _projected(wi), _projected(wv)
    expected = (
        a[0]
        + xi[:, None] * a[1] / 90
        + yi[:, None] * a[2] / 90
        + b[0]
        + xv[:, None] * b[1] / 90
        + yv[:, None] * b[2] / 90
    )
    np.testing.assert_allclose(interpolate_table(table, wi, wv), expected, atol=1e-10)


def test_interpolation_is_continuous_bounded_and_zero_below_horizon(rng):
    table = rng.random((81, 81, 3))
    wi = _vec(rng.uniform(0, 89.9, 500), rng.uniform(0, 360, 500))
    wv = _vec(rng.uniform(0, 89.9, 500), rng.uniform(0, 360, 500))
    out = interpolate_table(table, wi, wv)
    assert np.all(out >= 0.0) and np.all(out <= table.max() + 1e-12)
    # A tiny rotation of both directions changes the value only a little.
    rot = np.radians(1e-4)
    c, s = np.cos(rot), np.sin(rot)
    R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    out2 = interpolate_table(table, wi @ R.T, wv @ R.T)
    assert np.max(np.abs(out2 - out)) < 1e-3
    below = _vec(np.full(4, 100.0), np.arange(4) * 90.0)
    assert np.all(interpolate_table(table, below, wv[:4]) == 0.0)
    assert np.all(interpolate_table(table, wi[:4], below) == 0.0)
    # A view at the horizon takes the 75-degree ring's values (nearest-ring extrapolation) ...
    ring75 = np.nonzero(ubo_grid()[0] == 75.0)[0]
    horizon = _vec(np.full(24, 89.999999), ubo_grid()[1][ring75])
    np.testing.assert_allclose(
        interpolate_table(table, _grid_vectors()[:24], horizon),
        table[np.arange(24), ring75],
        atol=1e-6,
    )
    # ... while a light there falls towards 0 (an ABRDF holds cos θi): linearly from the 75°
    # ring, to 1 - (89.2 - 75) / 15 of it at the clamp radius (90° cos(pi / 24) = 89.2°).
    at_horizon = interpolate_table(table, horizon, _grid_vectors()[:24])
    assert np.all(at_horizon <= 0.06 * table[ring75, np.arange(24)] + 1e-12)
    half = _vec(np.full(24, 82.5), ubo_grid()[1][ring75])
    np.testing.assert_allclose(
        interpolate_table(table, half, _grid_vectors()[:24]), 0.5 * table[ring75, np.arange(24)]
    )


# ---------------------------------------------------------------------------------------------
# Lit sphere
# ---------------------------------------------------------------------------------------------


def _pixel(img, u, v):
    """Pixel at image-plane coordinates (u right, v up) in [-1, 1]."""
    n = img.shape[0]
    col = int((u + 1) / 2 * n)
    row = int((1 - v) / 2 * n)
    return img[min(row, n - 1), min(col, n - 1)]


def test_sphere_shape_range_background():
    img = render_sphere(_lambert(), size=64)
    assert img.shape == (64, 64, 3) and img.dtype == np.float32
    assert img.min() >= 0.0 and img.max() <= 1.0
    corner = img[0, 0]
    np.testing.assert_allclose(corner, corner[0])  # grey
    assert 0.3 < corner[0] < 0.6  # mid grey: the unlit (black) part of a sphere stands out
    assert render_sphere(_lambert(), size=10, supersample=1).shape == (10, 10, 3)
    with pytest.raises(InputError):
        render_sphere(_lambert(), size=0)


def test_lambertian_sphere_is_brighter_towards_the_light():
    table = _lambert()
    img = render_sphere(table, light=(45.0, 0.0), size=96, supersample=1)
    lum = img @ LUMA
    # Along the horizontal diameter the normal turns from the light (left) towards it (right):
    # the cosine law makes the brightness rise up to u = sin 45 deg.
    us = np.linspace(-0.6, 0.65, 12)
    profile = np.array([_pixel(lum, u, 0.0) for u in us])
    assert np.all(np.diff(profile) > 0), profile
    # Points facing away from the light are black; the lit side is well lit.
    assert np.all(_pixel(img, -0.9, 0.0) == 0.0)
    assert _pixel(lum, np.sin(np.radians(45)), 0.0) > 0.3
    # Symmetric light and camera: mirror image top/bottom (up to the interpolation's triangles).
    np.testing.assert_allclose(lum, lum[::-1], atol=0.03)
    # Light along +y: the bright side moves to the top.
    up = render_sphere(table, light=(45.0, 90.0), size=96, supersample=1) @ LUMA
    assert _pixel(up, 0.0, 0.6) > _pixel(up, 0.0, -0.6) + 0.2


def test_sphere_radiance_follows_the_cosine_law():
    """Through the tone curve's inverse, the rendered radiance is albedo/pi * cos(n, l)."""
    albedo = np.array([0.5, 0.5, 0.5])
    table = _lambert(albedo)
    e = 1.0
    img = render_sphere(table, light=(0.0, 0.0), size=64, exposure=e, supersample=1)
    t = np.where(img <= 0.04045, img / 12.92, ((img + 0.055) / 1.055) ** 2.4)
    y = t / (1 - t)  # inverse Reinhard
    for u in (0.0, 0.3, 0.6):
        cos = np.sqrt(1 - u * u)
        got = _pixel(y, u, 0.0)[0]
        # Linear interpolation of cos(theta) over the grid: a few percent at most.
        assert abs(got - albedo[0] / np.pi * cos) < 0.03 * albedo[0] / np.pi, (u, got)


def test_sphere_shows_anisotropy_orientation():
    """A table bright only for light along the local x axis: with the light at phi = 0 the
    sphere is lit; with the same light rotated to phi = 90 deg it is dark."""
    w = _grid_vectors()
    along_x = np.abs(w[:, 0]) / np.maximum(np.hypot(w[:, 0], w[:, 1]), 1e-9)
    along_x[0] = 0.0
    table = np.broadcast_to((along_x**8 * w[:, 2])[:, None, None], (81, 81, 3)).copy() + 1e-3
    e = exposure_of(table)
    lit = render_sphere(table, light=(60.0, 0.0), size=48, exposure=e) @ LUMA
    dark = render_sphere(table, light=(60.0, 90.0), size=48, exposure=e) @ LUMA
    assert _pixel(lit, 0.0, 0.0) > 2 * _pixel(dark, 0.0, 0.0)


# ---------------------------------------------------------------------------------------------
# Comparison figure
# ---------------------------------------------------------------------------------------------


def test_comparison_figure_writes_png(tmp_path):
    ref = _lambert()
    m = {"de76": 1.5, "de2000": 1.0, "rmse8": 3.0, "psnr": 38.6, "logerr": 0.01}
    out = comparison_figure(
        [("lambert", ref, ref * 0.9, m), ("same", ref, ref, None)],
        tmp_path / "fig.png",
        sphere_size=48,
    )
    data = (tmp_path / "fig.png").read_bytes()
    assert out == tmp_path / "fig.png"
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 2000
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fig.png"]  # no temporary left


def test_comparison_figure_bad_paths_leave_nothing(tmp_path):
    ref = _lambert()
    rows = [("x", ref, ref, None)]
    with pytest.raises(InputError, match="fig.jpeg"):
        comparison_figure(rows, tmp_path / "fig.jpeg")
    with pytest.raises(InputError, match="missing"):
        comparison_figure(rows, tmp_path / "missing" / "fig.png")
    with pytest.raises(InputError):
        comparison_figure([], tmp_path / "fig.png")
    with pytest.raises(InputError):
        comparison_figure([("bad", ref, ref[:, :10], None)], tmp_path / "fig.png")
    assert list(tmp_path.iterdir()) == []
    # An existing figure survives a failed redraw.
    keep = tmp_path / "keep.png"
    keep.write_bytes(b"old")
    with pytest.raises(InputError):
        comparison_figure([("bad", ref, np.full((81, 81, 3), np.inf), None)], keep)
    assert keep.read_bytes() == b"old"


def test_sphere_of_a_material_is_exact_and_matches_its_table_at_grid_directions():
    """A material draws the sphere from the model itself; where the table interpolation is
    exact (a Lambertian table is linear in cos θi only up to interpolation) both agree, and for
    a sharp specular lobe the exact sphere has a brighter, narrower highlight than the table."""
    from abrdf_jax import materials

    clay = materials.get_material("lambert-clay")
    table = materials.dense_table(clay)
    e = exposure_of(table)
    exact = render_sphere(clay, size=48, exposure=e)
    interp = render_sphere(table, size=48, exposure=e)
    assert np.percentile(np.abs(exact - interp), 99) < 0.03  # cos θi linear between rings
    steel = materials.get_material("ward-brushed-steel")
    t = materials.dense_table(steel)
    e = exposure_of(t)
    peak_exact = (render_sphere(steel, size=64, exposure=e) @ LUMA).max()
    peak_table = (render_sphere(t, size=64, exposure=e) @ LUMA).max()
    assert peak_exact > peak_table
    # the exposure defaults to the material's dense table's
    np.testing.assert_array_equal(
        render_sphere(clay, size=16), render_sphere(clay, size=16, exposure=exposure_of(table))
    )


def test_sphere_of_a_bad_material_is_refused():
    with pytest.raises(InputError, match="shape"):
        render_sphere(lambda wi, wv: np.ones(wi.shape[:-1]), size=8, exposure=1.0)
    with pytest.raises(InputError, match="non-finite"):
        render_sphere(lambda wi, wv: np.full(wi.shape, np.nan), size=8, exposure=1.0)


def test_delta_e76_pairs_is_the_map_of_the_metric(rng):
    ref = rng.gamma(0.5, 0.2, size=(81, 81, 3))
    rec = ref * rng.uniform(0.7, 1.3, size=ref.shape)
    rec[3, 4] = ref[3, 4]  # an exact pair counts 0
    de = np.asarray(metrics.delta_e76_pairs(rec, ref))
    assert de.shape == (81, 81) and de[3, 4] == 0.0 and np.all(de[de != 0] > 0)
    np.testing.assert_allclose(de.mean(), float(metrics.delta_e76(rec, ref)), rtol=1e-6)


def test_comparison_figure_with_a_material_row(tmp_path):
    from abrdf_jax import materials

    clay = materials.get_material("lambert-clay")
    ref = materials.dense_table(clay)
    comparison_figure([("clay", ref, ref * 1.1, None, clay)], tmp_path / "f.png", sphere_size=32)
    assert (tmp_path / "f.png").read_bytes()[:4] == b"\x89PNG"
    with pytest.raises(InputError, match="callable"):
        comparison_figure([("clay", ref, ref, None, "clay")], tmp_path / "g.png")
    with pytest.raises(InputError, match="items"):
        comparison_figure([("clay", ref, ref)], tmp_path / "g.png")
    assert not (tmp_path / "g.png").exists()
