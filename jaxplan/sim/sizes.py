"""Size classes: scenes padded to a few fixed shapes, so that compiled programs are reused.

A jitted program is compiled for its arrays' shapes. Scenes differ in their counts of
obstacles, recorded steps, lanelet outlines, goal polygons, stop lines and lane paths
(``jaxplan.scenarios.batch.SIZE_NAMES``); padded to the largest scene, a batch of small scenes
pays for one large one, and every new file with a new count compiles again. So:

- the obstacle count ``K``, which sets a planner's work, is rounded up to its **class** (the
  next value of ``OBSTACLE_CLASSES``), and scenes are driven group by group, one group per class;
- every other count is rounded up to its class and the run pads every scene to the largest of
  those (``run_sizes``): they cost little, and the drives of a run then need one program per
  obstacle class, the metrics one program in all;
- the lanelet outlines (``Scene.drivable``), which planners and the simulator never read, are
  cut to one degenerate outline for the drive (``for_drive``): only the metrics see them.

A new file almost always falls into compiled classes, whose programs, with the persistent
compilation cache, are kept on disk from earlier runs.
"""

from __future__ import annotations

import dataclasses

CLASSES = {
    "K": (8, 16, 32, 64, 128, 256),  # obstacles
    "T": (48, 160, 400, 1000),  # recorded steps
    "M": (16, 64, 256),  # lanelet outlines
    "V": (16, 32, 64, 128, 256),  # vertices of an outline
    "G": (1, 4),  # goal polygons
    "W": (4, 16, 48, 128),  # vertices of a goal polygon
    "NL": (0, 4, 16),  # stop lines
    "P": (1, 1000, 4000),  # steps of a stop line's colour cycle
    "LP": (16, 64, 256, 1024),  # lane paths
}


def size_class(n: int, classes: tuple) -> int:
    """The smallest class ``>= n``; past the last, ``n`` rounded up to a multiple of the last."""
    for c in classes:
        if n <= c:
            return c
    last = classes[-1]
    return -(-n // last) * last


def obstacle_class(scene) -> int:
    """The obstacle class ``K`` of an unbatched scene (at least one obstacle slot)."""
    from jaxplan.scenarios.batch import scene_sizes

    return size_class(max(scene_sizes(scene)["K"], 1), CLASSES["K"])


def run_sizes(scenes) -> dict:
    """The padded sizes of a run over unbatched scenes: every count's class, the largest over the
    scenes (``K`` included: the metrics' size; the drives use each group's ``obstacle_class``)."""
    from jaxplan.scenarios.batch import SIZE_NAMES, scene_sizes

    out = {k: 0 for k in SIZE_NAMES}
    for s in scenes:
        for k, n in scene_sizes(s).items():
            out[k] = max(out[k], size_class(n, CLASSES[k]))
    return out


def for_drive(batch):
    """A batched scene without its lanelet outlines (one degenerate outline each): what the drive
    program needs (planners and the simulator never read them), so that its compiled shape does
    not depend on the map's size."""
    return dataclasses.replace(
        batch, drivable=batch.drivable[:, :1, :3], drivable_valid=batch.drivable_valid[:, :1, :3]
    )
