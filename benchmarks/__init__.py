"""Benchmarks of abrdf_jax: accuracy on the MERL split, speed, and the scipy peer."""
