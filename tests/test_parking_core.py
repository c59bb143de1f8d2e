"""Park-out planner: circles, radii, transforms, footprint check, pure pursuit, rules, loop."""
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import shapely

import jaxplan.parking as pk
from jaxplan.geometry import box_corners, box_has_overlap
from jaxplan.types import VehicleParams

CAR = VehicleParams()
CFG = pk.ParkoutConfig()
R = float(pk.turning_radius(CAR))
D = float(pk.stop_line(CAR, CFG.c))

_hits_grid = jax.jit(lambda pre, gp, poses: pk.footprint_hits_grid(pre, gp, poses, CAR, CFG))
_no_hits = lambda poses: jnp.zeros(poses.shape[:-1], bool)  # noqa: E731
_rollout_free = jax.jit(jax.vmap(lambda p, c: pk.rollout(p, c, _no_hits, CAR, CFG)))
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


def test_transforms_round_trip(rng):
    pose = jnp.asarray(_random_poses(rng, 50, (5, 5, 3)))
    xy = jnp.asarray(rng.uniform(-8, 8, (50, 2)).astype(np.float32))
    assert np.allclose(pk.from_frame(pose, pk.to_frame(pose, xy)), xy, atol=1e-5)
    other = jnp.asarray(_random_poses(rng, 50, (5, 5, 3)))
    back = np.asarray(pk.compose(pose, pk.relative(pose, other)))
    assert np.allclose(back[:, :2], other[:, :2], atol=1e-5)
    assert np.allclose(np.cos(back[:, 2] - other[:, 2]), 1, atol=1e-6)
    rc = pk.world_to_cell(pose, xy, CFG)
    assert np.allclose(pk.cell_to_world(pose, rc, CFG), xy, atol=1e-4)
    # the cell under the grid pose itself is the central one
    rc0 = np.floor(np.asarray(pk.world_to_cell(pose, pose[:, :2], CFG)))
    assert np.all(rc0 == [CFG.rows // 2, CFG.cols // 2])
    centres = pk.cell_centres(CFG)
    assert np.allclose(pk.world_to_cell(pose[0], pk.from_frame(pose[0], centres[3, 7]), CFG), [3.5, 7.5], atol=1e-3)


def test_footprint_check_matches_shapely(rng):
    bad, hits = 0, 0
    for density in (3e-4, 2e-3):
        for _ in range(6):
            cells = rng.random((CFG.rows, CFG.cols)) < density
            gp = jnp.asarray(rng.normal(size=3), jnp.float32)
            poses = jnp.asarray(_random_poses(rng, 64, (7, 4, 3.2)))
            ours = np.asarray(_hits_grid(pk.row_prefix(cells), gp, poses))
            cen = np.asarray(pk.cell_to_world(gp, jnp.asarray(np.argwhere(cells) + 0.5, jnp.float32), CFG))
            polys = shapely.polygons(np.asarray(box_corners(pk.footprint_boxes(poses, CAR, CFG.margin))))
            tree = shapely.STRtree(shapely.points(cen))
            strict = np.zeros(len(polys), bool)
            loose = np.zeros(len(polys), bool)
            strict[tree.query(polys, predicate="contains_properly")[0]] = True
            loose[tree.query(polys, predicate="intersects")[0]] = True
            bad += np.sum((ours != strict) & (ours != loose))
            hits += ours.sum()
    assert bad == 0 and 0 < hits < 12 * 64


def test_pursuit_follows_circle_and_line():
    k = 1 / 8.0
    mk = lambda p, k, l: pk.make_curve(jnp.array(p), jnp.array([k, 0.0, 0.0]), jnp.array([l, 0.0, 3.0]),  # noqa
                                       jnp.array(l), jnp.array(1.0 if abs(p[2]) < 1 else -1.0))
    arc, line, back = mk([0.0, 0.0, 0.0], k, 6.0), mk([0.0, 0.3, 0.0], 0.0, 7.0), mk([0.0, 0.0, np.pi], 0.0, 2.0)
    curves = jax.tree_util.tree_map(lambda *x: jnp.stack(x), arc, line, back)
    start = jnp.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.02, 0.0]])
    r = _rollout_free(start, curves)
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
    cells[:, 300:] = True  # a wall 5 m ahead of the rear axle (cells from x = 5.0 m)
    grid = pk.Grid(jnp.asarray(cells), jnp.zeros(3))
    line = pk.make_curve(jnp.zeros((1, 3)), jnp.zeros((1, 3)), jnp.array([[6.0, 0.0, 3.0]]), jnp.array([6.0]),
                         jnp.array([1.0]))
    pre = pk.row_prefix(grid.cells)
    hits = lambda poses: pk.footprint_hits_grid(pre, grid.pose, poses, CAR, CFG)  # noqa: E731
    r = jax.vmap(lambda p, c: pk.rollout(p, c, hits, CAR, CFG))(jnp.zeros((1, 3)), line)
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


