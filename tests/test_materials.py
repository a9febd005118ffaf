"""Ground-truth materials: the merl-nbrdf evaluator against the shared reference values, and the
analytic / procedural models against their defining properties (float64, see conftest)."""

import math
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import abrdf_jax.materials as M
from abrdf_jax._errors import InputError
from abrdf_jax._grid import pair_grid, to_vector, ubo_grid

REPO = Path(__file__).resolve().parents[1]


def vec(theta_deg, phi_deg):
    return to_vector(
        jnp.deg2rad(jnp.asarray(theta_deg, float)), jnp.deg2rad(jnp.asarray(phi_deg, float))
    )


# One batch size for the random directions of all tests (= 81 x 81), so that every model
# structure compiles once and the cache serves the other tests.
N = 6561


def hemisphere(rng, n=N, zmin=0.02):
    z = rng.uniform(zmin, 1.0, n)
    phi = rng.uniform(0, 2 * np.pi, n)
    s = np.sqrt(1 - z * z)
    return jnp.asarray(np.stack([s * np.cos(phi), s * np.sin(phi), z], -1))


def rotate_z(w, a):
    c, s = jnp.cos(a), jnp.sin(a)
    return jnp.stack([c * w[..., 0] - s * w[..., 1], s * w[..., 0] + c * w[..., 1], w[..., 2]], -1)


@eqx.filter_jit
def all_grads(m, wi, wv):
    """Gradients of sum(m(wi, wv)) w.r.t. the parameters and both directions (one compile)."""
    return eqx.filter_grad(lambda args: args[0](args[1], args[2]).sum())((m, wi, wv))


def all_finite(tree):
    leaves = jax.tree_util.tree_leaves(tree)
    return bool(leaves) and all(np.all(np.isfinite(x)) for x in leaves)


def special_pairs():
    """Awkward configurations: normal/normal, mirror, retro, grazing, below horizon, wi = -wv."""
    e = 1e-9
    g = math.sqrt(1 - e * e)
    rows = [
        ([0, 0, 1], [0, 0, 1]),
        (vec(30, 0), vec(30, 180)),
        (vec(60, 45), vec(60, 45)),
        ([g, 0, e], [-g, 0, e]),  # grazing, retro-opposite
        ([g, 0, e], [g, 0, e]),  # grazing, coincident
        ([1, 0, 0], [0, 0, 1]),  # exactly on the horizon
        ([0, 0, 1], [0, 1, 0]),
        (vec(45, 10), [0.6, 0, -0.8]),  # view below the horizon
        ([0.6, 0, 0.8], [-0.6, 0, -0.8]),  # wi = -wv
        (vec(75, 300), vec(15, 20)),
    ]
    wi = jnp.stack([jnp.asarray(a, float) for a, _ in rows])
    wv = jnp.stack([jnp.asarray(b, float) for _, b in rows])
    return wi, wv


# ---------------------------------------------------------------------------------------------
# merl-nbrdf
# ---------------------------------------------------------------------------------------------

CHECK_BRDF = [
    ("white-diffuse-bball", (0, 0, 0, 0), (0.143788, 0.127724, 0.101381)),
    ("white-diffuse-bball", (60, 0, 30, 90), (0.102572, 0.0862459, 0.0573567)),
    ("gold-paint", (45, 20, 60, 230), (0.110871, 0.073618, 0.034233)),
    ("gold-paint", (30, 0, 30, 180), (0.328866, 0.234693, 0.130317)),
    ("chrome", (45, 0, 45, 180), (735.162, 872.11, 881.951)),
    ("blue-acrylic", (75, 180, 60, 0), (0.172371, 0.166389, 0.197681)),
    ("cardboard", (30, 30, 75, 180), (0.131569, 0.105185, 0.0853691)),
    ("red-fabric", (15, 300, 60, 45), (0.070207, 0.0101976, 0.00431941)),
]

