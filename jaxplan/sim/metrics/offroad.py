"""``offroad``: the car's box leaves the drivable area (the union of the lanelets).

The box is on the road when

* points along its outline (its corners and at most every ``SPACING`` metres of its sides) each
  lie inside some lanelet outline, or within ``TOL`` of one (seams between lanelets whose shared
  bound is not vertex-identical), and
* no vertex of the road's outer edge lies inside the box (deeper than ``TOL``). A road edge
  vertex is a lanelet vertex with a point ``PROBE`` away from it (along either adjacent edge's
  normal or the corner's bisector) that lies in no lanelet: the edge between two outline samples
  can only dip into the box through such a vertex (a straight edge crossing the box cuts off a
  corner or two, which the first rule sees).

Together these decide enclosure in the union buffered by ``TOL`` (a road edge is found by
its vertices' outside ``PROBE`` away; holes inside the union smaller than a car are not looked for), as the drivability checker's
``obb_enclosure_polygons_static`` does (the referee, ``jaxplan.eval.referee``).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxplan.geometry.boxes import box_corners
from jaxplan.sim.metrics.overlap import car_boxes
from jaxplan.sim.metrics.registry import register_metric
from jaxplan.sim.metrics.road import TOL, in_drivable

SPACING = 0.5
PROBE = 0.1  # m: how far from a vertex its outside is probed (> TOL, so seams are not edges)


def outline_points(boxes, spacing: float = SPACING, length=4.5, width=1.8):
    """Points ``(..., P, 2)`` along the outlines of boxes ``(..., 5)`` (corners included)."""
    c = box_corners(boxes)  # (..., 4, 2)
    pts = []
    for i in range(4):
        a, b = c[..., i, :], c[..., (i + 1) % 4, :]
        side = length if i % 2 == 0 else width  # corners run FL, RL, RR, FR: edges 0 and 2 are the long sides
        n = max(1, int(-(-side // spacing)))
        u = jnp.arange(n, dtype=boxes.dtype) / n
        pts.append(a[..., None, :] + u[:, None] * (b - a)[..., None, :])
    return jnp.concatenate(pts, axis=-2)


EDGE_VERTICES = 192  # lanelet vertices near the drive that are tested for the road's edge


def road_edge_vertices(scene, idx, use=None):
    """``(n,)`` bool: which of the lanelet vertices ``idx (n,)`` (indices into the flattened ``(M V)``
    outline vertices) lie on the outer edge of the drivable area (see the module docstring), and the
    count of lanelets left untested (``in_drivable``).

    ``use (n,)``: the vertices to test (default all); the others are False, and their probes are
    put on the first used vertex, so that lanelets far from every used vertex are skipped."""
    v, ok = scene.drivable, scene.drivable_valid  # (M, V, 2), (M, V)
    k = jnp.sum(ok, axis=-1, keepdims=True)
    pos = jnp.arange(v.shape[-2])
    nxt = jnp.take_along_axis(v, jnp.where(pos + 1 < k, pos + 1, 0)[..., None], axis=-2)
    prv = jnp.take_along_axis(v, jnp.where(pos > 0, pos - 1, k - 1)[..., None], axis=-2)
    flat = lambda a: a.reshape((-1,) + a.shape[2:])[idx]  # noqa: E731
    v, nxt, prv, ok = flat(v), flat(nxt), flat(prv), flat(ok)

    def unit(d):
        return d / jnp.maximum(jnp.linalg.norm(d, axis=-1, keepdims=True), 1e-9)

    e1, e2 = unit(v - prv), unit(nxt - v)
    perp = lambda d: jnp.stack([-d[..., 1], d[..., 0]], -1)  # noqa: E731
    dirs = jnp.stack([perp(e1), perp(e2), unit(e2 - e1)], -2)  # (n, 3, 2)
    probes = v[..., None, :] + PROBE * jnp.concatenate([dirs, -dirs], -2)  # (n, 6, 2)
    use = ok if use is None else ok & use
    probes = jnp.where(use[:, None, None], probes, v[jnp.argmax(use)])
    inside, unchecked = in_drivable(probes, scene)
    return use & jnp.any(~inside, axis=-1), unchecked


def offroad_steps(log, scene, vehicle):
    """``(N,)`` bool: the car's box is not enclosed by the drivable area at that step (within the drive).

    The road's edge is looked for among the ``EDGE_VERTICES`` lanelet vertices nearest the drive that
    lie within reach of the car's box (the others cannot touch it)."""
    return _offroad(log, scene, vehicle)[0]


def _offroad(log, scene, vehicle):
    """``offroad_steps`` and how much was left unchecked: vertices within reach beyond ``EDGE_VERTICES``,
    lanelets within reach beyond ``NEAR_LANELETS`` (0 normally)."""
    boxes = car_boxes(log, vehicle)
    pts = outline_points(boxes, SPACING, vehicle.length, vehicle.width)  # (N, P, 2)
    inside, unchecked_outline = in_drivable(pts, scene)
    out_pts = ~jnp.all(inside, axis=-1)
    verts = scene.drivable.reshape(-1, 2)
    vok = scene.drivable_valid.reshape(-1)
    reach = 0.5 * jnp.hypot(vehicle.length, vehicle.width) + PROBE

    def nearest(d2, b):  # the squared distance of every vertex to the nearest box centre of the drive
        d = jnp.sum((verts - b[:2]) ** 2, -1)
        return jnp.minimum(d2, jnp.where(b[5] > 0, d, jnp.inf)), None

    d2, _ = jax.lax.scan(
        nearest,
        jnp.full(verts.shape[:1], jnp.inf, verts.dtype),
        jnp.concatenate([boxes, log.valid[:, None].astype(boxes.dtype)], -1),
    )
    within = vok & (d2 <= reach**2)
    n = min(EDGE_VERTICES, verts.shape[0])
    _, idx = jax.lax.top_k(jnp.where(within, -d2, -jnp.inf), n)
    edge, unchecked_probes = road_edge_vertices(scene, idx, within[idx])  # (n,)
    c, s = jnp.cos(boxes[:, 4]), jnp.sin(boxes[:, 4])
    d = verts[idx][None] - boxes[:, None, :2]  # (N, n, 2)
    along = d[..., 0] * c[:, None] + d[..., 1] * s[:, None]
    across = -d[..., 0] * s[:, None] + d[..., 1] * c[:, None]
    # deeper than TOL: the referee's lanelets are buffered by that much
    dips = edge & (jnp.abs(along) < vehicle.length / 2 - TOL) & (jnp.abs(across) < vehicle.width / 2 - TOL)
    unchecked = jnp.maximum(jnp.sum(within) - n, 0) + unchecked_outline + unchecked_probes
    return (out_pts | jnp.any(dips, axis=-1)) & log.valid, unchecked


@register_metric("offroad")
def offroad(log, scene, vehicle):
    off, unchecked = _offroad(log, scene, vehicle)
    k = jnp.argmax(off)
    return {
        "offroad": jnp.any(off),
        "first_step": jnp.where(jnp.any(off), k, -1),
        "steps": jnp.sum(off),
        "unchecked": unchecked,
    }
