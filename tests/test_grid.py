import jax.numpy as jnp
import numpy as np
import pytest

import abrdf_jax as aj
from abrdf_jax._grid import from_vector, ring_indices, vectors_from_half_diff


def test_ubo_grid_layout():
    theta, phi = aj.ubo_grid()
    assert theta.shape == phi.shape == (81,)
    assert theta[0] == 0 and phi[0] == 0
    np.testing.assert_array_equal(theta[1:7], 15.0)
    np.testing.assert_allclose(phi[1:7], [0, 60, 120, 180, 240, 300])
    np.testing.assert_array_equal(theta[57:], 75.0)
    np.testing.assert_allclose(phi[57:], np.arange(24) * 15.0)
    # sorted by theta, then phi
    order = np.lexsort((phi, theta))
    np.testing.assert_array_equal(order, np.arange(81))
    assert list(ring_indices(30.0)) == list(range(7, 19))


def test_pair_grid_is_illumination_major():
    ti, pi_, tv, pv = aj.pair_grid()
    assert ti.shape == (6561,)
    theta, phi = aj.ubo_grid()
    k = 20 * 81 + 45
    assert (ti[k], pi_[k], tv[k], pv[k]) == (theta[20], phi[20], theta[45], phi[45])


def test_vectors_and_angles_round_trip(rng):
    t = rng.uniform(0, np.pi / 2, 100)
    p = rng.uniform(0, 2 * np.pi, 100)
    w = aj.to_vector(t, p)
    np.testing.assert_allclose(jnp.linalg.norm(w, axis=-1), 1.0, atol=1e-12)
    t2, p2 = from_vector(w)
    np.testing.assert_allclose(t2, t, atol=1e-10)
    np.testing.assert_allclose(p2, p, atol=1e-10)


def test_onion_conventions(rng):
    # the normal maps to (0, 0); x-axis tilt is beta, y-z tilt is alpha
    np.testing.assert_allclose(aj.onion(0.0, 0.0), [0.0, 0.0], atol=1e-15)
    np.testing.assert_allclose(aj.onion(np.pi / 6, 0.0), [0.0, np.pi / 6], atol=1e-12)
    np.testing.assert_allclose(aj.onion(np.pi / 6, np.pi / 2), [np.pi / 6, 0.0], atol=1e-12)
    w = aj.to_vector(rng.uniform(0, np.pi / 2, 50), rng.uniform(0, 2 * np.pi, 50))
    ab = aj.onion_from_vector(w)
    assert np.all(np.abs(ab) <= np.pi / 2 + 1e-12)
    np.testing.assert_allclose(aj.vector_from_onion(ab), w, atol=1e-12)


def test_half_diff_check_value_from_evaluation_md():
    # ../shared/data/merl-nbrdf/EVALUATION.md: w_i = (45, 20), w_o = (60, 230) degrees
    wi = aj.to_vector(np.deg2rad(45.0), np.deg2rad(20.0))
    wo = aj.to_vector(np.deg2rad(60.0), np.deg2rad(230.0))
    th, ph, td, pd = np.rad2deg(np.asarray(aj.half_diff(wi, wo)))
    np.testing.assert_allclose(th, 19.822970, atol=1e-5)
    np.testing.assert_allclose(ph, 360 - 75.657130, atol=1e-5)
    np.testing.assert_allclose(td, 50.091034, atol=1e-5)
    np.testing.assert_allclose(pd, 113.459050, atol=1e-5)


def test_half_diff_round_trip(rng):
    wi = aj.to_vector(rng.uniform(0.05, 1.5, 64), rng.uniform(0, 2 * np.pi, 64))
    wv = aj.to_vector(rng.uniform(0.05, 1.5, 64), rng.uniform(0, 2 * np.pi, 64))
    a, b = vectors_from_half_diff(aj.half_diff(wi, wv))
    np.testing.assert_allclose(a, wi, atol=1e-10)
    np.testing.assert_allclose(b, wv, atol=1e-10)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_azimuths_on_the_seam_and_at_the_poles_are_zero_in_numpy_and_jax(dtype):
    """Directions whose azimuth is 0 up to rounding (a y component of ±1e-17), and the half
    and difference vectors at their poles (mirror pairs, ``wi = wv``), get the azimuth 0 in
    numpy and in JAX, never 2π or ``atan2`` of rounding noise."""
    import jax.numpy as jnp

    from abrdf_jax._grid import from_vector, half_diff, to_vector

    w = np.array([[0.5, -1e-17, 0.866], [0.5, 1e-17, 0.866], [0.5, -1e-9, 0.866]], dtype)
    for xp in (np, jnp):
        phi = np.asarray(from_vector(xp.asarray(w), xp)[1])
        assert phi[0] == 0 and phi[1] == pytest.approx(0, abs=1e-16)
        assert 0 <= phi[2] < 2 * np.pi
    ti = np.deg2rad(30.0)
    wi = to_vector(np.array([ti, ti]), np.array([0.7, 0.7]), np).astype(dtype)
    wv = np.stack([wi[0], to_vector(np.array(ti), np.array(0.7 + np.pi), np)]).astype(dtype)
    for xp in (np, jnp):
        hd = np.asarray(half_diff(xp.asarray(wi), xp.asarray(wv), xp))
        assert hd[0, 3] == 0  # wi = wv: d at its pole, φd = 0
        assert hd[1, 1] == 0  # mirror pair about the normal: h at its pole, φh = 0


