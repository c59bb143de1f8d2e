"""The geometry core against shapely on thousands of random convex pairs."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest

shapely = pytest.importorskip("shapely")

from jaxplan.geometry import (CORNER_OF_A, CORNER_OF_B, EDGE_CROSSING, box_corners, overlap_area,
                              overlap_polygon_tagged, polygon_area, separation)
from jaxplan.scenarios.shapes import edge_case_box_pairs, random_boxes, random_convex_polygons

N_RANDOM = 5000  # boxes and polygons each: 10,000 pairs in all, plus edge cases


def _pairs(seed=7):
    with jax.enable_x64(True):
        return _pairs64(seed)


def _pairs64(seed):
    rng = np.random.default_rng(seed)
    pa, ma = random_convex_polygons(rng, N_RANDOM)
    pb, mb = random_convex_polygons(rng, N_RANDOM)
    ba = box_corners(random_boxes(rng, N_RANDOM)).astype(np.float64)
    bb = box_corners(random_boxes(rng, N_RANDOM)).astype(np.float64)
    edge = np.asarray(box_corners(edge_case_box_pairs()), np.float64)
    # Boxes padded to 8 vertices so that one batch holds everything.
    pad = lambda x: np.concatenate([x, np.repeat(x[:, -1:], 4, axis=1)], axis=1)
    m4 = np.concatenate([np.ones((1, 4), bool), np.zeros((1, 4), bool)], 1)
    a = np.concatenate([pa, pad(np.asarray(ba)), pad(edge[:, 0]), pa[:500]])
    b = np.concatenate([pb, pad(np.asarray(bb)), pad(edge[:, 1]), pa[:500]])  # identical polygons too
    n_box = N_RANDOM + len(edge)
    va = np.concatenate([ma, np.repeat(m4, n_box, 0), ma[:500]])
    vb = np.concatenate([mb, np.repeat(m4, n_box, 0), ma[:500]])
    return a, va, b, vb


def _shapely(a, va):
    out = np.empty(len(a), dtype=object)
    out[:] = [shapely.Polygon(p[m]) for p, m in zip(a, va)]
    return out


@pytest.fixture(scope="module")
def oracle():
    a, va, b, vb = _pairs()
    A, B = _shapely(a, va), _shapely(b, vb)
    inter = shapely.intersection(A, B)
    interior = shapely.relate_pattern(A, B, "T********")
    deep = shapely.relate_pattern(shapely.buffer(A, -1e-6, join_style="mitre"), B, "T********")
    dist = shapely.distance(A, B)
    return dict(a=a, va=va, b=b, vb=vb, area=shapely.area(inter), inter=inter,
                interior=interior, deep=deep, dist=dist)


_tagged = jax.jit(overlap_polygon_tagged)
_sep = jax.jit(separation)
_area = jax.jit(overlap_area)


@pytest.mark.parametrize("x64,band", [(True, 1e-6), (False, 1e-4)])
def test_has_overlap_matches_shapely(oracle, x64, band):
    with jax.enable_x64(x64):
        dtype = jnp.float64 if x64 else jnp.float32
        a, b = jnp.asarray(oracle["a"], dtype), jnp.asarray(oracle["b"], dtype)
        sep = np.asarray(_sep(a, b, oracle["va"], oracle["vb"]))
    ours = sep < 0
    truth = oracle["interior"]
    # Ambiguous only within `band` of touching: shapely distance below band while
    # apart, or an overlap that vanishes when A shrinks by the band.
    if x64:
        ambiguous = (~truth & (oracle["dist"] < band)) | (truth & ~oracle["deep"])
    else:
        ambiguous = np.abs(sep) < band
    agree = ours == truth
    assert len(truth) >= 10_000
    assert np.all(agree | ambiguous), np.nonzero(~(agree | ambiguous))[0][:10]
    assert truth.sum() > 1000 and (~truth).sum() > 1000  # both classes well represented
    # Apart: separation is a lower bound on the true distance.
    apart = ~truth & (oracle["dist"] > band)
    assert np.all(sep[apart] <= oracle["dist"][apart] + 1e-4)


@pytest.mark.parametrize("x64,rtol", [(True, 1e-5), (False, 1e-3)])
def test_overlap_area_matches_shapely(oracle, x64, rtol):
    with jax.enable_x64(x64):
        dtype = jnp.float64 if x64 else jnp.float32
        out = _tagged(jnp.asarray(oracle["a"], dtype), jnp.asarray(oracle["b"], dtype),
                      oracle["va"], oracle["vb"])
        area_poly = np.asarray(polygon_area(out.vertices, out.valid))
        area_fast = np.asarray(_area(jnp.asarray(oracle["a"], dtype), jnp.asarray(oracle["b"], dtype),
                                     oracle["va"], oracle["vb"]))
    ref = oracle["area"]
    big = ref > 1e-3
    assert big.sum() > 1000
    for area in (area_poly, area_fast):
        rel = np.abs(area[big] - ref[big]) / ref[big]
        assert rel.max() < rtol, (rel.max(), np.argmax(rel))
        # No area where shapely finds none.
        assert np.all(area[ref == 0] < (1e-6 if x64 else 1e-3))


def test_overlap_vertices_and_tags_match_shapely(oracle):
    with jax.enable_x64(True):
        out = _tagged(jnp.asarray(oracle["a"]), jnp.asarray(oracle["b"]), oracle["va"], oracle["vb"])
        out = jax.tree_util.tree_map(np.asarray, out)
    checked = 0
    for i in np.nonzero(oracle["area"] > 1e-3)[0][:1500]:
        ours = out.vertices[i][out.valid[i]]
        theirs = np.asarray(shapely.simplify(oracle["inter"][i], 1e-9).exterior.coords)[:-1]
        d = np.linalg.norm(ours[:, None] - theirs[None], axis=-1)
        assert d.min(1).max() < 1e-6 and d.min(0).max() < 1e-6, i
        # Counter-clockwise: positive signed area.
        x, y = ours[:, 0], ours[:, 1]
        assert np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y) > 0
        a = oracle["a"][i][oracle["va"][i]]
        b = oracle["b"][i][oracle["vb"][i]]
        for v, src, ia, ib in zip(ours, out.source[i][out.valid[i]], out.index_a[i][out.valid[i]],
                                  out.index_b[i][out.valid[i]]):
            if src == CORNER_OF_A:
                assert np.allclose(v, a[ia])
            elif src == CORNER_OF_B:
                assert np.allclose(v, b[ib])
            else:
                assert src == EDGE_CROSSING
                ea = shapely.LineString([a[ia], a[(ia + 1) % len(a)]])
                eb = shapely.LineString([b[ib], b[(ib + 1) % len(b)]])
                pt = shapely.Point(v)
                assert ea.distance(pt) < 1e-7 and eb.distance(pt) < 1e-7
        checked += 1
    assert checked >= 1000


def test_box_half_extents_are_half_the_projected_lengths_of_shapely_boxes():
    """``box_half_extents`` against shapely: a box's polygon rotated so that ``heading`` is the x
    axis; its bounds' half width and half height, for 2,000 random boxes and headings."""
    from shapely import affinity

    from jaxplan.geometry import box_half_extents

    rng = np.random.default_rng(3)
    boxes = np.column_stack([rng.uniform(-50, 50, 2000), rng.uniform(-50, 50, 2000), rng.uniform(0.5, 12, 2000),
                             rng.uniform(0.5, 3, 2000), rng.uniform(-4, 4, 2000)])
    heading = rng.uniform(-4, 4, 2000)
    got = np.asarray(box_half_extents(jnp.asarray(boxes, jnp.float32), jnp.asarray(heading, jnp.float32)))
    for b, h, g in zip(boxes, heading, got):
        x, y, L, W, th = b
        poly = affinity.rotate(shapely.box(-L / 2, -W / 2, L / 2, W / 2), th - h, origin=(0, 0), use_radians=True)
        x0, y0, x1, y1 = poly.bounds
        np.testing.assert_allclose(g, [0.5 * (x1 - x0), 0.5 * (y1 - y0)], atol=2e-5 * max(L, 1.0))
