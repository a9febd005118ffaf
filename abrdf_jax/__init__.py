"""abrdf_jax: restore a material's full ABRDF from sparse slice measurements, in JAX."""