CHECK_TABLE = [
    ("gold-paint", 0, 0, (0.350799, 0.246771, 0.134453)),
    ("gold-paint", 20, 45, (0.0466418, 0.0277025, 0.0117963)),
    ("chrome", 9, 25, (0.000480002, 0.000389108, 0.000440039)),
    ("cardboard", 80, 5, (0.028301, 0.0218087, 0.0170974)),
    ("blue-acrylic", 69, 37, (0.0446129, 0.0430645, 0.0511637)),
]


def test_default_data_dir(monkeypatch, tmp_path):
    here = Path(M.__file__).resolve()
    assert here.parents[2] == REPO  # abrdf_jax/materials/__init__.py -> repository root
    monkeypatch.delenv("ABRDF_DATA", raising=False)
    default = REPO.parent / "shared" / "data"
    if default.is_dir():
        assert M.default_data_dir() == default
    missing = tmp_path / "nowhere"
    monkeypatch.setenv("ABRDF_DATA", str(missing))
    with pytest.raises(M.DataNotFoundError) as err:
        M.default_data_dir()
    assert isinstance(err.value, InputError) and isinstance(err.value, FileNotFoundError)
    assert str(missing) in str(err.value) and "ABRDF_DATA" in str(err.value)
    with pytest.raises(InputError, match="tables81.npz"):
        M.load_tables81(tmp_path)


@pytest.mark.parametrize("name, angles, ref", CHECK_BRDF)
def test_nbrdf_check_values(data_dir, name, angles, ref):
    m = M.load_nbrdf(name, data_dir)
    f = m.brdf(vec(*angles[:2]), vec(*angles[2:]))
    np.testing.assert_allclose(f, ref, rtol=2e-5)
    abrdf = m(vec(*angles[:2]), vec(*angles[2:]))
    np.testing.assert_allclose(
        abrdf, np.asarray(ref) * math.cos(math.radians(angles[0])), rtol=2e-5
    )


def test_nbrdf_input_vector():
    x = jax.jit(M.nbrdf_input)(vec(45, 20), vec(60, 230))
    np.testing.assert_allclose(x, [0.339115, 0, 0.940745, -0.305364, 0.703663, 0.641570], atol=2e-6)


@pytest.mark.parametrize("name, i, v, ref", CHECK_TABLE)
def test_nbrdf_table_entries(data_dir, name, i, v, ref):
    theta, phi = ubo_grid()
    m = M.load_nbrdf(name, data_dir)
    got = m(vec(theta[i], phi[i]), vec(theta[v], phi[v]))
    np.testing.assert_allclose(got, ref, rtol=2e-5)
    t = M.load_tables81(data_dir)
    k = list(t["names"]).index(name)
    np.testing.assert_allclose(t["abrdf"][k, i, v], ref, rtol=2e-5)


@pytest.fixture(scope="module")
def nbrdf_stack(data_dir):
    return M.stack_nbrdf(M.load_nbrdf_all(data_dir=data_dir))


def _all_tables(stack, dtype):
    ti, pi, tv, pv = (np.deg2rad(a) for a in pair_grid())
    wi = to_vector(jnp.asarray(ti, dtype), jnp.asarray(pi, dtype))
    wv = to_vector(jnp.asarray(tv, dtype), jnp.asarray(pv, dtype))
    out = jax.jit(jax.vmap(lambda m: m(wi, wv)))(stack)
    assert out.dtype == dtype and out.shape == (108, 6561, 3)
    return np.asarray(out, np.float64).reshape(108, 81, 81, 3)


