"""Park-out planner: circles, radii, transforms, footprint check, pure pursuit, rules, loop."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import shapely

import jaxplan.parking as pk
from jaxplan.geometry import box_corners
from jaxplan.types import VehicleParams
from parking_oracle import collisions

CAR = VehicleParams()
CFG = pk.ParkoutConfig()
R = float(pk.turning_radius(CAR))
D = float(pk.stop_line(CAR, CFG.c))
H = CFG.cell


def row_of(y):
    """Grid row whose cells start at ``y`` (grid at the slot frame's origin)."""
    return int(round((y - CFG.y_min) / H))


def col_of(x):
    return int(round((x - CFG.x_min) / H))



@jax.jit
def _rollout_grid(poses, curves, cells):
    """Rollouts ``(B,)`` along curves on one grid read at the origin."""
    tab = pk.cell_table(cells)
    hits = lambda q: pk.footprint_hits_grid(tab, jnp.zeros(3), q, CAR, CFG)  # noqa: E731
    return jax.vmap(lambda p, c: pk.rollout(p, c, hits, CAR, CFG))(poses, curves)


EMPTY = jnp.zeros((CFG.rows, CFG.cols), bool)


@jax.jit
def _box_vs_poly(cells, gp, poses):
    tab = pk.cell_table(cells)
    boxes = pk.footprint_boxes(poses, CAR, CFG.margin)
    return (pk.box_covers_occupied(tab, gp, boxes, CFG),
            pk.polygon_covers_occupied(tab, gp, box_corners(boxes), CFG))
_forward = jax.jit(jax.vmap(lambda p: pk.forward_curve(p, R, D)))
_points = jax.jit(jax.vmap(pk.curve_point))
_circles = jax.jit(lambda p: pk.reference_circles(p, R, D))


def _random_poses(rng, n, spread=(3.0, 1.5, 0.6)):
    return (rng.uniform(-1, 1, (n, 3)) * np.asarray(spread)).astype(np.float32)


def test_radii_closed_forms():
    assert np.isclose(R, CAR.wheelbase / np.tan(CAR.max_steer), rtol=1e-6)
    # the outer front corner rotating about O3 = (0, R), brute force
    corner = np.asarray(box_corners(pk.footprint_boxes(jnp.zeros(3), CAR)))[3]  # front-right
    assert np.isclose(np.hypot(corner[0], corner[1] - R), float(pk.front_corner_radius(CAR)), rtol=1e-5)


def test_min_front_gap_matches_swept_footprint():
    """The analytic gap equals the smallest gap that the footprint swept on O3 clears."""
    for m, cy in ((0.0, 0.95), (0.1, 0.95), (0.1, 1.2)):
        th = np.linspace(0, np.pi / 2, 2000)
        poses = np.stack([R * np.sin(th), R - R * np.cos(th), th], -1)
        corners = np.asarray(box_corners(pk.footprint_boxes(jnp.asarray(poses), CAR, m)))
        swept = shapely.union_all(shapely.polygons(corners))
        a = CAR.wheelbase + CAR.front_overhang
        xs = a + np.arange(0.5, 3.5, 0.002)
        hit = shapely.contains_xy(swept, xs, np.full_like(xs, cy))
        brute = xs[np.nonzero(hit)[0].max() + 1] - a
        assert abs(brute - float(pk.min_front_gap(CAR, m, cy))) < 0.01


def test_reference_circles_and_tangencies(rng):
    poses = _random_poses(rng, 200)
    centres, tp = map(np.asarray, _circles(jnp.asarray(poses)))
    x, y, th = poses.T
    assert np.allclose(centres[:, 2], np.stack([x - R * np.sin(th), y + R * np.cos(th)], -1), atol=1e-5)
    assert np.allclose(centres[:, 1], np.stack([x + R * np.sin(th), y - R * np.cos(th)], -1), atol=1e-5)
    assert np.allclose(centres[:, 0, 1], D - R, atol=1e-5)  # O1 tangent to y = d
    assert np.allclose(np.linalg.norm(centres[:, 0] - centres[:, 2], axis=-1), 2 * R, atol=1e-4)  # O1 touches O3
    assert np.allclose(np.linalg.norm(tp - centres[:, 2], axis=-1), R, atol=1e-4)
    assert np.allclose(np.linalg.norm(tp - centres[:, 0], axis=-1), R, atol=1e-4)


def test_forward_curve_is_tangent_chain(rng):
    poses = _random_poses(rng, 100, (2.0, 0.5, 0.5))
    c = _forward(jnp.asarray(poses))
    centres, tp = map(np.asarray, _circles(jnp.asarray(poses)))
    start, length = np.asarray(c.start), np.asarray(c.length)
    normal = np.asarray(c.length[:, 0]) > 1e-3  # not the 'already past the tangent point' fallback
    assert normal.mean() > 0.8
    assert np.allclose(start[normal, 1, :2], tp[normal], atol=2e-3)  # arc O3 ends at the tangent point
    end = np.asarray(_points(c, c.end))
    assert np.allclose(end[normal, :2], np.stack([centres[normal, 0, 0], np.full(normal.sum(), D)], -1), atol=2e-3)
    assert np.allclose(np.cos(end[normal, 2]), 1.0, atol=1e-5)  # level at the stop line
    # every point of the O3 / O1 parts lies on its circle
    s = np.linspace(0, 1, 7)[None, :]
    pts3 = np.asarray(_points(c, jnp.asarray(s * length[:, :1])))
    pts1 = np.asarray(_points(c, jnp.asarray(length[:, :1] + s * length[:, 1:2])))
    assert np.allclose(np.linalg.norm(pts3[..., :2] - centres[:, None, 2], axis=-1)[normal], R, atol=2e-3)
    assert np.allclose(np.linalg.norm(pts1[..., :2] - centres[:, None, 0], axis=-1)[normal], R, atol=2e-3)


def test_backward_curve_rules():
    b = pk.backward_curve(jnp.array([0.3, 0.2, np.radians(3.0)]), R, CFG.theta1, CFG.theta2, CFG.back_cap)
    assert np.isclose(float(b.end), CFG.back_cap) and np.allclose(np.asarray(b.start[0]), [0.3, 0.0, np.pi], atol=1e-6)
    th = np.radians(20.0)
    b = pk.backward_curve(jnp.array([0.3, 0.2, th]), R, CFG.theta1, CFG.theta2, CFG.back_cap)
    end = np.asarray(pk.curve_point(b, b.end))
    assert np.isclose(end[2] - np.pi, CFG.theta2, atol=1e-5)  # heading reaches theta2
    o2 = np.array([0.3 + R * np.sin(th), 0.2 - R * np.cos(th)])
    assert np.isclose(np.linalg.norm(end[:2] - o2), R, atol=1e-4)  # on O2


@jax.jit
def _transforms(pose, xy, other):
    rc = pk.world_to_cell(pose, xy, CFG)
    return (pk.from_frame(pose, pk.to_frame(pose, xy)), pk.compose(pose, pk.relative(pose, other)),
            pk.cell_to_world(pose, rc, CFG), pk.world_to_cell(pose, pose[:, :2], CFG),
            pk.world_to_cell(pose[0], pk.from_frame(pose[0], pk.cell_centres(CFG)[3, 7]), CFG))


def test_transforms_round_trip(rng):
    pose = jnp.asarray(_random_poses(rng, 50, (5, 5, 3)))
    xy = jnp.asarray(rng.uniform(-8, 8, (50, 2)).astype(np.float32))
    other = jnp.asarray(_random_poses(rng, 50, (5, 5, 3)))
    xy2, back, xy3, rc0, rc37 = map(np.asarray, _transforms(pose, xy, other))
    assert np.allclose(xy2, xy, atol=1e-5)
    assert np.allclose(back[:, :2], other[:, :2], atol=1e-5)
    assert np.allclose(np.cos(back[:, 2] - other[:, 2]), 1, atol=1e-6)
    assert np.allclose(xy3, xy, atol=1e-4)
    assert np.all(np.floor(rc0) == [row_of(0.0), col_of(0.0)])  # the grid's pose sits at (x, y) = 0
    assert np.allclose(rc37, [3.5, 7.5], atol=1e-3)


def _virtual_centres(band=6.0):
    """Centres of the cells of the lattice extended ``band`` metres beyond the grid, outside the grid."""
    k = int(band / H)
    r, c = np.meshgrid(np.arange(-k, CFG.rows + k), np.arange(-k, CFG.cols + k), indexing="ij")
    out = (r < 0) | (r >= CFG.rows) | (c < 0) | (c >= CFG.cols)
    return np.stack([CFG.x_min + (c[out] + 0.5) * H, CFG.y_min + (r[out] + 0.5) * H], -1)


def test_footprint_check_matches_shapely(rng):
    """Box slab scan and polygon scan both equal shapely's cell-centre containment, where the cells
    beyond the grid count as occupied (a footprint reaching past the grid is a hit)."""
    bad, hits, beyond = 0, 0, 0
    virtual = shapely.STRtree(shapely.points(_virtual_centres()))  # in the grid's own frame

    def contained(tree, polys):
        strict = np.zeros(len(polys), bool)
        loose = np.zeros(len(polys), bool)
        strict[tree.query(polys, predicate="contains_properly")[0]] = True
        loose[tree.query(polys, predicate="intersects")[0]] = True
        return strict, loose

    for density in (3e-4, 2e-3):
        for _ in range(4):
            cells = rng.random((CFG.rows, CFG.cols)) < density
            gp = jnp.asarray(rng.normal(size=3) * [1, 1, 0.3], jnp.float32)
            poses = _random_poses(rng, 64, (14, 6, 3.2)) + np.array([2.0, 2.0, 0.0], np.float32)
            poses[:4, 2] = float(gp[2]) + np.array([0, np.pi / 2, np.pi, 1e-8])  # axis-aligned with the grid
            poses = jnp.asarray(poses)
            ours, ours_poly = map(np.asarray, _box_vs_poly(jnp.asarray(cells), gp, poses))
            rc = np.argwhere(cells) + 0.5
            cen = np.stack([CFG.x_min + rc[:, 1] * H, CFG.y_min + rc[:, 0] * H], -1)  # grid frame
            corners = np.asarray(box_corners(pk.footprint_boxes(poses, CAR, CFG.margin)), np.float64)
            g = np.asarray(gp, np.float64)
            d = corners - g[:2]
            local = np.stack([np.cos(g[2]) * d[..., 0] + np.sin(g[2]) * d[..., 1],
                              -np.sin(g[2]) * d[..., 0] + np.cos(g[2]) * d[..., 1]], -1)
            polys = shapely.polygons(local)
            s_in, l_in = contained(shapely.STRtree(shapely.points(cen)), polys)
            s_out, l_out = contained(virtual, polys)
            strict, loose = s_in | s_out, l_in | l_out
            bad += np.sum((ours != strict) & (ours != loose)) + np.sum(ours != ours_poly)
            hits += ours.sum()
            beyond += np.sum(s_out & ~l_in)  # footprints that hit only because of the outside
    assert bad == 0 and 0 < hits < 8 * 64 and beyond > 10


def test_pursuit_follows_circle_and_line():
    k = 1 / 8.0
    mk = lambda p, k, l: pk.make_curve(jnp.array(p), jnp.array([k, 0.0, 0.0]), jnp.array([l, 0.0, 3.0]),  # noqa
                                       jnp.array(l), jnp.array(1.0 if abs(p[2]) < 1 else -1.0))
    arc, line, back = mk([0.0, 0.0, 0.0], k, 6.0), mk([0.0, 0.3, 0.0], 0.0, 7.0), mk([0.0, 0.0, np.pi], 0.0, 2.0)
    curves = jax.tree_util.tree_map(lambda *x: jnp.stack(x), arc, line, back)
    start = jnp.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.02, 0.0]])
    r = _rollout_grid(start, curves, EMPTY)
    p, v = np.asarray(r.poses), np.asarray(r.valid)
    assert np.all(np.asarray(r.complete))
    on_arc = np.abs(np.hypot(p[0, v[0], 0], p[0, v[0], 1] - 8.0) - 8.0)
    assert on_arc.max() < 0.02  # steer-rate transient at the start and end of the arc only
    assert abs(np.sum(v[0]) * CFG.dl - 6.0) < 0.2
    late = p[1, v[1]][p[1, v[1], 0] > 5.0]
    assert len(late) and np.abs(late[:, 1] - 0.3).max() < 0.03  # converged onto the line from 0.3 m off
    assert np.abs(p[2, v[2], 1]).max() <= 0.0201 and p[2, v[2], 0].min() < -1.9  # backward along y = 0
    assert np.all(np.diff(p[2, v[2], 0]) <= 1e-6)


