"""Convex polygons: separating-axis overlap, signed separation, intersection polygon, area.

Polygons are ``(..., N, 2)`` arrays of counter-clockwise vertices with an
optional ``(..., N)`` bool mask whose True entries form a prefix (padding at
the end). Leading dimensions of the two polygons broadcast against each other.
"""
from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp

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


def _mask(v, valid):
    return jnp.ones(v.shape[:-1], bool) if valid is None else jnp.asarray(valid, bool)


def _tol(*arrays):
    """Absolute length tolerance from the dtype and the coordinate scale."""
    dtype = jnp.result_type(*arrays)
    scale = 1.0 + sum(jnp.max(jnp.abs(a), axis=(-2, -1)) for a in arrays)
    return 64.0 * jnp.finfo(dtype).eps * scale


def polygon_edges(v, valid=None):
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
    d = jnp.einsum("...ik,...ijk->...ij", n, b[..., None, :, :] - a[..., :, None, :])
    d = jnp.where(vb[..., None, :], d, _BIG)
    per_edge = jnp.min(d, axis=-1)
    return jnp.max(jnp.where(ok, per_edge, -_BIG), axis=-1)


def separation(poly_a, poly_b, valid_a=None, valid_b=None):
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


def has_overlap(poly_a, poly_b, valid_a=None, valid_b=None):
    """Separating-axis overlap test of convex polygons; touching is not overlap.

    Returns:
        ``(...)`` bool.
    """
    return separation(poly_a, poly_b, valid_a, valid_b) < 0


def points_in_polygon(points, poly, valid=None, tol=0.0):
    """Whether points lie inside (or within ``tol`` of) a convex polygon.

    Args:
        points: ``(..., P, 2)``; poly: ``(..., N, 2)``; valid: ``(..., N)``.

    Returns:
        ``(..., P)`` bool.
    """
    poly = jnp.asarray(poly)
    _, n, ok = polygon_edges(poly, valid)
    d = jnp.einsum("...jk,...ijk->...ij", n, points[..., :, None, :] - poly[..., None, :, :])
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

    vertices: jnp.ndarray
    valid: jnp.ndarray
    source: jnp.ndarray
    index_a: jnp.ndarray
    index_b: jnp.ndarray


def overlap_polygon_tagged(poly_a, poly_b, valid_a=None, valid_b=None) -> OverlapPolygon:
    """Convex intersection polygon with every vertex tagged by where it comes from.

    Vertices of one polygon lying on the other's boundary count as inside and
    take the corner tag (A's before B's) rather than the crossing tag; points
    closer than a dtype-scaled tolerance are merged. An empty or degenerate
    (touching) intersection has fewer than 3 valid vertices and zero area.

    Args:
        poly_a: ``(..., N, 2)``; poly_b: ``(..., M, 2)``; masks ``(..., N)``, ``(..., M)``.

    Returns:
        ``OverlapPolygon`` with ``N + M`` vertex slots.
    """
    _check(poly_a, poly_b, valid_a, valid_b)
    a, b = jnp.asarray(poly_a), jnp.asarray(poly_b)
    dtype = jnp.result_type(a, b)
    a, b = a.astype(dtype), b.astype(dtype)
    lead = jnp.broadcast_shapes(a.shape[:-2], b.shape[:-2])
    a = jnp.broadcast_to(a, lead + a.shape[-2:])
    b = jnp.broadcast_to(b, lead + b.shape[-2:])
    va = jnp.broadcast_to(_mask(a, valid_a), a.shape[:-1])
    vb = jnp.broadcast_to(_mask(b, valid_b), b.shape[:-1])
    N, M = a.shape[-2], b.shape[-2]
    tol = _tol(a, b)

    in_b = points_in_polygon(a, b, vb, tol) & va  # (..., N)
    in_a = points_in_polygon(b, a, va, tol) & vb  # (..., M)

    # Edge-edge crossings: p + t r = q + u s.
    r, _, ok_a = polygon_edges(a, va)
    s, _, ok_b = polygon_edges(b, vb)
    p = a[..., :, None, :]
    rr = r[..., :, None, :]
    q = b[..., None, :, :]
    ss = s[..., None, :, :]
    qp = q - p

    def cross(u, v):
        return u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]

    den = cross(rr, ss)  # (..., N, M)
    lr = jnp.linalg.norm(rr, axis=-1)
    ls = jnp.linalg.norm(ss, axis=-1)
    par = jnp.abs(den) <= 1e-9 * lr * ls
    safe = jnp.where(par, 1.0, den)
    t = cross(qp, ss) / safe
    u = cross(qp, rr) / safe
    tt = tol[..., None, None] / jnp.maximum(lr, tol[..., None, None])
    tu = tol[..., None, None] / jnp.maximum(ls, tol[..., None, None])
    hit = (ok_a[..., :, None] & ok_b[..., None, :] & ~par
           & (t >= -tt) & (t <= 1 + tt) & (u >= -tu) & (u <= 1 + tu))
    xpt = p + jnp.clip(t, 0.0, 1.0)[..., None] * rr  # (..., N, M, 2)

    K = N + M + N * M
    pts = jnp.concatenate([a, b, xpt.reshape(lead + (N * M, 2))], axis=-2)
    ok = jnp.concatenate([in_b, in_a, hit.reshape(lead + (N * M,))], axis=-1)
    src = jnp.concatenate([jnp.full((N,), CORNER_OF_A), jnp.full((M,), CORNER_OF_B),
                           jnp.full((N * M,), EDGE_CROSSING)])
    ia = jnp.concatenate([jnp.arange(N), jnp.full((M,), -1), jnp.repeat(jnp.arange(N), M)])
    ib = jnp.concatenate([jnp.full((N,), -1), jnp.arange(M), jnp.tile(jnp.arange(M), N)])

    # Merge near-duplicates, keeping the first in (A corners, B corners, crossings) order.
    d2 = jnp.sum((pts[..., :, None, :] - pts[..., None, :, :]) ** 2, axis=-1)
    earlier = jnp.tril(jnp.ones((K, K), bool), k=-1)
    merge = (4 * tol[..., None, None]) ** 2
    dup = jnp.any((d2 <= merge) & earlier & ok[..., None, :], axis=-1)
    keep = ok & ~dup

    cnt = jnp.maximum(jnp.sum(keep, axis=-1, keepdims=True), 1)
    centre = jnp.sum(jnp.where(keep[..., None], pts, 0.0), axis=-2) / cnt
    rel = pts - centre[..., None, :]
    ang = jnp.arctan2(rel[..., 1], rel[..., 0])
    order = jnp.argsort(jnp.where(keep, ang, jnp.inf), axis=-1)[..., : N + M]

    def take(x):
        return jnp.take_along_axis(jnp.broadcast_to(x, lead + (K,)) if x.ndim == 1 else x, order, axis=-1)

    verts = jnp.take_along_axis(pts, order[..., None], axis=-2)
    return OverlapPolygon(verts, take(keep), take(src), take(ia), take(ib))


def overlap_polygon(poly_a, poly_b, valid_a=None, valid_b=None):
    """Convex intersection polygon of two convex polygons.

    Returns:
        (vertices ``(..., N+M, 2)`` counter-clockwise with valid ones first,
        valid ``(..., N+M)``). See ``overlap_polygon_tagged`` for the tags.
    """
    out = overlap_polygon_tagged(poly_a, poly_b, valid_a, valid_b)
    return out.vertices, out.valid


def polygon_area(vertices, valid=None):
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
