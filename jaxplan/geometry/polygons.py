"""Convex polygons: separating-axis overlap, signed separation, intersection polygon, area.

Polygons are ``(..., N, 2)`` arrays of counter-clockwise vertices with an
optional ``(..., N)`` bool mask whose True entries form a prefix (padding at
the end). Leading dimensions of the two polygons broadcast against each other.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Bool, Float, Int

from jaxplan.types import check_polygons, is_concrete

# Where a vertex of the overlap polygon comes from.
CORNER_OF_A = 0  # a vertex of A inside (or on) B
CORNER_OF_B = 1  # a vertex of B inside (or on) A
EDGE_CROSSING = 2  # an edge of A crosses an edge of B

_BIG = 1e30


def _check(poly_a, poly_b, valid_a, valid_b):
    """Host-side input checks, run only outside jit (on concrete arrays)."""
    if is_concrete(poly_a, poly_b, valid_a, valid_b):
        check_polygons(poly_a, valid_a, "poly_a")
        check_polygons(poly_b, valid_b, "poly_b")


def _dot(u, v):
    """Dot product over a trailing axis of 2, by broadcasting (faster than einsum here)."""
    return u[..., 0] * v[..., 0] + u[..., 1] * v[..., 1]


def _mask(v, valid):
    return jnp.ones(v.shape[:-1], bool) if valid is None else jnp.asarray(valid, bool)


def _tol(*arrays):
    """Absolute length tolerance from the dtype and the coordinate scale."""
    dtype = jnp.result_type(*arrays)
    scale = 1.0 + sum(jnp.max(jnp.abs(a), axis=(-2, -1)) for a in arrays)
    return 64.0 * jnp.finfo(dtype).eps * scale


@jax.jit
def polygon_edges(
    v: Float[ArrayLike, "... N 2"], valid: Bool[ArrayLike, "... N"] | None = None
) -> tuple[Float[Array, "... N 2"], Float[Array, "... N 2"], Bool[Array, "... N"]]:
    """Edges of padded convex polygons.

    Args:
        v: ``(..., N, 2)`` vertices; valid: ``(..., N)`` or None.

    Returns:
        (edge vectors ``(..., N, 2)`` from vertex i to the next valid vertex,
        unit outward normals ``(..., N, 2)``, edge mask ``(..., N)``).
    """
    v = jnp.asarray(v)
    valid = _mask(v, valid)
    n = v.shape[-2]
    idx = jnp.arange(n)
    nxt_ok = jnp.roll(valid, -1, axis=-1) & (idx < n - 1)
    nxt = jnp.where(nxt_ok, idx + 1, 0)
    e = jnp.take_along_axis(v, nxt[..., None], axis=-2) - v
    length = jnp.linalg.norm(e, axis=-1)
    ok = valid & (length > 0)
    safe = jnp.where(ok, length, 1.0)[..., None]
    normal = jnp.stack([e[..., 1], -e[..., 0]], axis=-1) / safe
    return e, normal, ok


def _max_separation(a, va, b, vb):
    """Largest gap of B beyond an edge of A, over A's edges. Shape ``(...)``."""
    _, n, ok = polygon_edges(a, va)
    # d[..., i, j] = <n_i, b_j - a_i>
    d = _dot(n[..., :, None, :], b[..., None, :, :] - a[..., :, None, :])
    d = jnp.where(vb[..., None, :], d, _BIG)
    per_edge = jnp.min(d, axis=-1)
    return jnp.max(jnp.where(ok, per_edge, -_BIG), axis=-1)


