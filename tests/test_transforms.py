"""The public entry points under JAX's transforms: jit, vmap, grad, and no retrace for new values.

For :func:`abrdf_jax.reconstruct` (grouped :class:`Measurements`), :func:`abrdf_jax.reconstruct_batch`,
a :func:`abrdf_jax.compile_operator` call and :func:`abrdf_jax.sample` with ``as_measurements=True``:

- jit equals eager (``jax.disable_jit()``),
- vmap equals a Python loop,
- ``jax.grad`` in the :class:`Params` (α, widths, λ) is finite and equals central differences,
- new values, new parameters and an equal new :class:`Config` of the same shapes and dtypes are
  not traced again (counted with ``jax.monitoring``'s trace and compile events, and the
  operator's own ``TRACE_COUNT``).

float64 throughout (conftest). Kept cheap for CI (about a minute on two cores): the measurements
cover two small elevation pairs (108 RBF centres instead of PROTOCOL.md's 1296), the
reconstructions are evaluated at a few dozen direction pairs (``targets``: the same code path as
the 6561 of the table), and only one reconstruction runs eagerly (an eager first run compiles
every primitive on its own: ~15 s). The full-size pipeline is checked in ``test_pipeline.py`` and
``test_operator.py``.
"""

import contextlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import abrdf_jax as aj
from abrdf_jax._operator import TRACE_COUNT

Q = 24  # target pairs of most tests (the trace test uses its own count, for a fresh compile)


def model(wi, wv, scale=1.0):
    """A smooth anisotropic material: a glossy lobe around the mirror direction, RGB-tinted."""
    r = jnp.stack([-wi[..., 0], -wi[..., 1], wi[..., 2]], -1)
    c = jnp.sum(r * wv, -1, keepdims=True)
    lobe = jnp.exp(3.0 * (c - 1.0)) * (1.0 + 0.3 * wi[..., :1] * wv[..., :1])
    base = scale * (0.2 + 0.5 * lobe) * wi[..., 2:3]
    return jnp.concatenate([base, 0.8 * base, 0.6 * base], -1)


def _targets(q, seed=7):
    rng = np.random.default_rng(seed)
    return tuple(
        aj.to_vector(
            jnp.asarray(rng.uniform(0.1, 1.3, q)), jnp.asarray(rng.uniform(0.0, 2 * np.pi, q))
        )
        for _ in range(2)
    )


TARGETS = _targets(Q)
SMALL_PAIRS = ((15.0, 15.0), (30.0, 15.0))  # UBO rings of 6 and 12 azimuths: 108 RBF centres
SMALL = {"pairs": SMALL_PAIRS, "slice_count": 12}
CONFIGS = {
    # the paper's method: Gaussian kernel, linear values, Cholesky, eq. (5)
    "iso-paper": aj.Config(budget="iso102", **SMALL),
    # the recommendation on anisotropic data: TPS with a linear tail (LU), log values, eq. (2-4)
    "aniso-recommended": aj.preset("recommended", "aniso204", **SMALL),
}
# α for the gradient checks. At the protocol's 15° the RBF centres' subspace queries fall on the
# slices' sample positions (multiples of 7.5° against knots at multiples of 15°), where linear
# slice interpolation has a kink: there jax.grad is one of the one-sided derivatives and a central
# difference their mean. Off the knots both agree.
ALPHA_DEG = 13.3


def _measure(cfg, params, scale=1.0):
    return aj.sample(lambda wi, wv: model(wi, wv, scale), cfg, params, as_measurements=True)


def _stack(cfg, params, scales=(1.0, 0.5, 2.0)):
    return aj.stack_measurements([_measure(cfg, params, s) for s in scales])


def _close(a, b, rtol=1e-9):
    a, b = np.asarray(a), np.asarray(b)
    np.testing.assert_allclose(a, b, rtol=rtol, atol=rtol * float(np.max(np.abs(b))))


# --- trace counting -------------------------------------------------------------------------

_EVENTS = ("/jax/core/compile/jaxpr_trace_duration", "/jax/core/compile/backend_compile_duration")
_SEEN: list[list[str]] = []  # the open counters


def _listener(event, *args, **kwargs):
    if event in _EVENTS:
        for seen in _SEEN:
            seen.append(event)


jax.monitoring.register_event_duration_secs_listener(
    _listener
)  # once per session; idle when closed


