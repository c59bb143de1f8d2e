"""Replan building blocks against brute force: tracking point search, gear-shift split,
collision queue and brake-stop point, first collision point, re-plan decision."""
import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import shapely

from jaxplan.geometry.boxes import box_corners, poses_to_boxes
from jaxplan.replan import queue as Q
from jaxplan.replan.supervisor import (GOAL, IMMEDIATE, LAZY, LOST, NO_REPLAN, OBSTACLE, PERIOD, PERIODIC,
                                       SupervisorConfig, replan_decision)
from jaxplan.replan.tracking import find_tracking_point_directional_jit, find_tracking_point_jit
from jaxplan.replan.trajectory import (BRAKE_STOP, COLLISION, END, GEAR_SHIFT, NORMAL, START, point_types,
                                       split_at_gear_shifts, sub_trajectories_jit)
from jaxplan.types import Trajectory, VehicleParams

N, W = 40, 16


def random_path(rng, n=N):
    """Legs of random length and gear; heading drifts; reverse legs move against the heading."""
    xy, gear, head = [np.zeros(2)], [1], [0.0]
    h, g = rng.uniform(-np.pi, np.pi), 1
    while len(xy) < n:
        g = -g if len(xy) > 1 else g
        for _ in range(rng.integers(4, 12)):
            h += rng.normal(0, 0.15)
            step = rng.uniform(0.2, 0.8)
            xy.append(xy[-1] + g * step * np.array([np.cos(h), np.sin(h)]))
            gear.append(g)
            head.append(h)
    return np.array(xy[:n]), np.array(gear[:n], np.int32), np.array(head[:n])


def brute_tracking(path, car, start, end, max_dist, gear=None, heading=None, motion=None, tol=1e-3):
    """Reference: every segment j in [start, end), same criteria; also says whether the case is near a tie/boundary."""
    cands = []
    ambiguous = False
    for j in range(start, end):
        a, b = path[j], path[j + 1]
        d = b - a
        L = np.linalg.norm(d)
        if L <= 1e-9:
            continue
        w = car - a
        p = (w @ d) / L
        dist = abs(d[0] * w[1] - d[1] * w[0]) / L
        if gear is not None:
            m = motion * np.array([np.cos(heading), np.sin(heading)])
            if gear[j + 1] != motion or d @ m <= 0:
                continue
            ambiguous |= abs(d @ m) / L < tol
        ambiguous |= (abs(p) < tol or abs(p - L) < tol) or abs(dist - max_dist) < tol
        if 0 < p <= L and dist <= max_dist:
            cands.append((dist, j))
    cands.sort()
    if len(cands) > 1 and cands[1][0] - cands[0][0] < tol:
        ambiguous = True
    return (cands[0][1] if cands else None), (cands[0][0] if cands else None), ambiguous


def _cases(rng, n_cases, directional):
    rows = []
    for _ in range(n_cases):
        path, gear, head = random_path(rng)
        i = rng.integers(0, N - 1)
        car = path[i] + rng.normal(0, 0.6, 2)
        start = int(rng.integers(0, N - 2))
        end = int(rng.integers(start + 1, N))
        motion = int(rng.choice([-1, 1]))
        rows.append((path, gear, car, head[i] + rng.normal(0, 0.3), motion, start, end))
    return rows


@pytest.mark.parametrize("directional", [False, True])
def test_tracking_matches_brute_force(rng, directional):
    rows = _cases(rng, 300, directional)
    path, gear, car, heading, motion, start, end = (np.array(c) for c in zip(*rows))
    max_dist = 1.0
    if directional:
        fn = jax.vmap(lambda p, g, c, h, m, s, e: find_tracking_point_directional_jit(p, g, c, h, m, s, e, W, max_dist))
        tp = fn(jnp.asarray(path, jnp.float32), gear, jnp.asarray(car, jnp.float32),
                jnp.asarray(heading, jnp.float32), motion, start, end)
    else:
        fn = jax.vmap(lambda p, c, s, e: find_tracking_point_jit(p, c, s, e, W, max_dist))
        tp = fn(jnp.asarray(path, jnp.float32), jnp.asarray(car, jnp.float32), start, end)
    checked = found = 0
    for k in range(len(rows)):
        stop = min(start[k] + W, end[k])  # incremental: only W segments from the last tracking point
        kw = dict(gear=gear[k], heading=heading[k], motion=motion[k]) if directional else {}
        j, dist, amb = brute_tracking(path[k], car[k], start[k], stop, max_dist, **kw)
        if amb:
            continue
        checked += 1
        assert bool(tp.found[k]) == (j is not None), k
        if j is not None:
            found += 1
            assert int(tp.index[k]) == j
            assert abs(float(tp.dist[k]) - dist) < 1e-4
            assert 0 < float(tp.proj[k]) <= np.linalg.norm(path[k][j + 1] - path[k][j]) + 1e-5
        else:
            assert int(tp.index[k]) == start[k]
    assert checked > 200 and found > 50