def _true_collisions(res, scene):
    """Executed poses whose exact footprint overlaps a true obstacle box."""
    boxes = pk.footprint_boxes(res.poses, CAR)  # (B, M, T, 5)
    hit = box_has_overlap(boxes[..., None, :], scene.boxes[:, None, None]) & scene.valid[:, None, None]
    return np.asarray(jnp.any(hit, -1) & res.valid)


def test_park_out_loop():
    rng = np.random.default_rng(3)
    gaps = np.array([0.2, 1.0, 2.3, 3.0], np.float32)
    scene, info = pk.make_scenes(rng, 4, CAR, front_gap=gaps, rear_gap=np.array([0.3, 1.5, 0.5, 1.0]))
    res = pk.park_out(scene, jax.random.PRNGKey(0), CFG, CAR)
    success, moves = np.asarray(res.success), np.asarray(res.moves)
    assert not _true_collisions(res, scene).any()
    need = np.asarray(pk.min_front_gap(CAR, CFG.margin, info["front_corner_y"]))
    assert np.all(gaps[2:] > need[2:] + 0.05) and np.all(success[2:]) and np.all(moves[2:] == 1)
    assert not success[0] and (bool(res.stuck[0]) or moves[0] == CFG.max_moves)  # hopeless slot: clear failure
    fin = np.asarray(res.final_pose)
    assert np.all(fin[success, 1] >= D)
    # the executed moves chain: each starts where the previous ended
    p, v = np.asarray(res.poses), np.asarray(res.valid)
    for b in np.nonzero(success)[0]:
        ends = [p[b, m, v[b, m]][-1] for m in range(moves[b])]
        starts = [p[b, m, 0] for m in range(moves[b])]
        assert np.allclose(starts[0], 0.0) and all(np.allclose(s, e, atol=1e-5) for s, e in zip(starts[1:], ends[:-1]))
    # single-instance and batched agree; the jitted planner does not recompile for equal shapes
    one = pk.park_out(jax.tree_util.tree_map(lambda x: x[2], scene), jax.random.split(jax.random.PRNGKey(0), 4)[2],
                      CFG, CAR)
    assert np.allclose(np.asarray(one.final_pose), fin[2], atol=1e-4)


def test_plan_parkout_api():
    scene, _ = pk.make_scenes(np.random.default_rng(1), 2, CAR, front_gap=3.0, rear_gap=1.0)
    pose = jnp.zeros((2, 3))
    grids = jax.vmap(lambda s, p, k: pk.render_grid(s, p, k, CFG, CAR))(
        scene, pose, jax.random.split(jax.random.PRNGKey(0), 2))
    plan = pk.plan_parkout(pose, grids, CFG, CAR)
    assert plan.trajectory.poses.shape == (2, CFG.steps, 3) and plan.trajectory.valid.shape == (2, CFG.steps)
    assert np.all(np.asarray(plan.use_forward)) and np.all(np.asarray(plan.out))
    with pytest.raises(ValueError, match="Grid.cells"):
        pk.plan_parkout(jnp.zeros(3), pk.Grid(jnp.zeros((10, 10), bool), jnp.zeros(3)), CFG, CAR)
    with pytest.raises(ValueError, match="scan_rows"):
        pk.plan_parkout(jnp.zeros(3), grids, pk.ParkoutConfig(scan_rows=40), CAR)
    with pytest.raises(ValueError):
        pk.ParkoutConfig(dl=0.0)