@contextlib.contextmanager
def traces():
    """The list of trace and compile events (any function, any jit) recorded inside the block."""
    seen: list[str] = []
    _SEEN.append(seen)
    try:
        yield seen
    finally:
        _SEEN.remove(seen)


# --- reconstruct and reconstruct_batch -------------------------------------------------------


def _members(stacked):
    return [
        jax.tree_util.tree_map(lambda x, k=k: x[k], stacked) for k in range(stacked.count.shape[0])
    ]


def test_reconstruct_jit_equals_eager():
    cfg = CONFIGS["aniso-recommended"]
    p = aj.Params.default(cfg)
    meas = _measure(cfg, p)
    jitted = aj.reconstruct(meas, cfg, p, targets=TARGETS)
    with jax.disable_jit():
        eager = aj.reconstruct(meas, cfg, p, targets=TARGETS)
    assert jitted.shape == (Q, 3) and np.all(np.isfinite(jitted))
    _close(jitted, eager)


def test_reconstruct_batch_and_vmap_equal_the_loop():
    """``reconstruct_batch`` (jit of a vmap) and a user's vmap of ``reconstruct`` equal a loop of
    ``reconstruct`` calls (each jit == eager, above; an eager vmap would cost another ~40 s)."""
    cfg = CONFIGS["iso-paper"]
    p = aj.Params.default(cfg)
    stacked = _stack(cfg, p)
    members = _members(stacked)
    batch = aj.reconstruct_batch(stacked, cfg, p, targets=TARGETS)
    assert batch.shape == (3, Q, 3)
    _close(
        jax.jit(lambda m, q: aj.reconstruct_batch(m, cfg, q, targets=TARGETS))(stacked, p), batch
    )
    loop = jnp.stack([aj.reconstruct(m, cfg, p, targets=TARGETS) for m in members])
    _close(batch, loop)
    _close(aj.reconstruct_batch(members, cfg, p, targets=TARGETS), loop)  # a list is stacked
    _close(jax.vmap(lambda m: aj.reconstruct(m, cfg, p, targets=TARGETS))(stacked), loop)


def test_reconstruct_vmap_over_params_equals_loop():
    """α, widths and λ are traced: they vmap like data (one factorisation per member)."""
    cfg = CONFIGS["iso-paper"]
    p = aj.Params.default(cfg)
    meas = _measure(cfg, p)
    ps = aj.Params(
        jnp.deg2rad(jnp.asarray([12.0, 15.0, 19.0])),
        jnp.stack([p.widths * f for f in (0.8, 1.0, 1.3)]),
        jnp.asarray([1e-3, 1e-2, 3e-2]),
    )
    got = jax.vmap(lambda q: aj.reconstruct(meas, cfg, q, targets=TARGETS))(ps)
    want = jnp.stack(
        [
            aj.reconstruct(meas, cfg, aj.Params(a, w, r), targets=TARGETS)
            for a, w, r in zip(ps.alpha, ps.widths, ps.reg)
        ]
    )
    _close(got, want)


def _leaves(p):
    """The scalar coordinates of a Params: (name, getter, setter)."""
    out = [("alpha", lambda q: q.alpha, lambda q, v: aj.Params(v, q.widths, q.reg))]
    for k in range(4):
        out.append(
            (
                f"widths[{k}]",
                lambda q, k=k: q.widths[k],
                lambda q, v, k=k: aj.Params(q.alpha, q.widths.at[k].set(v), q.reg),
            )
        )
    out.append(("reg", lambda q: q.reg, lambda q, v: aj.Params(q.alpha, q.widths, v)))
    return out


def _check_fd(value_and_grad, p, rel_step=1e-5, rtol=1e-5):
    """Each coordinate of the gradient (a Params) against a central difference of the value."""
    value, grad = value_and_grad(p)
    assert isinstance(grad, aj.Params)
    for name, get, put in _leaves(p):
        x = float(get(p))
        h = rel_step * max(abs(x), 1e-2)
        fd = (float(value_and_grad(put(p, x + h))[0]) - float(value_and_grad(put(p, x - h))[0])) / (
            2 * h
        )
        g = float(get(grad))
        assert np.isfinite(g) and g != 0.0, f"d loss / d {name} = {g}"
        scale = max(abs(fd), 1e-6 * abs(float(value)))
        assert abs(g - fd) <= rtol * scale, (
            f"d loss / d {name}: grad {g:.10g}, central difference {fd:.10g}"
        )