def test_tracking_never_looks_behind_or_past_window():
    path = np.stack([np.arange(N) * 0.5, np.zeros(N)], -1).astype(np.float32)
    car = np.array([3.2, 0.1], np.float32)  # on segment 6
    assert int(find_tracking_point_jit(path, car, 0, N - 1, W, 1.0).index) == 6
    assert not bool(find_tracking_point_jit(path, car, 7, N - 1, W, 1.0).found)  # behind the last tracking point
    far = np.array([15.2, 0.0], np.float32)  # segment 30: beyond start + W
    assert not bool(find_tracking_point_jit(path, far, 0, N - 1, W, 1.0).found)
    assert int(find_tracking_point_jit(path, far, 20, N - 1, W, 1.0).index) == 30
    # The projection must be > 0 and <= the segment length: a car exactly on point 6 belongs to segment 5.
    assert int(find_tracking_point_jit(path, np.array([3.0, 0.0], np.float32), 0, N - 1, W, 1.0).index) == 5


def test_directional_tracking_picks_the_right_branch_at_a_cusp():
    # Forward along x to x = 9.5 (points 0..19), gear shift, reverse back along y = 0.05 (points 20..39).
    fwd = np.stack([np.arange(20) * 0.5, np.zeros(20)], -1)
    rev = np.stack([9.5 - np.arange(20) * 0.5, np.full(20, 0.05)], -1)
    path = np.concatenate([fwd, rev]).astype(np.float32)
    gear = np.array([1] * 20 + [-1] * 20, np.int32)
    car = np.array([4.2, 0.06], np.float32)  # nearer the reverse branch
    plain = find_tracking_point_jit(path, car, 0, N - 1, N, 1.0)
    assert int(plain.index) >= 20  # the plain search takes the wrong (reverse) branch
    f = find_tracking_point_directional_jit(path, gear, car, 0.0, 1, 0, N - 1, N, 1.0)
    r = find_tracking_point_directional_jit(path, gear, car, 0.0, -1, 0, N - 1, N, 1.0)
    assert int(f.index) == 8 and bool(f.found)
    assert int(r.index) == 30 and bool(r.found)  # reverse segment 30 -> 31 spans x 4.5 .. 4.0
    # Heading flipped (car facing -x) and moving forward: no segment agrees.
    assert not bool(find_tracking_point_directional_jit(path, gear, car, np.pi, 1, 0, 19, N, 1.0).found)


def test_sub_trajectories_and_split(rng):
    for _ in range(20):
        _, gear, _ = random_path(rng)
        k = int(rng.integers(5, N + 1))
        valid = np.arange(N) < k
        lo, hi, direction, count = (np.asarray(a) for a in sub_trajectories_jit(gear, valid, max_sub=8))
        g = gear[:k]
        cuts = [i for i in range(k - 1) if g[i] != g[i + 1]]
        ref = list(zip([0] + cuts, cuts + [k - 1]))[:8]
        assert int(count) == len(ref)
        for s, (a, b) in enumerate(ref):
            assert (lo[s], hi[s]) == (a, b)
            assert direction[s] == g[min(a + 1, k - 1)]
            assert np.all(g[a + 1:b + 1] == direction[s])  # single direction
        traj = Trajectory(*(np.asarray(v, np.float32) for v in (np.arange(N), np.zeros(N), np.zeros(N), np.zeros(N),
                                                                 np.zeros(N), np.zeros(N), np.arange(N), np.arange(N))),
                          gear=gear)
        pieces = split_at_gear_shifts(traj, valid)
        assert len(pieces) == len(cuts) + 1
        for p, (a, b) in zip(pieces, zip([0] + cuts, cuts + [k - 1])):
            np.testing.assert_array_equal(p.x, np.arange(a, b + 1))
    with pytest.raises(ValueError):
        split_at_gear_shifts(traj, np.arange(N) % 2 == 0)


def test_point_types():
    gear = np.array([1, 1, 1, -1, -1, -1, 1, 1, 1, 1], np.int32)
    valid = np.arange(10) < 8
    t = np.asarray(point_types(gear, valid, brake_idx=4, collision_idx=5))
    assert t.tolist() == [START, NORMAL, GEAR_SHIFT, NORMAL, BRAKE_STOP, COLLISION, NORMAL, END, NORMAL, NORMAL]