def test_collision_cut_at_previous_point():
    cells = np.zeros((CFG.rows, CFG.cols), bool)
    cells[:, col_of(5.0):] = True  # a wall 5 m ahead of the rear axle (cells from x = 5.0 m)
    line = pk.make_curve(jnp.zeros((3, 3)), jnp.zeros((3, 3)), jnp.array([[6.0, 0.0, 3.0]] * 3),
                         jnp.array([6.0] * 3), jnp.array([1.0] * 3))
    r = _rollout_grid(jnp.zeros((3, 3)), line, jnp.asarray(cells))
    n = int(r.valid[0].sum())
    front = float(CAR.length - CAR.rear_overhang) + CFG.margin
    first_hit = int(np.ceil((5.0 + 0.025 - front) / CFG.dl + 1e-6))  # first pose touching a cell centre
    assert n == first_hit and bool(r.cut[0])
    x = np.asarray(r.poses[0, :, 0])
    assert x[n - 1] + front < 5.025 <= x[n] + front + 1e-6
    assert np.isclose(float(r.length[0]), (n - 1) * CFG.dl)


def _rollout(length, end_pose):
    T = 4
    poses = jnp.broadcast_to(jnp.asarray(end_pose, jnp.float32), (T, 3))
    return pk.Rollout(poses=poses, gear=jnp.ones(T), steer=jnp.zeros(T), s=jnp.zeros(T),
                      valid=jnp.ones(T, bool), length=jnp.asarray(length), complete=jnp.asarray(True),
                      cut=jnp.asarray(False))


