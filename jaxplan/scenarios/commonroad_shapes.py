"""commonroad-io's shapes across its releases (duck-typed: it renamed its shape classes): read as
the smallest oriented box covering them (``cover_box``: rectangles exactly, circles as the square
of their diameter, polygons and shape groups by their smallest covering box, turned to lie along a
heading), and built for writing (``_Shapes``).
"""

from __future__ import annotations

import math

import numpy as np

from jaxplan.scenarios.fields import ScenarioError
from jaxplan.scenarios.parse_obstacles import _min_area_box


def _point(p) -> np.ndarray:
    """A CommonRoad centre (array, shapely Point or None) as ``(2,)``."""
    if p is None or callable(p):
        return np.zeros(2)
    if hasattr(p, "x") and hasattr(p, "y"):
        return np.array([float(p.x), float(p.y)])
    return np.asarray(p, float).reshape(2)


def _shape_fields(shape) -> dict:
    """Length/width/centre/orientation of a CommonRoad shape or occupancy, or its polygon.

    Duck-typed: commonroad-io renamed its shape classes across releases.
    """
    group = getattr(shape, "occupancies", None) or getattr(shape, "shapes", None)
    if group:
        shape = group[0]
    if hasattr(shape, "length") and hasattr(shape, "width"):
        c = getattr(shape, "rect_center", None)
        c = getattr(shape, "center", None) if c is None else c
        c = _point(c)
        return {
            "length": float(shape.length),
            "width": float(shape.width),
            "center": c.tolist(),
            "orientation": float(getattr(shape, "orientation", 0.0) or 0.0),
        }
    if hasattr(shape, "radius"):
        c = _point(getattr(shape, "center", None))
        return {
            "length": 2 * float(shape.radius),
            "width": 2 * float(shape.radius),
            "center": c.tolist(),
            "orientation": 0.0,
        }
    if hasattr(shape, "vertices"):
        return {"polygon": np.asarray(shape.vertices, float).tolist()}
    raise ScenarioError(f"unsupported CommonRoad shape {type(shape).__name__}")


CIRCLE_SIDES = 16  # a circle inside a shape group is covered through its circumscribed 16-gon


def _outline(shape) -> np.ndarray:
    """``(N, 2)`` points whose covering box covers ``shape`` (a rectangle, circle, polygon or group)."""
    group = getattr(shape, "shapes", None) or getattr(shape, "occupancies", None)
    if group:
        return np.concatenate([_outline(s) for s in group])
    if hasattr(shape, "length") and hasattr(shape, "width"):
        c = getattr(shape, "rect_center", None)
        c = _point(getattr(shape, "center", None) if c is None else c)
        th = float(getattr(shape, "orientation", 0.0) or 0.0)
        u, w = np.array([math.cos(th), math.sin(th)]), np.array([-math.sin(th), math.cos(th)])
        hl, hw = 0.5 * float(shape.length), 0.5 * float(shape.width)
        return np.array([c + a * hl * u + b * hw * w for a, b in ((1, 1), (-1, 1), (-1, -1), (1, -1))])
    if hasattr(shape, "radius"):
        a = np.arange(CIRCLE_SIDES) * 2 * np.pi / CIRCLE_SIDES
        r = float(shape.radius) / math.cos(np.pi / CIRCLE_SIDES)
        return _point(getattr(shape, "center", None)) + r * np.column_stack([np.cos(a), np.sin(a)])
    if hasattr(shape, "vertices"):
        return np.asarray(shape.vertices, float).reshape(-1, 2)
    raise ScenarioError(f"unsupported CommonRoad shape {type(shape).__name__}")


def _toward(box: np.ndarray, heading: float) -> np.ndarray:
    """The same box ``[x, y, length, width, theta]`` with ``theta`` the one of its four equivalent
    orientations (quarter turns, length and width swapped on odd ones) nearest ``heading``."""
    best: tuple[float, np.ndarray] | None = None
    for k in range(4):
        th = box[4] + k * np.pi / 2
        d = math.remainder(th - heading, 2 * np.pi)
        if best is None or abs(d) < abs(best[0]) - 1e-12:
            L, W = (box[2], box[3]) if k % 2 == 0 else (box[3], box[2])
            best = (d, np.array([box[0], box[1], L, W, heading + d]))
    assert best is not None  # the first of the four orientations always sets it
    return best[1]