def test_queue_expiry_nearest_and_brake_stop_step_by_step():
    q = Q.queue_init(4)
    b = Q.brake_init()
    b = Q.update_brake_stop(b, q, 0.5)
    assert not bool(b.active)  # empty queue: no brake-stop point, drive on
    xy = jnp.zeros(2)
    q = Q.queue_push(q, 0.0, 12.0, xy)
    b = Q.update_brake_stop(b, Q.queue_expire(q, 0.0, 2.0), 0.5)
    assert bool(b.active) and float(b.s) == pytest.approx(11.5)
    q = Q.queue_push(q, 0.5, 9.0, xy)  # nearer: the brake point moves
    b = Q.update_brake_stop(b, Q.queue_expire(q, 0.5, 2.0), 0.5)
    assert float(b.s) == pytest.approx(8.5) and int(Q.queue_size(q)) == 2
    q = Q.queue_push(q, 1.0, 15.0, xy)  # farther: the nearest is unchanged, the brake point stays
    b = Q.update_brake_stop(b, Q.queue_expire(q, 1.0, 2.0), 0.5)
    assert float(b.s) == pytest.approx(8.5) and float(b.key) == 9.0
    q = Q.queue_expire(q, 2.0, 2.0)  # exactly 2 s old: kept
    assert int(Q.queue_size(q)) == 3
    q = Q.queue_expire(q, 2.2, 2.0)  # the t=0 entry (s=12) is older than 2 s
    b = Q.update_brake_stop(b, q, 0.5)
    assert int(Q.queue_size(q)) == 2 and float(b.s) == pytest.approx(8.5)
    q = Q.queue_expire(q, 2.7, 2.0)  # the t=0.5 entry (s=9) expires: nearest is now s=15
    b = Q.update_brake_stop(b, q, 0.5)
    assert int(Q.queue_size(q)) == 1 and float(b.s) == pytest.approx(14.5)
    s, _, found = Q.queue_nearest(q)
    assert bool(found) and float(s) == 15.0
    q = Q.queue_expire(q, 10.0, 2.0)
    b = Q.update_brake_stop(b, q, 0.5)
    assert int(Q.queue_size(q)) == 0 and not bool(b.active)
    # A full queue overwrites its oldest entry.
    q = Q.queue_init(3)
    for i, s in enumerate([5.0, 6.0, 7.0, 8.0]):
        q = Q.queue_push(q, float(i), s, xy)
    assert sorted(np.asarray(q.s).tolist()) == [6.0, 7.0, 8.0]
    q2 = Q.queue_push(q, 9.0, 1.0, xy, push=False)
    np.testing.assert_array_equal(q2.s, q.s)


def test_first_collision_point_and_contact_against_shapely(rng):
    car = VehicleParams()
    n = 30
    fn = jax.jit(jax.vmap(Q.collision_arc_length, in_axes=(0, 0, 0, 0, 0, 0)))
    X = []
    for _ in range(60):
        h = rng.uniform(-np.pi, np.pi)
        s = np.cumsum(rng.uniform(0.2, 0.6, n)) - 0.4
        hh = h + np.cumsum(rng.normal(0, 0.03, n))
        xy = np.cumsum(np.stack([np.cos(hh), np.sin(hh)], -1) * np.diff(np.concatenate([[0], s]))[:, None], 0)
        obs = np.stack([xy[rng.integers(5, n)] + rng.normal(0, 2.0, 2) for _ in range(3)])
        obs = np.concatenate([obs, rng.uniform(0.5, 2.5, (3, 2)), rng.uniform(-np.pi, np.pi, (3, 1))], -1)
        ov = rng.uniform(size=3) < 0.8
        start, end = int(rng.integers(0, 10)), int(rng.integers(15, n))
        X.append((xy, hh, s, start, end, obs, ov))
    xy, hh, s, start, end, obs, ov = (np.array(c) for c in zip(*X))
    boxes = poses_to_boxes(jnp.asarray(xy, jnp.float32), jnp.asarray(hh, jnp.float32), car)
    idx, cs, found = fn(boxes, jnp.asarray(s, jnp.float32), start, end, jnp.asarray(obs, jnp.float32), ov)
    bc = np.asarray(box_corners(boxes))
    oc = np.asarray(box_corners(jnp.asarray(obs, jnp.float32)))
    nf = 0
    for k in range(len(X)):
        polys = [shapely.Polygon(oc[k, j]) for j in range(3) if ov[k, j]]
        hit = [any(shapely.Polygon(bc[k, i]).intersection(p).area > 1e-4 for p in polys) for i in range(n)]
        touch = [any(shapely.Polygon(bc[k, i]).intersection(p).area > 1e-9 for p in polys) for i in range(n)]
        ref = next((i for i in range(start[k], end[k] + 1) if hit[i]), None)
        amb = any(touch[i] != hit[i] for i in range(start[k], end[k] + 1))
        if amb:
            continue
        assert bool(found[k]) == (ref is not None)
        if ref is not None:
            nf += 1
            assert int(idx[k]) == ref
            lo = s[k][ref - 1] if ref > start[k] else s[k][ref]
            assert lo - 1e-5 <= float(cs[k]) <= s[k][ref] + 1e-5
    assert nf > 10


