"""Brax 0.14.2's PPO on a JAX without ``jax.device_put_replicated`` (removed in jax 0.10).

This project pins ``jax<0.10`` (pyproject.toml) because Brax 0.14.2's PPO replicates its
training state with ``jax.device_put_replicated`` (``brax/training/agents/ppo/train.py``,
``brax/training/pmap.py``). A machine whose JAX is newer and cannot be changed (the GPU
device image has jax 0.11.2, see docs/training.md, "Transfer matrix on Go1") gets
:func:`device_put_replicated` instead, installed by :func:`install` *only when JAX lacks
the function*: on the pinned JAX nothing changes.

It does what jax 0.9's own ``device_put_replicated`` does when ``jax_pmap_shmap_merge`` is
on (the only ``pmap`` of jax >= 0.10): every leaf gets a new leading axis of length
``len(devices)``, its slice ``i`` on ``devices[i]``, as one array sharded over a
one-axis mesh of the devices. ``tests/test_transfer_go1.py`` checks it against jax 0.9's
function and through a ``jax.pmap``.
"""

from __future__ import annotations

from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np

_AXIS = "_device_put_replicated"


def device_put_replicated(x, devices: Sequence):
    """Each leaf of ``x`` stacked ``len(devices)`` times, slice ``i`` on ``devices[i]``.

    Args:
      x: an array, a scalar, or a pytree of them.
      devices: a non-empty sequence of ``jax.Device``.

    Returns:
      The same pytree, every leaf of shape ``(len(devices),) + shape``, sharded along its
      first axis over ``devices``.

    Raises:
      ValueError: ``devices`` is empty or not a sequence.
    """
    if not isinstance(devices, Sequence) or not devices:
        raise ValueError(f"devices must be a non-empty sequence of devices, got {devices!r}")
    n = len(devices)
    mesh = jax.sharding.Mesh(np.array(devices), (_AXIS,))
    sharding = jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec(_AXIS))

    def put(leaf):
        a = jnp.asarray(leaf)
        return jax.device_put(jnp.broadcast_to(a[None], (n,) + a.shape), sharding)

    return jax.tree.map(put, x)


def install() -> bool:
    """Sets ``jax.device_put_replicated`` to :func:`device_put_replicated` if JAX has none.

    Returns:
      True when it was installed (this JAX lacks the function), False when JAX has its own.
    """
    if hasattr(jax, "device_put_replicated"):
        return False
    jax.device_put_replicated = device_put_replicated
    return True