def separation(
    poly_a: Float[ArrayLike, "... N 2"],
    poly_b: Float[ArrayLike, "... M 2"],
    valid_a: Bool[ArrayLike, "... N"] | None = None,
    valid_b: Bool[ArrayLike, "... M"] | None = None,
) -> Float[Array, " ..."]:
    """Signed separation of convex polygons along the best separating axis.

    Positive: the polygons are apart by at least this much (exact when the
    closest features are an edge and a vertex). Negative: minus the penetration
    depth, i.e. the shortest translation that separates them (exact for convex
    polygons). Piecewise smooth in the vertices.

    Args:
        poly_a: ``(..., N, 2)``; poly_b: ``(..., M, 2)``; masks ``(..., N)``, ``(..., M)``.

    Returns:
        ``(...)``.
    """
    _check(poly_a, poly_b, valid_a, valid_b)
    a, b = jnp.asarray(poly_a), jnp.asarray(poly_b)
    dtype = jnp.result_type(a, b)
    a, b = a.astype(dtype), b.astype(dtype)
    va, vb = _mask(a, valid_a), _mask(b, valid_b)
    return jnp.maximum(_max_separation(a, va, b, vb), _max_separation(b, vb, a, va))


def has_overlap(
    poly_a: Float[ArrayLike, "... N 2"],
    poly_b: Float[ArrayLike, "... M 2"],
    valid_a: Bool[ArrayLike, "... N"] | None = None,
    valid_b: Bool[ArrayLike, "... M"] | None = None,
) -> Bool[Array, " ..."]:
    """Separating-axis overlap test of convex polygons; touching is not overlap.

    Returns:
        ``(...)`` bool.
    """
    return separation(poly_a, poly_b, valid_a, valid_b) < 0


def points_in_polygon(
    points: Float[Array, "... P 2"],
    poly: Float[ArrayLike, "... N 2"],
    valid: Bool[ArrayLike, "... N"] | None = None,
    tol=0.0,
) -> Bool[Array, "... P"]:
    """Whether points lie inside (or within ``tol`` of) a convex polygon.

    Args:
        points: ``(..., P, 2)``; poly: ``(..., N, 2)``; valid: ``(..., N)``.

    Returns:
        ``(..., P)`` bool.
    """
    poly = jnp.asarray(poly)
    _, n, ok = polygon_edges(poly, valid)
    d = _dot(n[..., None, :, :], points[..., :, None, :] - poly[..., None, :, :])
    tol = jnp.asarray(tol)[..., None, None]
    return jnp.all(jnp.where(ok[..., None, :], d <= tol, True), axis=-1)


class OverlapPolygon(NamedTuple):
    """Intersection of two convex polygons, counter-clockwise, valid vertices first.

    Attributes:
        vertices: ``(..., N+M, 2)``.
        valid: ``(..., N+M)`` bool.
        source: ``(..., N+M)`` int, one of CORNER_OF_A, CORNER_OF_B, EDGE_CROSSING.
        index_a: ``(..., N+M)`` the vertex of A (CORNER_OF_A) or the edge of A
            (EDGE_CROSSING, edge i runs from vertex i to the next); -1 otherwise.
        index_b: ``(..., N+M)`` likewise for B.
    """

    vertices: Float[Array, "... N+M 2"]
    valid: Bool[Array, "... N+M"]
    source: Int[Array, "... N+M"]
    index_a: Int[Array, "... N+M"]
    index_b: Int[Array, "... N+M"]


def _pseudo_angle(d):
    """A cheap monotone stand-in for atan2 over ``(..., 2)``: values in [0, 4)."""
    x, y = d[..., 0], d[..., 1]
    r = jnp.abs(x) + jnp.abs(y)
    r = jnp.where(r > 0, r, 1.0)
    p = x / r  # in [-1, 1], decreasing with the angle on the upper half
    return jnp.where(y >= 0, 1.0 - p, 3.0 + p)


def _prepare(poly_a, poly_b, valid_a, valid_b):
    a, b = jnp.asarray(poly_a), jnp.asarray(poly_b)
    dtype = jnp.result_type(a, b)
    a, b = a.astype(dtype), b.astype(dtype)
    lead = jnp.broadcast_shapes(a.shape[:-2], b.shape[:-2])
    a = jnp.broadcast_to(a, lead + a.shape[-2:])
    b = jnp.broadcast_to(b, lead + b.shape[-2:])
    va = jnp.broadcast_to(_mask(a, valid_a), a.shape[:-1])
    vb = jnp.broadcast_to(_mask(b, valid_b), b.shape[:-1])
    return a, va, b, vb, _tol(a, b)


