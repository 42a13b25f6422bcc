"""Entry points on top of ``jax_contact`` and ``envs``: the command line, reproduction, training."""