def test_nbrdf_all_tables_float64(data_dir, nbrdf_stack):
    t = M.load_tables81(data_dir)
    assert list(t["names"]) == M.nbrdf_names(data_dir) == sorted(t["names"])
    assert nbrdf_stack.name.split(",") == list(t["names"])
    ours = _all_tables(nbrdf_stack, jnp.float64)
    ref = t["abrdf"].astype(np.float64)
    # The tables are float64 results stored as float32: agreement to float32 rounding.
    np.testing.assert_allclose(ours, ref, rtol=3e-7, atol=1e-30)
    # dense_table of a single network goes through the same code.
    k = list(t["names"]).index("gold-paint")
    np.testing.assert_allclose(
        M.dense_table(M.load_nbrdf("gold-paint", data_dir), np.float64), ref[k], rtol=3e-7
    )


def test_nbrdf_all_tables_float32(data_dir, nbrdf_stack):
    t = M.load_tables81(data_dir)
    ours = _all_tables(nbrdf_stack, jnp.float32)
    ref = t["abrdf"].astype(np.float64)
    scale = ref.max(axis=(1, 2, 3), keepdims=True)
    err = np.abs(ours - ref) / np.maximum(ref, 1e-3 * scale)
    assert err.max() < 1e-3
    assert np.median(np.abs(ours - ref) / np.maximum(ref, 1e-30)) < 1e-5


def test_merl_split(data_dir):
    train, test = M.merl_split("train", data_dir), M.merl_split("test", data_dir)
    names = sorted(M.load_tables81(data_dir)["names"])
    assert len(train) == len(test) == 54
    assert train == names[0::2] and test == names[1::2]
    with pytest.raises(InputError, match="train"):
        M.merl_split("validation", data_dir)


def test_nbrdf_errors(data_dir, nbrdf_stack):
    with pytest.raises(InputError, match="gold-paint"):
        M.load_nbrdf("gold-pant", data_dir)
    with pytest.raises(InputError, match="vmap"):
        nbrdf_stack(vec(0, 0), vec(0, 0))
    with pytest.raises(InputError):
        M.stack_nbrdf([])
    with pytest.raises(InputError, match=r"\(\.\.\., 3\)"):
        M.load_nbrdf("gold-paint", data_dir)(jnp.ones((4, 2)), jnp.ones((4, 3)))


def test_nbrdf_symmetries_and_gradients(data_dir, rng):
    m = M.load_nbrdf("gold-paint", data_dir)
    wi, wv = hemisphere(rng), hemisphere(rng)
    a = m(wi, wv)
    # Isotropic: rotating both azimuths changes nothing; reciprocal: f(wi, wv) = f(wv, wi).
    np.testing.assert_allclose(m(rotate_z(wi, 1.1), rotate_z(wv, 1.1)), a, rtol=1e-9)
    np.testing.assert_allclose(m(wv, wi) / wv[:, 2:], a / wi[:, 2:], rtol=1e-9)
    si, sv = special_pairs()
    vals = m(si, sv)
    assert np.all(np.isfinite(vals)) and np.all(vals >= 0)
    assert np.all(vals[~((si[:, 2] > 0) & (sv[:, 2] > 0))] == 0)
    grads = all_grads(m, si, sv)
    assert all_finite(grads) and np.abs(grads[1]).sum() > 0


def test_registry_nbrdf(data_dir):
    m = M.get_material("nbrdf:gold-paint", data_dir=data_dir)
    assert isinstance(m, M.NeuralBRDF) and m.name == "gold-paint"
    info = M.material_info("nbrdf:gold-paint")
    assert info["isotropic"] and info["reciprocal"]
    with pytest.raises(InputError):
        M.get_material("nbrdf:no-such-material", data_dir=data_dir)


# ---------------------------------------------------------------------------------------------
# analytic and procedural models
# ---------------------------------------------------------------------------------------------

RGB = jnp.array([0.5, 0.3, 0.2])


def make_models():
    return {
        "lambert": M.Lambertian(RGB),
        "ward": M.Ward(RGB, jnp.array([0.2, 0.25, 0.3]), 0.1, 0.3, rotation=0.3),
        "ashikhmin": M.AshikhminShirley(RGB, jnp.array([0.05, 0.06, 0.07]), 10.0, 200.0, 0.3),
        "ggx": M.GGX(RGB, jnp.array([0.04, 0.5, 0.9]), 0.15, 0.4, rotation=0.3),
        "rough": M.RoughStructured(RGB, rotation=0.3),
    }


