"""Human demonstrations from recorded traffic (host side, numpy).

Every recorded vehicle with enough past and future becomes a demonstration: its
state at a start time, the centre line of the lane it drives in (following
successors), the other recorded vehicles as obstacles with their recorded futures
as predictions, and its own recorded future as the human choice. Each
demonstration is moved into its own local frame (start position at the origin,
headings unchanged) and padded to fixed sizes, so a list of them stacks into one
batched pytree.

The start state is estimated from the past only, as a planner would see it
(``fit_start_state``): the acceleration from a least-squares quadratic fit of the
positions over the last ``history`` seconds (>= 1 s; a one-step difference of NGSIM
speeds put a quarter of the starts beyond [-4, 2.5] m/s^2), the speed and heading
from the last step.

Short recordings (NGSIM Lankershim keeps 1-5.5 s per file) fit as long as they
hold ``history`` seconds before the start and ``min_future`` seconds after it; the
future is padded to ``horizon`` and ``human_valid`` marks the recorded part.

Each demonstration also carries host-side bookkeeping (``DemoIndex``): its scenario,
location (``location_of``), the recorded vehicle and that vehicle's identity across
files (``jaxplan.tuning.vehicles``), used for splits disjoint by vehicle and
confidence intervals over scenarios.
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np

from jaxplan.scenarios.fields import ScenarioError
from jaxplan.scenarios.polylines import arc_length, nearest_on_polyline, resample_polyline
from jaxplan.scenarios.scenario import Scenario, lane_at, lane_polyline

LOCATIONS = ("US-101", "Lankershim", "German roads", "other")


def location_of(scenario_id: str) -> str:
    """The recording location of a scenario id (CommonRoad naming): ``US-101``
    (``USA_US101-*``), ``Lankershim`` (``USA_Lanker-*``), ``German roads`` (``DEU_*``)
    or ``other`` (``ZAM_*`` and anything else)."""
    if scenario_id.startswith("USA_US101"):
        return "US-101"
    if scenario_id.startswith("USA_Lanker"):
        return "Lankershim"
    if scenario_id.startswith("DEU_"):
        return "German roads"
    return "other"


@dataclasses.dataclass(frozen=True)
class DemoConfig:
    """Sizes of a demonstration (static).

    Attributes:
        horizon: seconds of human future kept (T = horizon / dt + 1 samples, padded
            past the recording; ``human_valid`` marks the recorded samples).
        min_future: seconds of recorded future a start needs (<= horizon).
        history: seconds of past the start state is fitted on (>= 1 s, see the module docstring).
        stride: seconds between start times taken from one recorded vehicle.
        n_obstacles: K, the nearest other vehicles kept at the start.
        ref_points: P, samples of the reference line.
        ref_back, ref_ahead: metres of reference line behind and ahead of the start.
        min_speed: vehicles slower than this at the start are skipped (m/s).
        max_lane_offset: start farther than this from the lane centre is skipped (m).
    """

    horizon: float = 5.0
    min_future: float = 3.0
    history: float = 1.0
    stride: float = 1.0
    n_obstacles: int = 16
    ref_points: int = 96
    ref_back: float = 10.0
    ref_ahead: float = 180.0
    min_speed: float = 1.0
    max_lane_offset: float = 2.5

    def validate(self) -> DemoConfig:
        if not 0 < self.min_future <= self.horizon:
            raise ValueError(f"DemoConfig: need 0 < min_future <= horizon, got {self.min_future}, {self.horizon}")
        if self.history < 1.0:
            raise ValueError(f"DemoConfig.history must be >= 1 s (a smoothed fit), got {self.history}")
        if self.stride <= 0 or self.n_obstacles < 1 or self.ref_points < 2:
            raise ValueError("DemoConfig: need stride > 0, n_obstacles >= 1, ref_points >= 2")
        return self


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Demo:
    """One demonstration (or a batch with leading dims), in its local frame: numpy arrays as
    ``scenario_demos`` builds them, jax arrays once ``stack``ed.

    Attributes:
        ego: ``(5,)`` start state [x, y, heading, v, a] (x = y = 0), fitted on the past.
        ref_xy: ``(P, 2)`` reference line samples (lane centre line).
        obstacles: ``(K, T, 5)`` other vehicles' boxes at the demo's times.
        obstacle_valid: ``(K, T)``.
        obstacle_static: ``(K,)`` static obstacles (held over any horizon).
        human_xy: ``(T, 2)`` the recorded future (index 0 = start), padded by its last point.
        human_v: ``(T,)`` recorded speed (chord length / dt), padded likewise.
        human_valid: ``(T,)`` bool, the recorded samples.
        t: ``(T,)`` times from the start.
    """

    ego: jax.Array | np.ndarray
    ref_xy: jax.Array | np.ndarray
    obstacles: jax.Array | np.ndarray
    obstacle_valid: jax.Array | np.ndarray
    obstacle_static: jax.Array | np.ndarray
    human_xy: jax.Array | np.ndarray
    human_v: jax.Array | np.ndarray
    human_valid: jax.Array | np.ndarray
    t: jax.Array | np.ndarray


@dataclasses.dataclass(frozen=True)
class DemoIndex:
    """Host-side bookkeeping of demonstrations, numpy arrays ``(B,)``.

    Attributes:
        scenario: scenario ids; location: ``location_of`` each;
        obstacle_id: the recorded vehicle's id in its scenario;
        vehicle: the vehicle's identity across scenarios (``jaxplan.tuning.vehicles``;
            ``""`` when not computed); start: start time in the recording (s).
    """

    scenario: np.ndarray
    location: np.ndarray
    obstacle_id: np.ndarray
    vehicle: np.ndarray
    start: np.ndarray

    def __len__(self) -> int:
        return len(self.scenario)

    def take(self, idx) -> DemoIndex:
        return DemoIndex(*(np.asarray(getattr(self, f.name))[idx] for f in dataclasses.fields(self)))

    @staticmethod
    def concat(parts) -> DemoIndex:
        return DemoIndex(*(np.concatenate([getattr(p, f.name) for p in parts]) for f in dataclasses.fields(DemoIndex)))


@dataclasses.dataclass(frozen=True)
class DemoSet:
    """Batched demonstrations (``Demo`` with leading axis ``B``) and their ``DemoIndex``."""

    demos: Demo
    index: DemoIndex

    def __len__(self) -> int:
        return len(self.index)

    def take(self, idx) -> DemoSet:
        """A subset by integer indices or a boolean mask ``(B,)``."""
        idx = np.asarray(idx)
        if idx.dtype == bool:
            idx = np.nonzero(idx)[0]
        return DemoSet(jax.tree_util.tree_map(lambda x: x[idx], self.demos), self.index.take(idx))


def fit_start_state(xy_past: np.ndarray, dt: float, heading_fallback: float, min_speed: float = 0.5):
    """Speed, heading and acceleration at the last of ``xy_past``, from the past only.

    The acceleration is the tangential part of ``2 c2`` of a least-squares quadratic
    ``p(t) = c0 + c1 t + c2 t^2`` over the whole window (>= 1 s: a one-step
    difference of NGSIM positions is noise); the speed and heading come from the last
    step, ``|p(0) - p(-dt)| / dt + a dt / 2`` (the backward difference is the speed at
    ``-dt / 2``). On NGSIM US-101 the last step predicts the next 3 s far better than a
    fitted velocity (constant-velocity ADE3 1.03 m against 1.23 m for a 1 s quadratic
    fit: the fit lags), and past accelerations do not predict the next second's
    (correlation about -0.1), so the acceleration is for the models that want one.
    Exact for motion along a straight line at constant acceleration.

    Args:
        xy_past: ``(H + 1, 2)`` positions at times ``-H dt .. 0`` (``H >= 2``).
        dt: sample step (s).
        heading_fallback: heading used when the car moved less than ``min_speed * dt`` in the last step.

    Returns:
        (v, heading, a) at time 0: speed (m/s), direction of motion (rad), acceleration (m/s^2).
    """
    xy = np.asarray(xy_past, np.float64)
    H = len(xy) - 1
    if H < 2:
        raise ValueError(f"fit_start_state: need at least 3 samples, got {len(xy)}")
    t = (np.arange(H + 1) - H) * dt
    A = np.column_stack([np.ones_like(t), t, t * t])
    coef, *_ = np.linalg.lstsq(A, xy, rcond=None)  # (3, 2)
    step = xy[-1] - xy[-2]
    d = float(np.linalg.norm(step))
    if d < min_speed * dt:
        u = np.array([np.cos(heading_fallback), np.sin(heading_fallback)])
        heading = float(heading_fallback)
    else:
        u = step / d
        heading = float(np.arctan2(u[1], u[0]))
    a = float(2.0 * coef[2] @ u)
    return max(d / dt + 0.5 * a * dt, 0.0), heading, a


def scenario_demos(sc: Scenario, cfg: DemoConfig = DemoConfig()) -> tuple[list[Demo], DemoIndex]:
    """Every demonstration of one scenario, as unbatched numpy-backed ``Demo``s, and their index."""
    cfg.validate()
    boxes = np.asarray(sc.obstacles.boxes, np.float64)  # (K, S, 5)
    valid = np.asarray(sc.obstacles.valid)  # (K, S)
    static = np.asarray(sc.obstacles.static, bool)  # (K,)
    n_t = int(round(cfg.horizon / sc.dt)) + 1
    n_min = int(round(cfg.min_future / sc.dt)) + 1
    H = int(round(cfg.history / sc.dt))
    stride = max(1, int(round(cfg.stride / sc.dt)))
    S = boxes.shape[1] if boxes.ndim == 3 else 0
    K = cfg.n_obstacles
    demos, rows = [], []
    for i in range(boxes.shape[0]):
        if static[i]:
            continue
        for k0 in range(H, S - n_min + 1, stride):
            n_rec = min(n_t, S - k0)
            if not valid[i, k0 - H : k0 + n_rec].all():
                continue
            x0, y0, _, _, th_box = boxes[i, k0]
            origin = np.array([x0, y0])
            v0, th0, a0 = fit_start_state(boxes[i, k0 - H : k0 + 1, :2], sc.dt, th_box)
            if v0 < cfg.min_speed:
                continue
            try:
                lane = lane_at(sc, [x0, y0], th0)
                rxy = lane_polyline(sc, lane, max_length=cfg.ref_ahead + 50.0)
            except ScenarioError:
                continue
            keep = np.concatenate([[True], np.linalg.norm(np.diff(rxy, axis=0), axis=1) > 1e-3])
            rxy = rxy[keep]  # lanelets share their end points
            rs = arc_length(rxy)
            j, along, off = nearest_on_polyline(rxy, origin)
            if off > cfg.max_lane_offset:
                continue
            s0 = rs[j] + along
            ref_xy = resample_polyline(rxy, rs, np.linspace(s0 - cfg.ref_back, s0 + cfg.ref_ahead, cfg.ref_points))
            traj = np.empty((n_t, 2))
            traj[:n_rec] = boxes[i, k0 : k0 + n_rec, :2]
            traj[n_rec:] = traj[n_rec - 1]
            v = np.zeros(n_t)
            v[: n_rec - 1] = np.linalg.norm(np.diff(traj[:n_rec], axis=0), axis=1) / sc.dt
            v[n_rec - 1 :] = v[n_rec - 2]
            hv = np.arange(n_t) < n_rec
            # the K others nearest the start (present at the start); their recorded futures
            others = np.array([j for j in range(boxes.shape[0]) if j != i and valid[j, k0]], int)
            obs = np.zeros((K, n_t, 5))
            obs[..., 2:4] = 1.0  # padding: unit boxes, never valid
            ok = np.zeros((K, n_t), bool)
            st = np.zeros(K, bool)
            if len(others):
                dist = np.linalg.norm(boxes[others, k0, :2] - origin, axis=1)
                near = others[np.argsort(dist)[:K]]
                m = min(n_t, S - k0)
                obs[: len(near), :m] = boxes[near, k0 : k0 + m]
                ok[: len(near), :m] = valid[near, k0 : k0 + m]
                st[: len(near)] = static[near]
                ok[: len(near)] |= st[: len(near), None]  # static boxes are held past the recording
                obs[: len(near), m:] = np.where(
                    st[: len(near), None, None], boxes[near, k0 : k0 + 1], obs[: len(near), m:]
                )
                obs[..., :2] -= origin
                obs[~ok] = [0.0, 0.0, 1.0, 1.0, 0.0]
            demos.append(
                Demo(
                    np.array([0.0, 0.0, th0, v0, a0]),
                    ref_xy - origin,
                    obs,
                    ok,
                    st,
                    traj - origin,
                    v,
                    hv,
                    np.arange(n_t) * sc.dt,
                )
            )
            rows.append((sc.id, int(sc.obstacle_ids[i]), k0 * sc.dt))
    index = DemoIndex(
        np.array([r[0] for r in rows], dtype=object),
        np.array([location_of(r[0]) for r in rows], dtype=object),
        np.array([r[1] for r in rows], int),
        np.full(len(rows), "", dtype=object),
        np.array([r[2] for r in rows], float),
    )
    return demos, index


def stack(demos: list[Demo]) -> Demo:
    """Stack demonstrations into one batched ``Demo`` of float32 arrays."""
    if not demos:
        raise ValueError("no demonstrations to stack")
    return jax.tree.map(
        lambda *xs: jnp.asarray(np.stack(xs), jnp.float32 if np.asarray(xs[0]).dtype.kind == "f" else None), *demos
    )


def demo_set(scenarios, cfg: DemoConfig = DemoConfig(), identities: dict | None = None) -> DemoSet | None:
    """Every demonstration of loaded scenarios, batched, with its index.

    Args:
        scenarios: ``Scenario``s.
        identities: ``{(scenario id, obstacle id): vehicle identity}`` (``vehicles.vehicle_identities``);
            computed here when None.

    Returns:
        ``DemoSet`` or None when no scenario has a demonstration.
    """
    from jaxplan.tuning.vehicles import vehicle_identities

    scenarios = list(scenarios)
    if identities is None:
        identities = vehicle_identities(scenarios)
    demos, parts = [], []
    for sc in scenarios:
        d, ix = scenario_demos(sc, cfg)
        demos += d
        parts.append(ix)
    if not demos:
        return None
    index = DemoIndex.concat(parts)
    vehicle = np.array(
        [identities.get((s, int(o)), "") for s, o in zip(index.scenario, index.obstacle_id)], dtype=object
    )
    return DemoSet(stack(demos), dataclasses.replace(index, vehicle=vehicle))


def load_demos(scenarios, cfg: DemoConfig = DemoConfig(), share: int = 4) -> tuple[Demo | None, Demo | None, dict]:
    """Train and validation demonstrations from loaded scenarios, split by vehicle
    (``vehicles.split_by_vehicle``: no recorded vehicle is on both sides).

    Returns:
        (train, validation, info) where each is a batched ``Demo`` or None when empty,
        and info counts demonstrations per scenario.
    """
    from jaxplan.tuning.vehicles import split_by_vehicle

    ds = demo_set(scenarios, cfg)
    if ds is None:
        return None, None, {sc.id: 0 for sc in scenarios}
    val = split_by_vehicle(ds.index, share)
    info = {sc.id: int(np.sum(ds.index.scenario == sc.id)) for sc in scenarios}
    pick = lambda m: ds.take(m).demos if m.any() else None
    return pick(~val), pick(val), info


def synthetic_demos(n: int, seed: int = 0, cfg: DemoConfig = DemoConfig()) -> Demo:
    """``n`` demonstrations from ``jaxplan.scenarios.synthetic.road_scenes``.

    The "human" future keeps the start speed on the lane centre (replace it, for
    example with a lattice driver's choice, to generate choices with known weights).
    """
    from jaxplan.scenarios.synthetic import road_scenes

    sc = road_scenes(n, seed, cfg.n_obstacles, cfg.horizon, 0.1, cfg.ref_points, cfg.ref_back, cfg.ref_ahead)
    v = np.repeat(sc.ego[:, 3:4], sc.t.shape[1], axis=1)
    f32 = lambda x: jnp.asarray(x, jnp.float32)
    return Demo(
        f32(sc.ego),
        f32(sc.ref_xy),
        f32(sc.boxes),
        jnp.asarray(sc.valid),
        jnp.asarray(sc.static, bool),
        f32(sc.cruise),
        f32(v),
        jnp.ones(v.shape, bool),
        f32(sc.t),
    )


def synthetic_set(n: int, seed: int = 0, cfg: DemoConfig = DemoConfig(), per_scenario: int = 4) -> DemoSet:
    """``synthetic_demos`` with an index: ``per_scenario`` demonstrations per made-up scenario
    ``syn-<k>``, one vehicle each, location ``other``."""
    d = synthetic_demos(n, seed, cfg)
    sid = np.array([f"syn-{seed}-{i // per_scenario}" for i in range(n)], dtype=object)
    return DemoSet(
        d,
        DemoIndex(
            sid,
            np.full(n, "other", dtype=object),
            np.arange(n),
            np.array([f"{s}:{i}" for i, s in enumerate(sid)], dtype=object),
            np.zeros(n),
        ),
    )