def test_condition_and_selection_rules():
    tol = CFG.out_tol
    assert bool(pk.is_out(jnp.array([5.0, D, 0.0]), D, CFG))
    assert bool(pk.is_out(jnp.array([5.0, D + 1, 0.99 * tol]), D, CFG))
    assert not bool(pk.is_out(jnp.array([5.0, D - 0.01, 0.0]), D, CFG))
    assert not bool(pk.is_out(jnp.array([5.0, D + 1, 1.01 * tol]), D, CFG))
    out, notout = [5.0, D + 0.1, 0.0], [1.0, 0.5, 0.3]
    sel = lambda f, b: bool(pk.select_forward(_rollout(*f), _rollout(*b), D, CFG))  # noqa: E731
    assert sel((1.0, out), (5.0, notout))  # forward reaches the condition: forward, though shorter
    assert sel((2.0, notout), (1.0, notout))  # backward shorter: forward
    assert not sel((1.0, notout), (2.0, notout))  # backward longer: backward
    assert not sel((1.0, notout), (1.0, notout))  # tie: backward


def test_park_out_loop():
    rng = np.random.default_rng(3)
    gaps = np.array([0.2, 1.0, 2.3, 3.0], np.float32)
    scene, info = pk.make_scenes(rng, 4, CAR, front_gap=gaps, rear_gap=np.array([0.3, 1.5, 0.5, 1.0]))
    res = pk.park_out(scene, 0, CFG, CAR)
    success, moves = np.asarray(res.success), np.asarray(res.moves)
    assert not collisions(res.poses, res.valid, scene.polygons, scene.valid, CAR).any()
    need = np.asarray(pk.min_front_gap(CAR, CFG.margin, info["front_corner_y"]))
    assert np.all(gaps[2:] > need[2:] + 0.05) and np.all(success[2:]) and np.all(moves[2:] == 1)
    assert success[1] and not success[0]  # 2.5 m spare: several moves; 0.5 m spare: a clear failure
    fin = np.asarray(res.final_pose)
    assert np.all(fin[success, 1] >= D) and np.all(np.abs(fin[success, 2]) < CFG.out_tol)
    # the executed moves chain: each starts where the previous ended, gears alternate on the two-curve path
    p, v = np.asarray(res.poses), np.asarray(res.valid)
    for b in np.nonzero(success)[0]:
        ends = [p[b, m, v[b, m]][-1] for m in range(moves[b])]
        starts = [p[b, m, 0] for m in range(moves[b])]
        assert np.allclose(starts[0], np.asarray(scene.start[b]), atol=1e-6)
        assert all(np.allclose(s, e, atol=1e-5) for s, e in zip(starts[1:], ends[:-1]))
    # equal shapes do not recompile
    from jaxplan.parking.driver import run_two_curve
    n = run_two_curve._cache_size()
    again = pk.park_out(scene, 1, CFG, CAR)
    assert run_two_curve._cache_size() == n and bool(np.all(again.success[1:]))