RECIPROCAL = ["lambert", "ward", "ashikhmin", "ggx"]


@pytest.mark.parametrize("name", list(make_models()))
def test_values_and_gradients_finite(name, rng):
    m = make_models()[name]
    wi, wv = hemisphere(rng, N - 10, zmin=1e-3), hemisphere(rng, N - 10, zmin=1e-3)
    si, sv = special_pairs()
    wi, wv = jnp.concatenate([wi, si]), jnp.concatenate([wv, sv])
    val = m(wi, wv)
    assert val.shape == (wi.shape[0], 3)
    assert np.all(np.isfinite(val)) and np.all(val >= 0)
    valid = (wi[:, 2] > 0) & (wv[:, 2] > 0)
    assert np.all(val[~valid] == 0) and np.all(val[valid].sum(-1) > 0)
    # Below the horizon on either side: zero.
    flip = jnp.array([1.0, 1.0, -1.0])
    up = valid[:, None]
    assert np.all(m(wi * flip, wv)[valid] == 0) and np.all(m(wi, wv * flip)[valid] == 0)
    assert up.sum() >= N - 10
    grads = all_grads(m, wi, wv)
    assert all_finite(grads)
    assert np.abs(grads[1]).sum() > 0 and (name == "lambert" or np.abs(grads[2]).sum() > 0)
    # Gradients also at the parameter floors / degenerate settings (same structure: no recompile).
    if name == "ggx":
        assert all_finite(all_grads(eqx.tree_at(lambda q: q.alpha_x, m, jnp.asarray(0.0)), wi, wv))
    if name == "rough":
        flat = eqx.tree_at(
            lambda q: (q.groove_slope, q.fill), m, (jnp.asarray(0.0), jnp.asarray(0.0))
        )
        assert all_finite(all_grads(flat, wi, wv))


@pytest.mark.parametrize("name", list(make_models()))
def test_dtype_jit_vmap(name, rng):
    m = make_models()[name]
    wi, wv = hemisphere(rng), hemisphere(rng)
    out32 = m(wi.astype(jnp.float32), wv.astype(jnp.float32))
    out64 = m(wi, wv)
    assert out32.dtype == jnp.float32 and out64.dtype == jnp.float64
    np.testing.assert_allclose(out32, out64, rtol=2e-3, atol=1e-6)
    # One direction pair broadcast against many; vmap over directions equals the batch.
    # One direction broadcast against many equals the explicit broadcast.
    np.testing.assert_allclose(m(wi[0], wv), m(jnp.broadcast_to(wi[0], wv.shape), wv), rtol=1e-14)
    if name != "rough":  # (compile time; the code path is the same)
        np.testing.assert_allclose(jax.jit(jax.vmap(m))(wi, wv), out64, rtol=1e-12)


def test_vmap_over_parameters(rng):
    wi, wv = hemisphere(rng), hemisphere(rng)
    alphas = jnp.array([0.1, 0.2, 0.4])
    # Parameters are traced: a model built inside vmap/jit from traced values works.
    batched = jax.jit(jax.vmap(lambda ax, ay: M.GGX(RGB, 0.5, ax, ay)(wi, wv)))(
        alphas, alphas[::-1]
    )
    for k in range(3):
        np.testing.assert_allclose(
            batched[k], M.GGX(RGB, 0.5, alphas[k], alphas[2 - k])(wi, wv), rtol=1e-12
        )
    # A module with a leading parameter axis, vmapped over that axis.
    stacked = M.Ward(RGB, 0.3, alphas, alphas[::-1])
    axes = eqx.tree_at(
        lambda q: (q.diffuse, q.specular, q.alpha_x, q.alpha_y, q.rotation),
        jax.tree_util.tree_map(lambda _: None, stacked),
        (None, None, 0, 0, None),
        is_leaf=lambda x: x is None,
    )
    out = eqx.filter_jit(eqx.filter_vmap(lambda mm: mm(wi, wv), in_axes=(axes,)))(stacked)
    np.testing.assert_allclose(out[1], M.Ward(RGB, 0.3, 0.2, 0.2)(wi, wv), rtol=1e-12)


