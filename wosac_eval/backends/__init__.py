"""Compute backends for the feature kernels beyond numpy: `jax_backend` (jit, batched over scenes) and
`jax_realism` (realism on device arrays). Which backends exist, and whether this install has them:
`wosac_eval.extras`."""
