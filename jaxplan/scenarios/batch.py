"""Batches of scenes: unbatched (numpy) ``Scene``s of different sizes padded to common sizes and
stacked along a leading scene axis.

``stack_scenes`` pads every scene (``pad_scene``) to the largest of the batch, or to given lower
bounds (one compiled shape for several batches), in the counts ``SIZE_NAMES`` (``scene_sizes`` reads
them off one scene). Padding is invalid (obstacles, stop lines, lane paths) or repeats the last
vertex (polygons), with masks. ``index_scene`` takes one scene back out of a batch.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.scenarios.lights import no_lights, pad_lights
from jaxplan.scenarios.scene import OBSTACLE_TYPES, Scene
from jaxplan.types import Obstacles


def _pad_axis(a: np.ndarray, axis: int, size: int, fill) -> np.ndarray:
    a = np.asarray(a)
    if a.shape[axis] >= size:
        return a
    pad = [(0, 0)] * a.ndim
    pad[axis] = (0, size - a.shape[axis])
    if isinstance(fill, str) and fill == "edge":
        return np.pad(a, pad, mode="edge") if a.shape[axis] else np.pad(a, pad)
    return np.pad(a, pad, constant_values=fill)


def pad_scene(
    scene: Scene, K: int, T: int, M: int, V: int, G: int, W: int, NL: int = 0, P: int = 1, LP: int | None = None
) -> Scene:
    """Pad one (numpy) scene to ``K`` obstacles over ``T`` steps, ``M x V`` drivable and
    ``G x W`` goal polygons, ``NL`` stop lines with ``P`` steps of colors. Padding is invalid
    (obstacles, stop lines) or repeats the last vertex (polygons). ``LP``: pad the lane paths to
    ``LP`` (invalid paths) when given."""
    if LP is not None and scene.lane_paths is not None:
        scene = dataclasses.replace(
            scene,
            lane_paths=_pad_axis(scene.lane_paths, 0, LP, 0.0),
            lane_path_valid=_pad_axis(scene.lane_path_valid, 0, LP, False),
        )
    o = scene.obstacles
    b = _pad_axis(_pad_axis(o.boxes, 1, T, "edge"), 0, K, 0.0)
    if K > o.boxes.shape[0]:
        b[o.boxes.shape[0] :, :, 2:4] = 1.0  # padding: unit boxes, never valid
    v = _pad_axis(_pad_axis(o.valid, 1, T, False), 0, K, False)
    t = np.arange(T) * float(scene.dt)
    obs = Obstacles(b, v, t, _pad_axis(o.static, 0, K, False))
    sl = _pad_axis(_pad_axis(scene.obstacle_sl, 1, T, "edge"), 0, K, 0.0)
    ty = _pad_axis(scene.obstacle_type, 0, K, OBSTACLE_TYPES.index("unknown"))

    def polys(p, ok, m, w):
        p = _pad_axis(p, 1, w, "edge")
        ok = _pad_axis(ok, 1, w, False)
        return _pad_axis(p, 0, m, 0.0), _pad_axis(ok, 0, m, False)

    drv, drv_ok = polys(scene.drivable, scene.drivable_valid, M, V)
    reg, reg_ok = polys(scene.goal.region, scene.goal.region_valid, G, W)
    goal = dataclasses.replace(scene.goal, region=reg, region_valid=reg_ok)
    lights = pad_lights(no_lights() if scene.lights is None else scene.lights, NL, P)
    return dataclasses.replace(
        scene,
        drivable=drv,
        drivable_valid=drv_ok,
        obstacles=obs,
        obstacle_sl=sl,
        obstacle_type=ty,
        goal=goal,
        lights=lights,
    )


SIZE_NAMES = ("K", "T", "M", "V", "G", "W", "NL", "P", "LP")


def scene_sizes(scene: Scene) -> dict:
    """The counts of an unbatched (numpy) scene that padding changes (``SIZE_NAMES``): obstacles ``K``
    over ``T`` steps, ``M`` lanelet outlines of ``V`` vertices, ``G`` goal polygons of ``W``
    vertices, ``NL`` stop lines with ``P`` steps of colours, ``LP`` lane paths."""
    b = np.shape(scene.obstacles.boxes)
    nl, p = np.shape(scene.lights.color) if scene.lights is not None else (0, 1)
    return {
        "K": b[0],
        "T": b[1],
        "M": np.shape(scene.drivable)[0],
        "V": np.shape(scene.drivable)[1],
        "G": np.shape(scene.goal.region)[0],
        "W": np.shape(scene.goal.region)[1],
        "NL": nl,
        "P": p,
        "LP": np.shape(scene.lane_paths)[0] if scene.lane_paths is not None else 0,
    }


def stack_scenes(scenes: list, min_steps: int = 1, min_sizes=None) -> Scene:
    """One batched ``Scene`` (jnp leaves with a leading scene axis) from unbatched numpy scenes
    of any sizes (same route points and lanes).

    Args:
        min_steps: pad obstacles to at least this many steps.
        min_sizes: optional lower bounds of the padded sizes (one compiled shape for several
            batches): a dict over ``SIZE_NAMES`` (missing ones: the largest scene's), or a tuple
            ``(K, T, M, V, G, W)`` optionally followed by ``(NL, P)``.
    """
    if not scenes:
        raise ValueError("stack_scenes: no scenes")
    if min_sizes is not None and not isinstance(min_sizes, dict):
        min_sizes = dict(zip(SIZE_NAMES, min_sizes))
    bad = set(min_sizes or ()) - set(SIZE_NAMES)
    if bad:
        raise ValueError(f"stack_scenes: min_sizes has unknown sizes {sorted(bad)}; known: {', '.join(SIZE_NAMES)}")
    have = [scene_sizes(s) for s in scenes]
    size = {k: max([h[k] for h in have] + [int((min_sizes or {}).get(k, 0))]) for k in SIZE_NAMES}
    size["K"] = max(size["K"], 1)  # one invalid obstacle at least: no zero-size arrays in the kernels
    size["T"] = max(size["T"], min_steps)
    size["P"] = max(size["P"], 1)
    size["LP"] = max(size["LP"], 1)
    padded = [
        pad_scene(
            s, size["K"], size["T"], size["M"], size["V"], size["G"], size["W"], size["NL"], size["P"], LP=size["LP"]
        )
        for s in scenes
    ]
    f = jnp.result_type(float)

    def stack(*xs):
        a = np.stack([np.asarray(x) for x in xs])
        return jnp.asarray(a, f) if np.issubdtype(a.dtype, np.floating) else jnp.asarray(a)

    return jax.tree_util.tree_map(stack, *padded)


def index_scene(batch: Scene, i: int) -> Scene:
    """Scene ``i`` of a batch."""
    return jax.tree_util.tree_map(lambda x: x[i], batch)