def test_lambertian_formula(rng):
    wi, wv = hemisphere(rng), hemisphere(rng)
    np.testing.assert_allclose(M.Lambertian(RGB)(wi, wv), RGB / np.pi * wi[:, 2:], rtol=1e-14)
    assert M.Lambertian(0.5)(wi, wv).shape == (N, 3)


@pytest.mark.parametrize("name", RECIPROCAL)
def test_reciprocity(name, rng):
    m = make_models()[name]
    wi, wv = hemisphere(rng), hemisphere(rng)
    np.testing.assert_allclose(m(wi, wv) / wi[:, 2:], m(wv, wi) / wv[:, 2:], rtol=1e-10)


def _rough_grid_pairs():
    ti, pi, tv, pv = (np.deg2rad(a) for a in pair_grid())
    return to_vector(jnp.asarray(ti), jnp.asarray(pi)), to_vector(jnp.asarray(tv), jnp.asarray(pv))


def test_rough_structured_not_reciprocal():
    wi, wv = _rough_grid_pairs()
    m = M.RoughStructured(RGB)  # defaults (the registry test covers the named ones)
    a, b = m(wi, wv) / wi[:, 2:], m(wv, wi) / wv[:, 2:]
    assert (np.abs(a - b) / np.maximum(a, b)).max() > 0.05
    # Each non-reciprocal ingredient alone breaks reciprocity; without any of them it holds.
    base = dict(diffuse=RGB, specular_f0=0.3, roughness=0.25, groove_slope=0.6)
    recip = M.RoughStructured(
        **base, fill=0.0, forward=0.0, shadow_sharpness=6.0, mask_sharpness=6.0
    )
    np.testing.assert_allclose(recip(wi, wv) / wi[:, 2:], recip(wv, wi) / wv[:, 2:], rtol=1e-10)
    filled = eqx.tree_at(lambda q: q.fill, recip, jnp.asarray(0.4))
    np.testing.assert_allclose(filled(wi, wv) / wi[:, 2:], filled(wv, wi) / wv[:, 2:], rtol=1e-10)
    for change in (dict(forward=0.3), dict(shadow_sharpness=2.0)):
        m = eqx.tree_at(
            lambda q: tuple(getattr(q, k) for k in change),
            recip,
            tuple(jnp.asarray(v) for v in change.values()),
        )
        a, b = m(wi, wv) / wi[:, 2:], m(wv, wi) / wv[:, 2:]
        # (pairs where the lit facet is hidden from the view are black both ways without fill)
        assert (np.abs(a - b) / np.maximum(np.maximum(a, b), 1e-12)).max() > 0.02, change


