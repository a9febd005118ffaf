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


def to_device(x, dtype=None):
    """``jnp.asarray(x, dtype)``, cast on the host where ``x`` is a host array or number (its own
    dtype made canonical when ``dtype`` is ``None``: float64 → float32 without x64). Told no
    dtype, ``jnp.asarray`` of host data stages an eager conversion, which a cold process
    compiles for every shape and dtype (~10 ms each); JAX arrays and tracers go to
    ``jnp.asarray`` as they are."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    if isinstance(x, (np.ndarray, np.generic, float, int)):
        x = np.asarray(x, dtype)
        dtype = jax.dtypes.canonicalize_dtype(x.dtype)
    return jnp.asarray(x, dtype)