def test_onion_hd_is_onion_plus_the_half_vector_angles(rng):
    """The first four coordinates of ``"onion-hd"`` are the onion ones; the last two are
    ``√(θh π/2)`` and ``θd`` of the half vector, against their textbook formulas in float64
    (``θh = arccos h_z``, ``θd = arccos(wi · h)``, ``h`` the normalised sum), in numpy and JAX."""
    wi = aj.to_vector(rng.uniform(0.05, 1.5, 64), rng.uniform(0, 2 * np.pi, 64), np)
    wv = aj.to_vector(rng.uniform(0.05, 1.5, 64), rng.uniform(0, 2 * np.pi, 64), np)
    h = (wi + wv) / np.linalg.norm(wi + wv, axis=-1, keepdims=True)
    want = np.sqrt(np.arccos(h[:, 2]) * np.pi / 2), np.arccos(np.sum(wi * h, axis=-1))
    for xp in (np, jnp):
        x = np.asarray(aj.pair_coordinates(xp.asarray(wi), xp.asarray(wv), "onion-hd", xp))
        assert x.shape == (64, 6)
        onion = np.asarray(aj.pair_coordinates(xp.asarray(wi), xp.asarray(wv), "onion", xp))
        np.testing.assert_array_equal(x[:, :4], onion)
        np.testing.assert_allclose(x[:, 4], want[0], atol=1e-9)
        np.testing.assert_allclose(x[:, 5], want[1], atol=1e-9)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_half_diff_elevations_are_accurate_near_the_poles(dtype):
    """``θh`` and ``θd`` a few 1e-4 rad from their poles, in float32 as in float64: by atan2
    of the sine and cosine parts (arccos of a cosine near 1 loses them: in float32 it gives
    3e-4 for an exact mirror pair)."""
    for delta in (0.0, 1e-4, 5e-4, 2e-3):
        wi = aj.to_vector(np.asarray(0.6 + delta), np.asarray(0.0), np).astype(dtype)
        wv = aj.to_vector(np.asarray(0.6 - delta), np.asarray(np.pi), np).astype(dtype)
        for xp in (np, jnp):
            th = float(aj.half_diff(xp.asarray(wi), xp.asarray(wv), xp)[0])
            assert th == pytest.approx(delta, abs=2e-6 if dtype == np.float32 else 1e-12)
            td = float(aj.half_diff(xp.asarray(wi), xp.asarray(wi), xp)[2])  # wi = wv
            assert td == pytest.approx(0.0, abs=1e-6 if dtype == np.float32 else 1e-12)


@pytest.mark.parametrize("dtype", [np.float32, np.float64])
def test_onion_hd_is_accurate_and_differentiable_at_the_mirror_and_retro_pairs(dtype):
    """At a mirror pair (θh = 0) the warped θh is 0 to rounding even in float32 (arccos of
    the half vector's z would put it near 0.02 there), at ``wi = wv`` θd is 0, and the
    gradient with respect to the angles is finite at both."""
    import jax

    from abrdf_jax._grid import to_vector

    def coords(angles):
        ti, pi_, tv, pv = angles
        wi, wv = to_vector(ti, pi_)[None], to_vector(tv, pv)[None]
        return aj.pair_coordinates(wi, wv, "onion-hd")[0]

    mirror = jnp.asarray([0.5, 0.7, 0.5, 0.7 + np.pi], dtype)
    retro = jnp.asarray([0.5, 0.7, 0.5, 0.7], dtype)
    tol = 10 * np.finfo(dtype).eps ** 0.5
    assert abs(float(coords(mirror)[4])) < tol
    assert abs(float(coords(retro)[5])) < tol
    for angles in (mirror, retro):
        g = np.asarray(jax.jacfwd(coords)(angles))
        assert np.all(np.isfinite(g))


def test_coordinate_widths_extend_four_widths_by_their_geometric_mean():
    from abrdf_jax._rbf_system import coordinate_widths

    w = np.array([0.5, 1.0, 2.0, 4.0])
    np.testing.assert_allclose(coordinate_widths(w, 6, np), [*w, 2**0.5, 2**0.5])
    np.testing.assert_array_equal(coordinate_widths(w, 4, np), w)
    np.testing.assert_array_equal(coordinate_widths(np.asarray(0.3), 6, np), [0.3] * 6)
    with pytest.raises(ValueError):
        coordinate_widths(np.ones(3), 6, np)  # neither a scalar, (d,) nor (4,)