def _clip_edges(p, vp, q, vq, tol, keep_shared):
    """Clip every edge of convex P to convex Q (Cyrus-Beck).

    An edge lying on Q's boundary with the same outward side is kept only when
    ``keep_shared`` (so a shared boundary is counted once, for A); one lying on
    Q's boundary facing the other way (the polygons only touch) is dropped.

    Returns:
        (edges ``(..., N, 2)``, t_in, t_out ``(..., N)``, kept ``(..., N)``,
        index of Q's edge that bounds the entry ``(..., N)``).
    """
    e, n_p, ok_p = polygon_edges(p, vp)
    _, n_q, ok_q = polygon_edges(q, vq)
    # Signed distances of each edge's two ends beyond each of Q's edge lines,
    # snapped to 0 within tol so that collinear and touching cases are exact.
    nq = n_q[..., None, :, :]
    d0 = _dot(nq, p[..., :, None, :] - q[..., None, :, :])  # (..., N, M)
    d1 = d0 + _dot(nq, e[..., :, None, :])
    tl = tol[..., None, None]
    z0, z1 = jnp.abs(d0) <= tl, jnp.abs(d1) <= tl
    s0, s1 = jnp.where(z0, 0.0, d0), jnp.where(z1, 0.0, d1)
    okq = ok_q[..., None, :]
    on_line = okq & z0 & z1
    outside = okq & ~(z0 & z1) & (s0 >= 0) & (s1 >= 0)
    enter = okq & (s0 > 0) & (s1 < 0)
    leave = okq & (s0 < 0) & (s1 > 0)
    tq = s0 / jnp.where(enter | leave, s0 - s1, 1.0)
    t_enter = jnp.where(enter, tq, -_BIG)
    t_in = jnp.maximum(jnp.max(t_enter, axis=-1), 0.0)
    t_out = jnp.minimum(jnp.min(jnp.where(leave, tq, _BIG), axis=-1), 1.0)
    same_side = _dot(n_p[..., :, None, :], nq) > 0
    blocked = outside | (on_line & ~(same_side & keep_shared))
    kept = ok_p & ~jnp.any(blocked, axis=-1) & (t_out > t_in)
    return e, t_in, t_out, kept, jnp.argmax(t_enter, axis=-1)


def overlap_area(
    poly_a: Float[ArrayLike, "... N 2"],
    poly_b: Float[ArrayLike, "... M 2"],
    valid_a: Bool[ArrayLike, "... N"] | None = None,
    valid_b: Bool[ArrayLike, "... M"] | None = None,
) -> Float[Array, " ..."]:
    """Area of the intersection of convex polygons, without building the polygon.

    The boundary of A-and-B is A's edges clipped to B plus B's edges clipped to
    A; the area is the sum of their shoelace terms. Fast and differentiable.

    Args:
        poly_a: ``(..., N, 2)``; poly_b: ``(..., M, 2)``; masks ``(..., N)``, ``(..., M)``.

    Returns:
        ``(...)``.
    """
    _check(poly_a, poly_b, valid_a, valid_b)
    a, va, b, vb, tol = _prepare(poly_a, poly_b, valid_a, valid_b)
    c = a[..., :1, :]  # shoelace about a nearby point, for precision
    total: float | Array = 0.0
    for p, vp, q, vq, first in ((a, va, b, vb, True), (b, vb, a, va, False)):
        e, t_in, t_out, kept, _ = _clip_edges(p, vp, q, vq, tol, first)
        p0 = p - c + t_in[..., None] * e
        p1 = p - c + t_out[..., None] * e
        cr = p0[..., 0] * p1[..., 1] - p0[..., 1] * p1[..., 0]
        total = total + 0.5 * jnp.sum(jnp.where(kept, cr, 0.0), axis=-1)
    return jnp.maximum(total, 0.0)


