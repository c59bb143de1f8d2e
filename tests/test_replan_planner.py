"""The drivable planner in the loop: Dubins paths against independent integration, plans within
the car's curvature limit (three-point curvature of the points) and collision-free against a
shapely oracle of the obstacles where they are predicted to be; a crossing pedestrian is
predicted as moving. One jitted batched planner for every test."""
import functools

import jax
import jax.numpy as jnp
import numpy as np
import shapely

from jaxplan.replan import ApproachPlanner, PlanRequest, max_curvature
from jaxplan.replan import dubins as D
from jaxplan.replan.prediction import swept_boxes

PL = ApproachPlanner()
K = 4
B = 48
KMAX = max_curvature(PL.vehicle)


@functools.lru_cache(maxsize=None)
def _batched():
    return jax.jit(jax.vmap(PL))


def plan_batch(rows):
    """Plan a list of request dicts (padded to ``B``) with one compiled function."""
    rows = list(rows) + [rows[0]] * (B - len(rows))

    def stack(key, dtype=np.float32):
        return jnp.asarray(np.stack([np.asarray(r[key], dtype) for r in rows]))

    req = PlanRequest(stack("start"), stack("speed"), stack("gear", np.int32), stack("phase", np.int32),
                      stack("goal"), stack("obs"), stack("vel"), stack("valid", bool), stack("park", bool),
                      stack("prev_end"), stack("prev_via"))
    return jax.tree.map(np.asarray, _batched()(req))


def request(start, goal, park, obs=(), vel=(), speed=0.0, phase=1, gear=1):
    o, v, m = np.zeros((K, 5)), np.zeros((K, 2)), np.zeros(K, bool)
    for i, b in enumerate(obs):
        o[i], m[i] = b, True
        if i < len(vel):
            v[i] = vel[i]
    return dict(start=start, goal=goal, park=park, obs=o, vel=v, valid=m, speed=speed, phase=phase, gear=gear,
                prev_end=start, prev_via=start)


WORD_SIGNS = np.array([(1, 1), (-1, 1), (-1, -1), (1, -1)], float)


def corners(x, y, L, W, h):
    """Box corners ``(..., 4, 2)`` from centre, size and heading (numpy, independent of the library)."""
    x, y, L, W, h = np.broadcast_arrays(*(np.asarray(a, float) for a in (x, y, L, W, h)))
    c, s = np.cos(h)[..., None], np.sin(h)[..., None]
    a, e = WORD_SIGNS[:, 0] * L[..., None] / 2, WORD_SIGNS[:, 1] * W[..., None] / 2
    return np.stack([x[..., None] + a * c - e * s, y[..., None] + a * s + e * c], -1)


def car_corners(x, y, h, veh=PL.vehicle):
    """Car outline ``(..., 4, 2)`` from rear-axle poses."""
    L, W = float(veh.length), float(veh.width)
    off = 0.5 * L - float(veh.rear_overhang)
    return corners(x + off * np.cos(h), y + off * np.sin(h), L, W, h)


def box_polygon(b):
    return shapely.polygons(corners(*b))


def menger(xy):
    """Curvature of the circle through each three consecutive points ``(M - 2,)``."""
    a, b, c = xy[:-2], xy[1:-1], xy[2:]
    ab, bc, ca = (np.linalg.norm(b - a, axis=1), np.linalg.norm(c - b, axis=1), np.linalg.norm(a - c, axis=1))
    cross = (b - a)[:, 0] * (c - a)[:, 1] - (b - a)[:, 1] * (c - a)[:, 0]
    ok = (ab > 1e-3) & (bc > 1e-3)
    return np.where(ok, 2 * np.abs(cross) / np.maximum(ab * bc * ca, 1e-12), 0.0)


def test_dubins_words_reach_their_targets_by_independent_integration(rng):
    n = 400
    st = np.c_[rng.uniform(-12, 12, (n, 2)), rng.uniform(-4, 4, n)].astype(np.float32)
    en = np.c_[rng.uniform(-12, 12, (n, 2)), rng.uniform(-4, 4, n)].astype(np.float32)
    R = 5.0
    lengths, feas = (np.asarray(a) for a in jax.jit(D.word_lengths)(jnp.asarray(st), jnp.asarray(en), R))
    best = jax.tree.map(np.asarray, jax.jit(D.shortest)(jnp.asarray(st), jnp.asarray(en), R))
    # Integrate every word of every pair: 200 midpoint steps per segment (float64, numpy).
    x, y, h = (np.repeat(st[:, i:i + 1].astype(float), 6, 1) for i in range(3))
    for seg in range(3):
        sign = np.array([w[seg] for w in D.WORD_SIGNS], float)[None]
        ds = lengths[:, :, seg].astype(float) / 200
        for _ in range(200):
            hm = h + 0.5 * sign * ds / R
            x, y, h = x + ds * np.cos(hm), y + ds * np.sin(hm), h + sign * ds / R
    err = np.hypot(x - en[:, 0:1], y - en[:, 1:2])
    yaw = np.abs(np.sin((h - en[:, 2:3]) / 2))
    # a snapped near-full-turn arc may leave the end up to radius * SNAP off
    assert np.all(err[feas] < 1e-3 + R * D.SNAP) and np.all(yaw[feas] < 1e-3 + D.SNAP)
    assert np.mean(err[feas] < 2e-3) > 0.97
    assert feas.sum() > 1500
    tot = np.where(feas, lengths.sum(-1), np.inf)
    np.testing.assert_allclose(best.length, tot.min(-1), atol=1e-4)
    assert best.ok.all()


