"""Scenes split over every local device: a 1-D mesh, placement of a batch along its scene axis."""

from __future__ import annotations

from collections.abc import Callable

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec


def scene_mesh(devices=None) -> Mesh:
    """A 1-D mesh over the local devices with axis name ``"scenes"``."""
    devices = jax.local_devices() if devices is None else devices
    return Mesh(np.asarray(devices), ("scenes",))


def place(batch, mesh: Mesh | None = None, pad_to: int | None = None):
    """``batch`` (a pytree of arrays ``(B, ...)``) on the mesh's devices, split along the scene axis.

    The scene axis is padded (repeating the last scene) to at least ``pad_to`` and to a multiple
    of the device count, so that every chunk of a run has one shape and one compiled program.

    Returns:
        ``(placed batch, B)``.
    """
    mesh = mesh or scene_mesh()
    n_dev = mesh.devices.size
    B = jax.tree_util.tree_leaves(batch)[0].shape[0]
    size = max(B, pad_to or 0)
    pad = size - B + (-size) % n_dev

    def put(x):
        x = np.asarray(x)
        if pad:
            x = np.concatenate([x, np.repeat(x[-1:], pad, axis=0)], axis=0)
        spec = PartitionSpec("scenes", *([None] * (x.ndim - 1)))
        return jax.device_put(x, NamedSharding(mesh, spec))

    return jax.tree_util.tree_map(put, batch), B


def sharded_map(fn: Callable, batch, mesh: Mesh | None = None, pad_to: int | None = None):
    """Apply a jitted batched ``fn`` to ``batch`` split over the mesh's devices.

    Args:
        fn: jitted function of a pytree whose leaves have a leading scene axis.
        batch: pytree of arrays ``(B, ...)``.
        pad_to: pad the scene axis to at least this size (``place``).

    Returns:
        ``fn(batch)`` as numpy arrays ``(B, ...)`` (the padding cut off).
    """
    placed, B = place(batch, mesh, pad_to)
    out = fn(placed)
    return jax.tree_util.tree_map(lambda y: np.asarray(y)[:B], out)