def test_plan_parkout_api():
    # hand-built grids: a curb below the car and a car 3 m ahead / 1 m behind, read at the origin
    cells = np.zeros((2, CFG.rows, CFG.cols), bool)
    cells[:, : row_of(-1.25)] = True  # curb edge at y = -1.25
    ahead = col_of(CAR.length - CAR.rear_overhang + 3.0)
    behind = col_of(-CAR.rear_overhang - 1.0)
    cells[:, row_of(-1.25): row_of(0.95), ahead: ahead + 90] = True
    cells[:, row_of(-1.25): row_of(0.95), behind - 90: behind] = True
    cells[1, :, ahead - 40:] = True  # second scene: a wall 1 m ahead blocks the way out
    grids = pk.Grid(jnp.asarray(cells), jnp.zeros((2, 3)))
    plan = pk.plan_parkout(jnp.zeros((2, 3)), grids, CFG, CAR)
    tr = plan.trajectory
    assert tr.poses.shape == (2, CFG.steps, 3) and tr.valid.shape == (2, CFG.steps) and tr.gear.shape == (2, CFG.steps)
    assert np.asarray(plan.use_forward).tolist() == [True, False] and np.asarray(plan.out).tolist() == [True, False]
    assert np.all(np.asarray(tr.gear[0]) == 1) and np.all(np.asarray(tr.gear[1]) == -1)
    assert bool(plan.forward.cut[1]) and float(plan.backward.length[1]) > float(plan.forward.length[1])
    traj = tr.to_trajectory(CAR)
    traj.validate()
    n = int(tr.valid[0].sum())
    assert np.allclose(np.asarray(traj.x[0, :n]), np.asarray(tr.poses[0, :n, 0])) and float(traj.t[0, -1]) > 7.0
    with pytest.raises(ValueError, match="Grid.cells"):
        pk.plan_parkout(jnp.zeros(3), pk.Grid(jnp.zeros((10, 10), bool), jnp.zeros(3)), CFG, CAR)
    with pytest.raises(ValueError, match="scan_rows"):
        pk.plan_parkout(jnp.zeros((2, 3)), grids, pk.ParkoutConfig(scan_rows=40), CAR)
    with pytest.raises(ValueError):
        pk.ParkoutConfig(dl=0.0)


