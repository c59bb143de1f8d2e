"""The lattice in closed loop: it keeps moving when nothing asks it to stop, starts from a queue
when the leader leaves, stops before a dead end (and keeps its speed for one it cannot reach before
the drive ends), leaves room to a vehicle closing in from behind,
and yields at a T-junction before turning (one compiled drive for the synthetic scenes)."""
import dataclasses
import glob
import os

import jax
import numpy as np
import pytest
from conftest import DATA_DIR, shared_data_or_skip

from jaxplan.lattice.planner import LatticePlanner
from jaxplan.scenarios.batch import stack_scenes
from jaxplan.sim import SimConfig
from jaxplan.sim.rollout import ChunkedRollout, driven_scene
from jaxplan.sim.metrics.registry import evaluate_batch
from jaxplan.sim.verdict import success
from test_sim import _record, _road_dict

N_STEPS = 150
T = np.arange(N_STEPS + 1) * 0.1


def _queue():
    """The car stands 5.4 m (bumper to bumper) behind a stopped car that leaves at t = 2 s (2 m/s^2
    to 12 m/s)."""
    tt = np.arange(251) * 0.1
    go = np.clip(tt - 2.0, 0.0, None)
    s = 30.0 + 10.0 + np.where(go < 6.0, go ** 2, 36.0 + 12.0 * (go - 6.0))
    d = _road_dict(obstacles=[(s, np.zeros(251))], v0=0.0, goal_t=(0.0, 12.0))
    return dataclasses.replace(_record(d), name="QUEUE")


def _empty_time_goal():
    """An empty road and a goal that is only a time (survive until 3.3 s)."""
    d = _road_dict(v0=15.0)
    d["planning_problems"][0]["goals"][0] = {"time": [3.3, 3.3]}
    return dataclasses.replace(_record(d), name="EMPTY")


def _dead_end():
    """The road ends 120 m ahead of the car (15 m/s) and the goal is only a time (survive until 14 s):
    driving on leaves the road."""
    d = _road_dict(v0=15.0)
    for lane in d["lanelets"]:
        lane["left"], lane["right"] = lane["left"][:76], lane["right"][:76]  # 150 m of road
    d["planning_problems"][0]["goals"][0] = {"time": [14.0, 14.0]}
    return dataclasses.replace(_record(d), name="DEADEND")


def _far_dead_end():
    """The road ends 70 m ahead of the car (15 m/s, limit 20 m/s) and the goal is only a time
    (survive until 3.3 s): the drive ends before the car could get to the end."""
    d = _road_dict(v0=15.0)
    for lane in d["lanelets"]:
        lane["left"], lane["right"] = lane["left"][:51], lane["right"][:51]  # 100 m of road
    d["planning_problems"][0]["goals"][0] = {"time": [3.0, 3.3]}
    return dataclasses.replace(_record(d), name="FAREND")


def _closing_in():
    """A car 12 m behind (bumper to bumper about 7.5 m) at 20 m/s while the car drives 15 m/s on a
    two-lane road: keeping the speed gets it rear-ended within 1.5 s."""
    tt = np.arange(251) * 0.1
    d = _road_dict(obstacles=[(30.0 - 12.0 + 20.0 * tt, np.zeros(251))], v0=15.0, goal_t=(0.0, 8.0))
    return dataclasses.replace(_record(d), name="BEHIND")


def _tjunction():
    """A recorded T-junction of the development set where the car turns left across an oncoming car
    (None without the shared data)."""
    files = glob.glob(os.path.join(DATA_DIR, "commonroad", "hand-crafted", "ZAM_Tjunction-1_100_T-1.xml.gz"))
    if not files:
        return None
    from jaxplan.scenarios.files import load_records

    return dataclasses.replace(load_records(files)[0], name="TJUNCTION")


@pytest.fixture(scope="module")
def drives():
    """Every scene in one batch: one compiled drive."""
    recs = [_queue(), _empty_time_goal(), _closing_in(), _dead_end(), _far_dead_end()]
    tj = _tjunction()
    recs += [tj] if tj is not None else []
    batch = stack_scenes([r.scene for r in recs])
    planner = LatticePlanner()
    cfg = SimConfig(n_steps=N_STEPS)
    log = ChunkedRollout(planner, cfg)(batch)
    jlog = jax.tree_util.tree_map(np.asarray, log)
    m = evaluate_batch(jax.tree_util.tree_map(lambda a: a, log), driven_scene(log, batch), planner.vehicle)
    return {r.name: (jax.tree_util.tree_map(lambda a, i=i: np.asarray(a)[i], jlog),
                     {k: np.asarray(v)[i] for k, v in m.items()}, r) for i, r in enumerate(recs)}


def test_starts_from_a_queue_when_the_leader_leaves(drives):
    log, m, _ = drives["QUEUE"]
    assert not m["overlap.collided"]
    moving = np.nonzero(log.v > 0.5)[0]
    assert len(moving) and T[moving[0]] <= 4.0  # the leader leaves at 2 s; the car follows within 2 s
    assert log.v[int(log.end_step)] > 5.0 or m["goal.reached"]


def test_does_not_brake_on_an_empty_road_with_a_time_only_goal(drives):
    log, m, _ = drives["EMPTY"]
    assert m["goal.reached"] and not m["overlap.collided"] and not m["offroad.offroad"]
    assert m["comfort.min_accel"] > -1.0  # no braking without a reason
    assert log.v[int(log.end_step)] > 13.0


def test_stops_before_a_dead_end_when_the_goal_is_only_a_time(drives):
    log, m, _ = drives["DEADEND"]
    assert m["goal.reached"] and not m["overlap.collided"] and not m["offroad.offroad"]
    assert log.v[int(log.end_step)] < 0.5 and m["comfort.min_accel"] > -5.0  # stopped, within the comfortable limits


def test_keeps_its_speed_for_a_dead_end_it_cannot_reach_before_the_drive_ends(drives):
    log, m, _ = drives["FAREND"]
    assert m["goal.reached"] and not m["overlap.collided"] and not m["offroad.offroad"]
    assert m["comfort.min_accel"] > -0.5 and log.v[int(log.end_step)] > 14.5, (m["comfort.min_accel"], log.v)


def test_leaves_room_to_a_car_closing_in_from_behind(drives):
    log, m, _ = drives["BEHIND"]
    assert not m["overlap.collided"] and not m["offroad.offroad"]


def test_yields_at_a_t_junction_and_then_turns(drives):
    """ZAM_Tjunction-1_100: a car crosses the junction ahead at about 4-5 s; the lattice lets it pass, then
    turns into the goal road within the goal's 0.1 s window, touching nothing."""
    shared_data_or_skip("commonroad")
    log, m, rec = drives["TJUNCTION"]
    assert success({k: v.item() for k, v in m.items()}), m
    # it gave way: the crossing car (obstacle 0) passed the point where the two paths meet before the car
    n = int(log.end_step) + 1
    xy = np.stack([log.x[:n], log.y[:n]], -1)
    other = np.asarray(rec.scene.obstacles.boxes[0, :n, :2])
    d = np.linalg.norm(xy[:, None] - other[None], axis=-1)  # (car step, other step)
    i, j = np.unravel_index(np.argmin(d), d.shape)
    assert d[i, j] < 3.0 and j < i  # the other car was at the meeting point first