@pytest.mark.parametrize("name", list(CONFIGS))
def test_reconstruct_grad_in_params_matches_central_differences(name):
    """Through the sampling (α moves the slices) and the reconstruction (α, widths, λ)."""
    cfg = CONFIGS[name]
    truth = model(*TARGETS)

    def loss(p):
        rec = aj.reconstruct(_measure(cfg, p), cfg, p, targets=TARGETS)
        return jnp.mean((rec - truth) ** 2)

    # one compile: the central differences take their values from the same jitted function
    _check_fd(jax.jit(jax.value_and_grad(loss)), aj.Params.default(cfg, alpha_deg=ALPHA_DEG))


def test_reconstruct_batch_grad_matches_a_directional_difference():
    cfg = CONFIGS["iso-paper"]
    p = aj.Params.default(cfg, alpha_deg=ALPHA_DEG)
    stacked = _stack(cfg, p)
    truth = model(*TARGETS)

    @jax.jit
    @jax.value_and_grad
    def loss(q):
        return jnp.mean((aj.reconstruct_batch(stacked, cfg, q, targets=TARGETS) - truth[None]) ** 2)

    _, g = loss(p)
    d = aj.Params(jnp.asarray(0.01), jnp.asarray([0.02, -0.01, 0.015, 0.01]), jnp.asarray(1e-3))
    h = 1e-4

    def at(t):
        return aj.Params(p.alpha + t * d.alpha, p.widths + t * d.widths, p.reg + t * d.reg)

    fd = (float(loss(at(h))[0]) - float(loss(at(-h))[0])) / (2 * h)
    directional = sum(
        float(jnp.sum(a * b))
        for a, b in zip(jax.tree_util.tree_leaves(g), jax.tree_util.tree_leaves(d))
    )
    np.testing.assert_allclose(directional, fd, rtol=1e-6)
    assert all(np.all(np.isfinite(x)) for x in jax.tree_util.tree_leaves(g))


# --- compiled operator ------------------------------------------------------------------------


def test_operator_jit_eager_vmap_loop_grad_and_no_retrace():
    # TPS on the log of the samples, rule "average": one matrix
    cfg = aj.preset("operator", "aniso204", **SMALL)
    p = aj.Params.default(cfg, alpha_deg=ALPHA_DEG)
    stacked = _stack(cfg, p)
    template = _members(stacked)[0]
    op = aj.compile_operator(cfg, p, template, targets=TARGETS)
    ys = stacked.y
    batched = op(ys)  # the call is jit-compiled (its apply is a filter_jit)
    assert batched.shape == (3, Q, 3)  # that it equals the pipeline is test_operator.py's
    with jax.disable_jit():
        _close(op(ys), batched)
    # vmap == loop
    _close(jax.vmap(op)(ys), jnp.stack([op(y) for y in ys]))
    # grad in the values (log space: not linear) against a central difference along a direction
    w = jnp.where(
        stacked.mask[..., None], jnp.asarray(np.random.default_rng(1).normal(size=ys.shape)), 0.0
    )

    def loss_y(y):
        return jnp.sum(op(y) ** 2)

    g = jax.grad(loss_y)(ys)
    h = 1e-6
    fd = (loss_y(ys + h * w) - loss_y(ys - h * w)) / (2 * h)
    np.testing.assert_allclose(float(jnp.sum(g * w)), float(fd), rtol=1e-6)
    # grad in the Params through compile_operator: the matrix is differentiable in α, widths, λ
    truth = model(*TARGETS)

    def loss_p(q):
        return jnp.sum(
            (aj.compile_operator(cfg, q, template, targets=TARGETS)(ys) - truth[None]) ** 2
        )

    _check_fd(jax.jit(jax.value_and_grad(loss_p)), p)
    # new values, new parameters of the same shapes: neither the apply nor the build is traced again
    ys2 = ys * 1.7
    p2 = aj.Params(p.alpha * 1.1, p.widths * 0.9, p.reg * 2.0)
    n_apply, n_build = TRACE_COUNT["apply"], TRACE_COUNT["build"]
    with traces() as seen:
        op(ys2)
        aj.compile_operator(cfg, p2, template, targets=TARGETS)(ys2)
    assert (TRACE_COUNT["apply"], TRACE_COUNT["build"]) == (n_apply, n_build)
    assert seen == [], f"new values or parameters were traced again: {seen}"


# --- sample -----------------------------------------------------------------------------------