@jax.jit
def _two_corner(boxes, ref, poses):
    pts, ok = pk.two_corner_points(box_corners(boxes), jnp.ones(boxes.shape[0], bool), ref)
    return pts, ok, pk.footprint_hits_points(pts, ok, poses, CAR, 0.1)


def test_two_corner_model(rng):
    boxes = np.concatenate([rng.uniform(-6, 6, (5, 2)), rng.uniform(0.3, 4, (5, 2)), rng.uniform(-3, 3, (5, 1))], -1)
    ref = np.array([1.45, 0.0])
    poses = jnp.asarray(_random_poses(rng, 40, (5, 4, 3)))
    pts, ok, hit = _two_corner(jnp.asarray(boxes, jnp.float32), jnp.asarray(ref, jnp.float32), poses)
    corners = np.asarray(box_corners(jnp.asarray(boxes)))
    for k in range(5):
        near = corners[k][np.argsort(np.linalg.norm(corners[k] - ref, axis=-1))[:2]]
        assert np.allclose(np.asarray(pts)[2 * k: 2 * k + 2], near, atol=1e-5)
    hit = np.asarray(hit)
    polys = shapely.polygons(np.asarray(box_corners(pk.footprint_boxes(poses, CAR, 0.1))))
    ref_hit = np.array([shapely.contains_xy(p, np.asarray(pts)[:, 0], np.asarray(pts)[:, 1]).any() for p in polys])
    assert np.array_equal(hit, ref_hit) and 0 < hit.sum() < 40