def overlap_polygon_tagged(
    poly_a: Float[ArrayLike, "... N 2"],
    poly_b: Float[ArrayLike, "... M 2"],
    valid_a: Bool[ArrayLike, "... N"] | None = None,
    valid_b: Bool[ArrayLike, "... M"] | None = None,
) -> OverlapPolygon:
    """Convex intersection polygon with every vertex tagged by where it comes from.

    Each vertex is the start of one boundary piece: an edge of A clipped to B or
    an edge of B clipped to A. A piece starting at its own polygon's vertex gives
    a corner tag (a vertex on the other's boundary counts as inside), one
    starting where it enters the other polygon gives EDGE_CROSSING. A shared
    boundary is A's. Points closer than a dtype-scaled tolerance are merged.
    An empty or touching intersection has fewer than 3 valid vertices.

    Args:
        poly_a: ``(..., N, 2)``; poly_b: ``(..., M, 2)``; masks ``(..., N)``, ``(..., M)``.

    Returns:
        ``OverlapPolygon`` with ``N + M`` vertex slots.
    """
    _check(poly_a, poly_b, valid_a, valid_b)
    a, va, b, vb, tol = _prepare(poly_a, poly_b, valid_a, valid_b)
    N, M = a.shape[-2], b.shape[-2]
    parts = []
    for p, vp, q, vq, first in ((a, va, b, vb, True), (b, vb, a, va, False)):
        e, t_in, t_out, kept, j = _clip_edges(p, vp, q, vq, tol, first)
        tl = tol[..., None]
        length = jnp.maximum(jnp.linalg.norm(e, axis=-1), tl)
        kept = kept & ((t_out - t_in) * length > tl)
        corner = t_in * length <= tl
        own = jnp.broadcast_to(jnp.arange(p.shape[-2]), kept.shape)
        other = jnp.where(corner, -1, j)
        src = jnp.where(corner, CORNER_OF_A if first else CORNER_OF_B, EDGE_CROSSING)
        ia, ib = (own, other) if first else (other, own)
        parts.append((p + t_in[..., None] * e, kept, src, ia, ib))
    (pa, ka, sa, iaa, iba), (pb, kb, sb, iab, ibb) = parts
    pts = jnp.concatenate([pa, pb], axis=-2)
    ok = jnp.concatenate([ka, kb], axis=-1)
    src = jnp.concatenate([sa, sb], axis=-1)
    ia = jnp.concatenate([iaa, iab], axis=-1)
    ib = jnp.concatenate([iba, ibb], axis=-1)
    K = N + M
    # Merge B's pieces that start where one of A's does (degenerate contacts only).
    d2 = jnp.sum((pb[..., :, None, :] - pa[..., None, :, :]) ** 2, axis=-1)  # (..., M, N)
    dup = jnp.any((d2 <= (4 * tol[..., None, None]) ** 2) & ka[..., None, :], axis=-1)
    keep = ok & ~jnp.concatenate([jnp.zeros_like(ka), dup], axis=-1)
    # Counter-clockwise order: rank by angle about the mean (pairwise ranks, no sort).
    cnt = jnp.maximum(jnp.sum(keep, axis=-1, keepdims=True), 1)
    centre = jnp.sum(jnp.where(keep[..., None], pts, 0.0), axis=-2) / cnt
    key = jnp.where(keep, _pseudo_angle(pts - centre[..., None, :]), 10.0)
    idx = jnp.arange(K)
    before = (key[..., None, :] < key[..., :, None]) | (
        (key[..., None, :] == key[..., :, None]) & (idx[None, :] < idx[:, None])
    )
    rank = jnp.sum(before, axis=-1)  # (..., K), a permutation
    # order[r] = the element of rank r (inverse permutation), then gather.
    order = jnp.sum(jnp.where(rank[..., :, None] == idx, idx[:, None], 0), axis=-2)

    def place(x):
        return jnp.take_along_axis(x, order, axis=-1)

    verts = jnp.take_along_axis(pts, order[..., None], axis=-2)
    return OverlapPolygon(
        verts, place(keep), place(src).astype(jnp.int32), place(ia).astype(jnp.int32), place(ib).astype(jnp.int32)
    )