def _random_rows(rng, n):
    rows = []
    for i in range(n):
        kind = ("park", "drive", "final")[i % 3]
        if kind == "park":
            goal = np.array([rng.uniform(14, 20), -7 + rng.uniform(-0.3, 0.3), np.pi / 2 + rng.uniform(-0.1, 0.1)])
            start = np.array([0.0, rng.uniform(-0.3, 0.3), rng.uniform(-0.1, 0.1)])
        elif kind == "drive":
            goal = np.array([rng.uniform(20, 35), rng.uniform(-1, 1), rng.uniform(-0.1, 0.1)])
            start = np.array([0.0, 0.0, rng.uniform(-0.1, 0.1)])
        else:  # in the final reverse leg, near the slot
            goal = np.array([16.0, -7.0, np.pi / 2])
            start = np.array([16.0 + rng.uniform(1, 4), -7 + rng.uniform(4, 8), np.pi / 2 - rng.uniform(0.3, 0.9)])
        obs, vel = [], []
        for _ in range(int(rng.integers(1, K + 1))):
            t = rng.uniform(0.3, 0.8)
            p = start[:2] + t * (goal[:2] - start[:2]) + rng.normal(0, 1.5, 2)
            if rng.uniform() < 0.3:  # a walker crossing at 1-1.5 m/s
                d = rng.uniform(-np.pi, np.pi)
                sp = rng.uniform(1.0, 1.5)
                obs.append([p[0] - 3 * np.cos(d), p[1] - 3 * np.sin(d), 0.6, 0.6, d])
                vel.append([sp * np.cos(d), sp * np.sin(d)])
            else:
                obs.append([p[0], p[1], rng.uniform(0.6, 1.5), rng.uniform(0.6, 1.2), rng.uniform(-np.pi, np.pi)])
                vel.append([0.0, 0.0])
        speed = 0.0 if kind != "drive" or rng.uniform() < 0.5 else rng.uniform(0.5, 3.0)
        rows.append(request(start, goal, kind != "drive", obs, vel, speed=-speed if kind == "final" else speed,
                            phase=-1 if kind == "final" else 1, gear=-1 if kind == "final" else 1))
    return rows


def test_plans_are_drivable_and_collision_free_against_shapely(rng):
    rows = _random_rows(rng, B)
    out = plan_batch(rows)
    n_ok = 0
    for i, r in enumerate(rows):
        k = int(out.valid[i].sum())
        tr = jax.tree.map(lambda a: a[i, :k], out.traj)
        xy = np.stack([tr.x, tr.y], -1)
        # Curvature: the plan's own and the three-point curvature of its points, every plan.
        assert np.abs(tr.kappa).max() <= KMAX + 1e-4
        same_gear = (tr.gear[1:-1] == tr.gear[2:]) & (tr.gear[:-2] == tr.gear[1:-1])
        assert np.max(np.where(same_gear, menger(xy), 0.0), initial=0.0) <= KMAX + 5e-3
        np.testing.assert_allclose(xy[0], r["start"][:2], atol=1e-4)
        if not bool(out.ok[i]):
            continue
        n_ok += 1
        # Reaches the goal (within the planner's goal tolerance) and stops at every gear change.
        assert np.hypot(*(xy[-1] - r["goal"][:2])) <= PL.goal_tol[0] + PL.end_tol[0] + 1e-4
        shift = np.nonzero(tr.gear[:-1] != tr.gear[1:])[0]
        assert np.all(np.abs(tr.v[shift]) < 1e-6) and abs(tr.v[-1]) < 1e-6
        assert np.all(np.abs(tr.v) <= PL.limits.v_fwd + 1e-6)
        # The car moves the way its gear says (reverse legs move against the heading).
        d = np.diff(xy, axis=0)
        moving = np.linalg.norm(d, axis=1) > 1e-4
        along = (d[:, 0] * np.cos(tr.theta[1:]) + d[:, 1] * np.sin(tr.theta[1:])) * tr.gear[1:]
        assert np.all(along[moving] > 0)
        # Oracle: the car outline at each point, against each obstacle where it is predicted to be
        # around the time the car gets there (the planner's window), and swept between points.
        cc = car_corners(tr.x, tr.y, tr.theta)
        cars = shapely.polygons(cc)
        swept = shapely.convex_hull(shapely.multipoints(np.concatenate([cc[:-1], cc[1:]], axis=1)))
        for o, v, m in zip(r["obs"], r["vel"], r["valid"]):
            if not m:
                continue
            if np.allclose(v, 0):
                assert not shapely.intersects(swept, box_polygon(o)).any(), i
            else:
                tau = tr.t[:, None] + np.linspace(-PL.before, PL.after, 9)[None]  # (k, 9)
                moved = shapely.polygons(corners(o[0] + v[0] * tau, o[1] + v[1] * tau, o[2], o[3], o[4]))
                assert not shapely.intersects(cars[:, None], moved).any(), i
    assert n_ok >= B // 2