def test_margin_shrinks_next_to_the_curb():
    cells = np.zeros((2, CFG.rows, CFG.cols), bool)  # the same shapes as above: no new compile
    cells[:, : row_of(-1.0)] = True  # occupied cell centres up to y = -1.025, 0.075 m from the car
    grids = pk.Grid(jnp.asarray(cells), jnp.zeros((2, 3)))
    plan = pk.plan_parkout(jnp.zeros((2, 3)), grids, CFG, CAR)
    assert np.isclose(float(plan.margin[0]), CFG.margin - 2 * (CFG.margin - CFG.min_margin) / 3)
    # turning out swings the rear-right corner ~9 cm towards the curb: forward is cut at once, backward runs
    assert bool(plan.forward.cut[0]) and float(plan.forward.length[0]) < 0.2
    assert not bool(plan.use_forward[0]) and float(plan.backward.length[0]) > 1.9


@jax.jit
def _project_vs_dense(curves, p, s_min):
    """Closed-form projection and the brute-force nearest point on 1 mm samples (s >= s_min)."""
    from jaxplan.parking.pursuit import project, track

    def one(c, q, lo):
        s = project(track(c, CFG), q, lo)
        grid = jnp.maximum(lo, -40.0) + 1e-3 * jnp.arange(80000, dtype=q.dtype)
        d = jnp.linalg.norm(pk.curve_point(c, grid)[:, :2] - q, axis=-1)
        return jnp.linalg.norm(pk.curve_point(c, s)[:2] - q), d.min(), s

    return jax.vmap(one)(curves, p, s_min)


def test_projection_matches_dense_samples(rng):
    n = 64
    poses = _random_poses(rng, n, (1.0, 0.8, 0.6))
    poses[n // 2:, :2] += rng.uniform(-1, 1, (n // 2, 2)) * 2  # backward curves: line and O2 cases
    fw = _forward(jnp.asarray(poses[: n // 2]))
    bw = jax.vmap(lambda p: pk.backward_curve(p, R, CFG.theta1, CFG.theta2, CFG.back_cap))(jnp.asarray(poses[n // 2:]))
    curves = jax.tree_util.tree_map(lambda a, b: jnp.concatenate([a, b]), fw, bw)
    ends = np.asarray(curves.end)
    # points near the curve (at a random arc length, pushed off sideways) and far from it
    s_at = rng.uniform(-1.0, ends + 2.0)
    on = np.asarray(_points(curves, jnp.asarray(s_at, jnp.float32)))
    off = rng.normal(0, 1.0, (n, 2)) * np.where(rng.random(n) < 0.25, 6.0, 1.0)[:, None]
    q = (on[:, :2] + off).astype(np.float32)
    s_min = np.where(rng.random(n) < 0.5, -1e3, rng.uniform(-0.5, ends)).astype(np.float32)
    d, d_ref, s = (np.asarray(a) for a in _project_vs_dense(curves, jnp.asarray(q), jnp.asarray(s_min)))
    assert np.all(s >= np.maximum(s_min, -1e3) - 1e-5)
    assert np.all(np.abs(d - d_ref) < 2e-3), np.abs(d - d_ref).max()
