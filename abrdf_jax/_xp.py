"""The array namespace of the numerical core's dual-use functions: ``jax.numpy`` (traced,
differentiable; the default) or ``numpy`` (on the host, without importing JAX: the operator
store's build, :mod:`abrdf_jax._host_build`). Functions take ``xp=None`` and resolve it here."""


def namespace(xp=None):
    """``xp``, or ``jax.numpy`` (imported on first use) when it is ``None``."""
    if xp is None:
        import jax.numpy as jnp

        return jnp
    return xp


def stop_gradient(x, xp):
    """``jax.lax.stop_gradient`` under JAX; the value itself in numpy."""
    if xp.__name__ == "numpy":
        return x
    import jax

    return jax.lax.stop_gradient(x)