def test_rough_structured_limits(rng):
    wi, wv = hemisphere(rng), hemisphere(rng)
    # A flat surface (no grooves, no forward lobe) is the isotropic GGX model with a Lambertian base.
    flat = M.RoughStructured(
        RGB,
        specular_f0=0.3,
        roughness=0.2,
        groove_slope=0.0,
        fill=0.5,
        forward=0.0,
        shadow_sharpness=60.0,
        mask_sharpness=60.0,
    )
    np.testing.assert_allclose(flat(wi, wv), M.GGX(RGB, 0.3, 0.2, 0.2)(wi, wv), rtol=1e-12)
    # With fill = 1 the diffuse layer sees cos(g) cos(theta_i) on both facets (no shadows).
    g = 0.5
    full = M.RoughStructured(RGB, groove_slope=g, fill=1.0, forward=0.0)
    glossy = M.RoughStructured(0.0, groove_slope=g, fill=1.0, forward=0.0)
    np.testing.assert_allclose(
        full(wi, wv) - glossy(wi, wv), RGB / np.pi * np.cos(g) * wi[:, 2:], rtol=1e-10
    )
    # The forward lobe is a von Mises-Fisher term added on top.
    fwd = eqx.tree_at(lambda q: q.forward, full, jnp.asarray(0.2))
    axis = np.asarray(M.RoughStructured(0.0).forward_lift)
    c = np.stack([-wi[:, 0], -wi[:, 1], np.full(len(wi), axis)], -1)
    c /= np.linalg.norm(c, axis=-1, keepdims=True)
    k = 4.0
    lobe = 0.2 * wi[:, 2] * k / (2 * np.pi) * np.exp(k * (np.sum(c * wv, -1) - 1))
    np.testing.assert_allclose(
        fwd(wi, wv) - full(wi, wv), np.repeat(lobe[:, None], 3, 1), rtol=1e-10
    )


ISO = {
    "lambert": M.Lambertian(RGB),
    "ward": M.Ward(RGB, 0.3, 0.2, 0.2, rotation=0.4),
    "ashikhmin": M.AshikhminShirley(RGB, 0.05, 50.0, 50.0),
    "ggx": M.GGX(RGB, 0.2, 0.25, 0.25, rotation=1.0),
}


@pytest.mark.parametrize("name", list(ISO))
def test_isotropic_invariance(name, rng):
    m = ISO[name]
    wi, wv = hemisphere(rng), hemisphere(rng)
    for a in (0.3, 2.0):
        np.testing.assert_allclose(m(rotate_z(wi, a), rotate_z(wv, a)), m(wi, wv), rtol=1e-10)


@pytest.mark.parametrize("name", ["ward", "ashikhmin", "ggx", "rough"])
def test_anisotropic_not_invariant(name, rng):
    m = make_models()[name]
    wi, wv = hemisphere(rng), hemisphere(rng)
    a = m(wi, wv)
    b = m(rotate_z(wi, 0.7), rotate_z(wv, 0.7))
    assert (np.abs(a - b) / np.maximum(a, b)).max() > 0.1
    # ... while rotating the directions and the tangent frame together changes nothing.
    turned = eqx.tree_at(lambda q: q.rotation, m, m.rotation + 0.7)
    np.testing.assert_allclose(turned(rotate_z(wi, 0.7), rotate_z(wv, 0.7)), a, rtol=1e-10)


@pytest.mark.parametrize(
    "cls, swap",
    [
        (M.Ward, ("alpha_x", "alpha_y")),
        (M.GGX, ("alpha_x", "alpha_y")),
        (M.AshikhminShirley, ("n_u", "n_v")),
    ],
)
def test_rotation_quarter_turn_swaps_axes(cls, swap, rng):
    wi, wv = hemisphere(rng), hemisphere(rng)
    x, y = (0.1, 0.35) if cls is not M.AshikhminShirley else (15.0, 150.0)
    base = cls(RGB, 0.3, x, y)
    turned = cls(RGB, 0.3, y, x, rotation=np.pi / 2)
    np.testing.assert_allclose(turned(wi, wv), base(wi, wv), rtol=1e-10)
    assert getattr(base, swap[0]) == getattr(turned, swap[1])


def directional_albedo(m, wv, n=128):
    """∫ ABRDF(wi, wv) dωi over the hemisphere: midpoint rule in (cos θ, φ)."""
    mu = (jnp.arange(n) + 0.5) / n
    phi = (jnp.arange(2 * n) + 0.5) / (2 * n) * 2 * jnp.pi
    mu, phi = jnp.meshgrid(mu, phi, indexing="ij")
    s = jnp.sqrt(1 - mu**2)
    wi = jnp.stack([s * jnp.cos(phi), s * jnp.sin(phi), mu], -1).reshape(-1, 3)
    return m(wi, wv).mean(0) * 2 * jnp.pi