def overlap_polygon(
    poly_a: Float[ArrayLike, "... N 2"],
    poly_b: Float[ArrayLike, "... M 2"],
    valid_a: Bool[ArrayLike, "... N"] | None = None,
    valid_b: Bool[ArrayLike, "... M"] | None = None,
) -> tuple[Float[Array, "... N+M 2"], Bool[Array, "... N+M"]]:
    """Convex intersection polygon of two convex polygons.

    Returns:
        (vertices ``(..., N+M, 2)`` counter-clockwise with valid ones first,
        valid ``(..., N+M)``). See ``overlap_polygon_tagged`` for the tags.
    """
    out = overlap_polygon_tagged(poly_a, poly_b, valid_a, valid_b)
    return out.vertices, out.valid


def polygon_area(
    vertices: Float[ArrayLike, "... N 2"], valid: Bool[ArrayLike, "... N"] | None = None
) -> Float[Array, " ..."]:
    """Area of polygons by the shoelace formula (positive when counter-clockwise).

    Args:
        vertices: ``(..., N, 2)``; valid: ``(..., N)`` prefix mask or None.

    Returns:
        ``(...)``; 0 for fewer than 3 valid vertices.
    """
    v = jnp.asarray(vertices)
    e, _, _ = polygon_edges(v, valid)
    m = _mask(v, valid)
    nxt = v + e
    cr = v[..., 0] * nxt[..., 1] - v[..., 1] * nxt[..., 0]
    area = 0.5 * jnp.sum(jnp.where(m, cr, 0.0), axis=-1)
    return jnp.where(jnp.sum(m, axis=-1) >= 3, area, 0.0)


def points_in_simple_polygon(
    points: Float[ArrayLike, "... P 2"],
    poly: Float[ArrayLike, "... N 2"],
    valid: Bool[ArrayLike, "... N"] | None = None,
    tol=0.0,
) -> Bool[Array, "... P"]:
    """Whether points lie inside a simple (possibly non-convex) polygon, or within ``tol`` of its boundary.

    The even-odd (crossing-number) rule with half-open edges, so a point on an edge shared
    by two polygons that list it with the same vertices is inside exactly one of them.

    Args:
        points: ``(..., P, 2)``.
        poly: ``(..., N, 2)`` vertices in either orientation; valid: ``(..., N)`` prefix mask.
        tol: metres; points this close to an edge count as inside (seams between polygons
            whose shared edge is not vertex-identical).

    Returns:
        ``(..., P)`` bool.
    """
    poly = jnp.asarray(poly)
    points = jnp.asarray(points, poly.dtype)
    n = poly.shape[-2]
    valid = jnp.ones(poly.shape[:-1], bool) if valid is None else jnp.asarray(valid, bool)
    k = jnp.sum(valid, axis=-1, keepdims=True)  # (..., 1)
    idx = jnp.arange(n)
    nxt = jnp.where(idx + 1 < k, idx + 1, 0)
    a = poly
    b = jnp.take_along_axis(poly, nxt[..., None], axis=-2)
    a, b, ok = a[..., None, :, :], b[..., None, :, :], valid[..., None, :]  # (..., 1, N, 2)
    p = points[..., :, None, :]  # (..., P, 1, 2)
    ay, by = a[..., 1], b[..., 1]
    straddle = (ay > p[..., 1]) != (by > p[..., 1])
    dy = jnp.where(by == ay, 1.0, by - ay)
    xc = a[..., 0] + (p[..., 1] - ay) * (b[..., 0] - a[..., 0]) / dy
    cross = ok & straddle & (xc > p[..., 0])
    inside = (jnp.sum(cross, axis=-1) % 2) == 1
    if tol:
        d = b - a
        L2 = jnp.maximum(jnp.sum(d * d, -1), 1e-12)
        u = jnp.clip(jnp.sum((p - a) * d, -1) / L2, 0.0, 1.0)
        dist = jnp.linalg.norm(p - (a + u[..., None] * d), axis=-1)
        near = jnp.any(ok & (dist <= tol), axis=-1)
        inside = inside | near
    return inside