def test_swept_box_covers_the_moving_box(rng):
    n = 200
    boxes = np.c_[rng.normal(0, 3, (n, 2)), rng.uniform(0.3, 3, (n, 2)), rng.uniform(-np.pi, np.pi, n)]
    vel = rng.normal(0, 1.5, (n, 2))
    vel[::5] = 0.0
    t0 = rng.uniform(-1, 1, n)
    t1 = t0 + rng.uniform(0, 3, n)
    sw = np.asarray(jax.jit(swept_boxes)(jnp.asarray(boxes, jnp.float32), jnp.asarray(vel, jnp.float32),
                                         jnp.asarray(t0, jnp.float32), jnp.asarray(t1, jnp.float32)))
    for i in range(n):
        hull = shapely.convex_hull(shapely.multipoints(np.concatenate(
            [corners(*np.r_[boxes[i, :2] + vel[i] * t, boxes[i, 2:]]) for t in (t0[i], t1[i])])))
        s = box_polygon(sw[i])
        assert hull.difference(s).area < 1e-3 * hull.area + 1e-5, i
        if np.allclose(vel[i], 0):
            assert abs(s.area - hull.area) < 1e-3
        # aligned with the velocity: the swept box is the hull exactly
        aligned = np.r_[boxes[i, :4], np.arctan2(vel[i, 1], vel[i, 0])]
        if not np.allclose(vel[i], 0):
            sa = box_polygon(np.asarray(swept_boxes(jnp.asarray(aligned), jnp.asarray(vel[i]), t0[i], t1[i])))
            ha = shapely.convex_hull(shapely.multipoints(np.concatenate(
                [corners(*np.r_[aligned[:2] + vel[i] * t, aligned[2:]]) for t in (t0[i], t1[i])])))
            assert abs(sa.area - ha.area) < 1e-3 * ha.area + 1e-4


def test_a_crossing_pedestrian_is_predicted_as_moving():
    start, goal = np.array([0.0, 0.0, 0.0]), np.array([30.0, 0.0, 0.0])
    ped = [15.0, -2.0, 0.6, 0.6, np.pi / 2]
    rows = [
        # Walks off the path long before the car gets there (its 2 s swept box held static would block).
        request(start, goal, False, [ped], [[0.0, 1.3]]),
        # Far from the path now, but on it when the car arrives: pass behind it (the side it came from).
        request(start, goal, False, [[15.0, -8.0, 0.6, 0.6, np.pi / 2]], [[0.0, 1.3]]),
        # The same pedestrian standing still is no obstacle at all.
        request(start, goal, False, [[15.0, -8.0, 0.6, 0.6, np.pi / 2]], [[0.0, 0.0]]),
    ]
    out = plan_batch(rows)
    for i in range(3):
        assert bool(out.ok[i]), i
    k = [int(out.valid[i].sum()) for i in range(3)]
    y = [out.traj.y[i, :k[i]] for i in range(3)]
    x = [out.traj.x[i, :k[i]] for i in range(3)]
    assert np.abs(y[0]).max() < 0.05 and np.abs(y[2]).max() < 0.05  # straight on
    near = np.abs(x[1] - 15.0) < 1.0
    assert y[1][near].max() < -1.0  # behind the pedestrian
    # A static box the size of the pedestrian's 2 s walk would have forced a detour.
    held = request(start, goal, False, [[15.0, -2.0 + 1.3, 0.6 + 2.6, 0.6, np.pi / 2]], [[0.0, 0.0]])
    out2 = plan_batch([held])
    k2 = int(out2.valid[0].sum())
    assert np.abs(out2.traj.y[0, :k2]).max() > 1.0
