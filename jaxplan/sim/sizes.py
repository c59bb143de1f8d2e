"""Size classes: scenes padded to a few fixed shapes, so that compiled programs are reused.

A jitted program is compiled for its arrays' shapes. Scenes differ in their counts of
obstacles, recorded steps, lanelet outlines and goal polygons; padded to the largest scene
of a run, a batch of small scenes pays for one large one, and every new file with a new
count compiles again. Instead, each count is rounded up to its **class** (the next value in
a short geometric list), scenes are grouped by class and driven group by group: a new file
almost always falls into a class whose program is compiled (and, with the persistent
compilation cache, stored on disk from an earlier run).

The planner and the simulator never read the lanelet outlines (``Scene.drivable``): the drive
program sees them at a fixed minimal size (``for_drive``) and only the metrics, a program
that compiles in seconds, see them whole.
"""
from __future__ import annotations

import dataclasses

import numpy as np

OBSTACLE_CLASSES = (8, 16, 32, 64, 128, 256)  # K
STEP_CLASSES = (48, 96, 160, 256, 384)  # T: recorded steps (and the drive's length + 1)
POLYGON_CLASSES = (16, 64, 256)  # M: lanelet outlines
VERTEX_CLASSES = (16, 32, 64, 128, 256)  # V: vertices of an outline
GOAL_CLASSES = (1, 4)  # G: goal polygons
GOAL_VERTEX_CLASSES = (4, 16, 48, 128)  # W: vertices of a goal polygon


def size_class(n: int, classes: tuple) -> int:
    """The smallest class ``>= n``; past the last, ``n`` rounded up to a multiple of the last."""
    for c in classes:
        if n <= c:
            return c
    last = classes[-1]
    return -(-n // last) * last


def scene_counts(scene) -> dict:
    """The counts of an unbatched (numpy) ``Scene``: ``K, T, M, V, G, W``."""
    b = np.shape(scene.obstacles.boxes)
    return {"K": b[0], "T": b[1], "M": np.shape(scene.drivable)[0], "V": np.shape(scene.drivable)[1],
            "G": np.shape(scene.goal.region)[0], "W": np.shape(scene.goal.region)[1]}


@dataclasses.dataclass(frozen=True, order=True)
class DriveClass:
    """The padded shape a scene is driven at: obstacles ``K`` over ``T`` steps, goal ``G x W``."""

    K: int
    T: int
    G: int
    W: int

    def label(self) -> str:
        return f"K{self.K}-T{self.T}-G{self.G}x{self.W}"


def drive_class(scene, n_steps: int) -> DriveClass:
    """The ``DriveClass`` of an unbatched scene driven for ``n_steps`` steps."""
    c = scene_counts(scene)
    return DriveClass(size_class(max(c["K"], 1), OBSTACLE_CLASSES), size_class(max(c["T"], n_steps + 1), STEP_CLASSES),
                      size_class(c["G"], GOAL_CLASSES), size_class(c["W"], GOAL_VERTEX_CLASSES))


def metric_sizes(scenes) -> tuple:
    """``(M, V)`` classes covering every scene of ``scenes`` (unbatched, numpy)."""
    m = max(scene_counts(s)["M"] for s in scenes)
    v = max(scene_counts(s)["V"] for s in scenes)
    return size_class(m, POLYGON_CLASSES), size_class(v, VERTEX_CLASSES)


def for_drive(batch):
    """A batched scene without its lanelet outlines (one degenerate outline each): what the drive
    program needs (planners and the simulator never read them), so that its compiled shape does
    not depend on the map's size."""
    d = batch.drivable
    return dataclasses.replace(batch, drivable=d[:, :1, :3], drivable_valid=batch.drivable_valid[:, :1, :3])