def test_energy():
    views = [vec(0, 0), vec(45, 30), vec(75, 100)]
    lam = M.Lambertian(RGB)
    for wv in views:
        np.testing.assert_allclose(directional_albedo(lam, wv), RGB, rtol=1e-3)
    ward = M.Ward(0.0, 1.0, 0.2, 0.35)
    ggx = M.GGX(0.0, 1.0, 0.2, 0.35)
    for wv in views:
        for m in (ward, ggx):
            a = np.asarray(directional_albedo(m, wv))
            assert 0.5 < a.max() <= 1.01, (type(m).__name__, a)


# ---------------------------------------------------------------------------------------------
# registry
# ---------------------------------------------------------------------------------------------


def test_registry_names_and_info():
    names = M.material_names()
    mats = M.default_materials()
    assert list(mats) == names and len(names) == 8
    for n in names:
        info = M.material_info(n)
        assert set(info) >= {"isotropic", "reciprocal", "description"}
        assert M.is_anisotropic(n) == (not info["isotropic"])
        assert type(M.get_material(n)) is type(mats[n])
    assert not M.material_info("rough-fabric")["reciprocal"]
    assert M.material_info("ggx-plastic")["isotropic"]
    with pytest.raises(InputError) as err:
        M.get_material("lambert-cly")
    assert all(n in str(err.value) for n in names)
    with pytest.raises(InputError):
        M.material_info("nope")


@pytest.mark.parametrize("name", M.material_names())
def test_registry_materials_behave_as_declared(name, rng):
    m = M.get_material(name)
    info = M.material_info(name)
    t = M.dense_table(m, np.float64)
    assert t.shape == (81, 81, 3) and t.dtype == np.float64
    assert np.all(np.isfinite(t)) and t.min() > 0
    assert 0.002 < np.median(t) < 1.0 and t.max() < 60
    wi, wv = hemisphere(rng, zmin=0.1), hemisphere(rng, zmin=0.1)
    a = m(wi, wv)
    rot = m(rotate_z(wi, 0.9), rotate_z(wv, 0.9))
    assert (
        np.abs(rot - a).max() / a.max() < 1e-9
        if info["isotropic"]
        else np.abs(rot - a).max() / a.max() > 0.01
    )
    rec = np.abs(m(wv, wi) / wv[:, 2:] - a / wi[:, 2:]) / (a / wi[:, 2:])
    assert rec.max() < 1e-9 if info["reciprocal"] else rec.max() > 0.05


def test_dense_table_convention():
    m = M.Lambertian(RGB)
    t = M.dense_table(m)
    assert t.shape == (81, 81, 3) and t.dtype == np.float32
    theta, phi = ubo_grid()
    # Row = illumination: each row is constant over the views and scales with cos(theta_i).
    np.testing.assert_allclose(t, t[:, :1, :].repeat(81, 1), rtol=1e-6)
    np.testing.assert_allclose(
        t[:, 0, :], np.cos(np.deg2rad(theta))[:, None] * RGB / np.pi, rtol=1e-6
    )
    # The same by name, and for an asymmetric material table[i, v] = material(w_i, w_v).
    np.testing.assert_allclose(
        M.dense_table("lambert-clay"), M.dense_table(M.get_material("lambert-clay"))
    )
    g = M.get_material("rough-grooves")
    t64 = M.dense_table(g, np.float64)
    i, v = 57, 3
    np.testing.assert_allclose(
        t64[i, v], g(vec(theta[i], phi[i]), vec(theta[v], phi[v])), rtol=1e-12
    )
    assert not np.allclose(
        t64[i, v], t64[v, i] * np.cos(np.deg2rad(theta[i])) / np.cos(np.deg2rad(theta[v]))
    )