def cover_box(shape, heading: float = 0.0) -> np.ndarray:
    """The smallest oriented box ``(5,)`` ``[x, y, length, width, theta]`` covering a CommonRoad shape:
    a rectangle itself, a circle the square of its diameter (at ``heading``), a polygon or a shape
    group the smallest box around their outlines (``parse_obstacles._min_area_box``); ``theta`` within 45 degrees
    of ``heading`` (length along it).

    Raises:
        ScenarioError: a shape kind commonroad-io has that is none of these, or a degenerate polygon.
    """
    group = getattr(shape, "shapes", None) or getattr(shape, "occupancies", None)
    if group and len(group) == 1:
        shape, group = group[0], None
    if not group and hasattr(shape, "radius") and not hasattr(shape, "length"):
        c, d = _point(getattr(shape, "center", None)), 2 * float(shape.radius)
        return np.array([c[0], c[1], d, d, heading])
    if not group and hasattr(shape, "length") and hasattr(shape, "width"):
        f = _shape_fields(shape)
        box = np.array([*f["center"], f["length"], f["width"], f["orientation"]])
    else:
        pts = _outline(shape)
        try:
            box = _min_area_box(pts)
        except ValueError:
            raise ScenarioError(f"degenerate {type(shape).__name__} (its points lie on a line)") from None
        if box[2] <= 1e-9 or box[3] <= 1e-9:
            raise ScenarioError(f"degenerate {type(shape).__name__} (its points lie on a line)")
    return _toward(box, heading)


def _placed(box: np.ndarray, x: float, y: float, theta: float) -> np.ndarray:
    """A box given in an obstacle's own frame, placed by its state ``(x, y, theta)``."""
    c, s = math.cos(theta), math.sin(theta)
    return np.array([x + c * box[0] - s * box[1], y + s * box[0] + c * box[1], box[2], box[3], box[4] + theta])


class _Shapes:
    """Constructors of commonroad-io's shapes across its releases.

    2024.x has ``commonroad.geometry.shape`` (``Rectangle``, ``Polygon``, ``ShapeGroup``);
    2026.x splits them into obstacle shapes (placed by a state) and occupancies (placed areas).
    """

    def __init__(self):
        try:
            from commonroad.geometry import shape as old
        except ImportError:
            old = None
        self.old = old

    def obstacle_rect(self, length: float, width: float):
        if self.old:
            return self.old.Rectangle(length, width)
        from commonroad.geometry.obstacle_shapes.rect_obstacle_shape import RectObstacleShape

        return RectObstacleShape(width=width, length=length)

    def obstacle_polygon(self, vertices: np.ndarray):
        if self.old:
            return self.old.Polygon(np.asarray(vertices, float))
        from commonroad.geometry.obstacle_shapes.polygon_obstacle_shape import PolygonObstacleShape

        return PolygonObstacleShape(vertices=tuple(map(tuple, np.asarray(vertices, float).tolist())))

    def region_rect(self, length: float, width: float, center, orientation: float):
        if self.old:
            return self.old.Rectangle(length, width, np.asarray(center, float), orientation)
        import shapely
        from commonroad.geometry.occupancy.rect_occupancy import RectOccupancy

        return RectOccupancy(
            rect_center=shapely.Point(float(center[0]), float(center[1])),
            width=width,
            length=length,
            orientation=orientation,
        )

    def group(self, regions: list):
        if len(regions) == 1:
            return regions[0]
        if self.old:
            return self.old.ShapeGroup(list(regions))
        from commonroad.geometry.occupancy.occupancy_group import OccupancyGroup

        return OccupancyGroup(occupancies=tuple(regions))