def test_sample_jit_eager_vmap_loop_and_grad_in_alpha():
    cfg = aj.Config(budget="aniso204", **SMALL)
    p = aj.Params.default(
        cfg, alpha_deg=ALPHA_DEG
    )  # off the grid azimuths (sample_table is bilinear)
    theta, phi = aj.ubo_grid()
    w = aj.to_vector(jnp.deg2rad(jnp.asarray(theta)), jnp.deg2rad(jnp.asarray(phi)))
    table = model(jnp.broadcast_to(w[:, None], (81, 81, 3)), jnp.broadcast_to(w[None], (81, 81, 3)))
    alphas = jnp.deg2rad(jnp.asarray([10.0, 15.0, 22.0]))
    ps = aj.Params(alphas, jnp.broadcast_to(p.widths, (3, 4)), jnp.broadcast_to(p.reg, (3,)))
    for source in (model, table):  # exact angles, or interpolated over the table's azimuths

        def fn(q, source=source):
            return aj.sample(source, cfg, q, as_measurements=True)

        jitted = jax.jit(fn)(p)
        with jax.disable_jit():
            eager = fn(p)
        assert isinstance(jitted, aj.Measurements) and jitted.pairs == eager.pairs
        _close(jitted.y, eager.y, rtol=1e-12)
        np.testing.assert_array_equal(jitted.count, eager.count)
        _close(
            jax.vmap(fn)(ps).y,
            jnp.stack([fn(aj.Params(a, p.widths, p.reg)).y for a in alphas]),
            rtol=1e-12,
        )
        # grad: α moves every sample; widths and λ do not enter the sampling
        wts = jnp.where(
            eager.mask[..., None],
            jnp.asarray(np.random.default_rng(2).normal(size=eager.y.shape)),
            0.0,
        )

        @jax.jit
        @jax.value_and_grad
        def loss(q, fn=fn, wts=wts):
            return jnp.sum(fn(q).y * wts)

        _, g = loss(p)
        assert float(jnp.max(jnp.abs(g.widths))) == 0.0 and float(g.reg) == 0.0
        h = 1e-6
        fd = (
            float(loss(aj.Params(p.alpha + h, p.widths, p.reg))[0])
            - float(loss(aj.Params(p.alpha - h, p.widths, p.reg))[0])
        ) / (2 * h)
        np.testing.assert_allclose(float(g.alpha), fd, rtol=1e-6)


# --- trace counts of reconstruct itself -------------------------------------------------------


def test_reconstruct_does_not_retrace_for_new_values_params_or_an_equal_config():
    """New sample values, new Params (also from Python floats), an equal new Config, new targets of
    the same shape: no trace, no compile, for ``reconstruct`` and ``reconstruct_batch``."""
    cfg = CONFIGS["iso-paper"]
    p = aj.Params.default(cfg)
    stacked = _stack(cfg, p)
    meas = _members(stacked)[0]
    aj.reconstruct(meas, cfg, p, targets=TARGETS)  # compiled here unless an earlier test did
    aj.reconstruct_batch(stacked, cfg, p, targets=TARGETS)
    # the new inputs, made before counting (making them runs eager operations of their own)
    new_y = jnp.where(meas.mask[..., None], meas.y * 1.3 + 0.01, 0.0)
    cases = {
        "new values": (meas.replace(y=new_y), stacked.replace(y=stacked.y[::-1]), p, cfg, TARGETS),
        "new alpha": (meas, stacked, p.with_alpha_deg(18.0), cfg, TARGETS),
        "new params from floats": (
            meas,
            stacked,
            aj.Params(0.2, [0.5, 0.4, 0.6, 0.5], 3e-3),
            cfg,
            TARGETS,
        ),
        "an equal new Config": (meas, stacked, p, aj.Config(budget="iso102", **SMALL), TARGETS),
        "new targets": (meas, stacked, p, cfg, tuple(jnp.flip(t, 0) for t in TARGETS)),
    }
    with traces() as control:
        jax.jit(lambda x: x * 2)(
            jnp.zeros(17)
        ).block_until_ready()  # a fresh shape: the counter works
    assert control, "the trace counter saw no event for a fresh jit"
    traced = {}
    for name, (m, batch, q, c, t) in cases.items():
        with traces() as seen:
            aj.reconstruct(m, c, q, targets=t).block_until_ready()
            aj.reconstruct_batch(batch, c, q, targets=t).block_until_ready()
        if seen:
            traced[name] = len(seen)
    assert not traced, f"reconstruct traced or compiled again for: {traced}"