def _ref_decision(strategy, stopped, at_gs, at_bs, moved, new_col, lost_stopped, since, done, cfg, blocked_end,
                  busy=False):
    """Straight from the issue text, written independently of the implementation."""
    if done or busy:
        return NO_REPLAN
    if lost_stopped:
        return LOST
    r = _ref_strategy(strategy, stopped, at_gs, at_bs, moved, new_col, since, cfg)
    if r == NO_REPLAN and blocked_end and stopped and since >= cfg.retry_s:
        return OBSTACLE  # stopped at the end of a plan that does not reach the goal
    return r


def _ref_strategy(strategy, stopped, at_gs, at_bs, moved, new_col, since, cfg):
    if strategy == LAZY:
        if not stopped:
            return NO_REPLAN
        if at_bs and since >= cfg.retry_s:
            return OBSTACLE
        if at_gs and moved:
            return GOAL
        return NO_REPLAN
    if strategy == PERIODIC:
        return PERIOD if since >= 1.0 / cfg.periodic_hz else NO_REPLAN
    if since < cfg.debounce_s:  # immediate re-plans are debounced
        return NO_REPLAN
    if new_col:
        return OBSTACLE
    return GOAL if moved else NO_REPLAN


def test_replan_decision_truth_table():
    cfg = SupervisorConfig()
    rows = [(s, *flags, since) for s in (LAZY, PERIODIC, IMMEDIATE)
            for flags in itertools.product([False, True], repeat=9) for since in (0.2, 0.7, 1.0, 2.5)]
    cols = list(zip(*rows))
    strategy = np.array(cols[0])
    f = [np.array(c) for c in cols[1:10]]
    since = np.array(cols[10], np.float32)
    replan, reason = jax.jit(lambda *a: replan_decision(a[0], cfg, stopped=a[1], at_gear_shift=a[2],
                                                        at_brake_stop=a[3], goal_moved=a[4], new_collision=a[5],
                                                        lost_stopped=a[6], since_replan=a[10], done=a[7],
                                                        at_blocked_end=a[8], busy=a[9]))(strategy, *f, since)
    for i, r in enumerate(rows):
        s, stopped, at_gs, at_bs, moved, new_col, lost, done, blocked_end, busy, sn = r
        ref = _ref_decision(s, stopped, at_gs, at_bs, moved, new_col, lost, sn, done, cfg, blocked_end, busy)
        assert int(reason[i]) == ref, r
        assert bool(replan[i]) == (ref != NO_REPLAN)
        if s == LAZY and not stopped and not lost:
            assert not bool(replan[i])  # never while moving
        if s == IMMEDIATE and sn < cfg.debounce_s and not lost and not (blocked_end and stopped):
            assert not bool(replan[i])  # debounced


def test_bad_input_gets_a_clear_error():
    from jaxplan.replan import ManeuverSimConfig, simulate

    with pytest.raises(ValueError, match="dt"):
        SupervisorConfig(dt=0.0)
    with pytest.raises(ValueError, match="queue_size"):
        SupervisorConfig(queue_size=0)
    with pytest.raises(ValueError, match="strategy"):
        simulate(None, 3, ManeuverSimConfig())
    with pytest.raises(ValueError, match="limits"):
        from jaxplan.replan import ApproachPlanner, MotionLimits
        ManeuverSimConfig(planner=ApproachPlanner(limits=MotionLimits(v_fwd=5.0)))
    with pytest.raises(ValueError, match="radius_factor"):
        from jaxplan.replan import ApproachPlanner
        ApproachPlanner(radius_factor=0.9)
    from jaxplan.replan import sample_scenarios
    with pytest.raises(ValueError, match="kind"):
        sample_scenarios(0, 1, "valet")
