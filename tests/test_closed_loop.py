"""The closed-loop objective and tuning (``jaxplan.tuning.closed_loop``) and the lattice's soft selection."""
import dataclasses
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxplan.baselines import BrakePlanner, IDMPlanner
from jaxplan.lattice.cost import soft_choice
from jaxplan.scenarios.batch import stack_scenes
from jaxplan.sim import SimConfig, rollout
from jaxplan.sim.rollout import driven_scene
from jaxplan.tuning.closed_loop import ObjectiveWeights, drive_objective
from test_drive_runner import _records

CFG = SimConfig(n_steps=40, stop_at_goal=False)


def _drives(planner):
    batch = stack_scenes([r.scene for r in _records()])
    log = rollout(planner, batch, CFG)
    return log, driven_scene(log, batch)


def test_objective_terms_respond_to_what_they_measure():
    """Progress lowers ``short``; a car moved into an obstacle or past the road's edge raises
    ``clearance`` / ``road``; the total is the weighted sum and its gradient by the states is finite."""
    car = IDMPlanner().vehicle
    objective = jax.jit(drive_objective, static_argnums=2)  # one program per shape, not one per operation
    go, scene = _drives(IDMPlanner())
    stop, _ = _drives(BrakePlanner())
    t_go, t_stop = objective(go, scene, car), objective(stop, scene, car)
    assert float(t_go["short"][0]) < float(t_stop["short"][0]) - 30.0  # the free road: IDM drives on
    assert float(t_go["human"][0]) == 0.0  # no recording given
    w = ObjectiveWeights()
    np.testing.assert_allclose(np.asarray(t_go["total"]), np.asarray(w.total(t_go)), rtol=1e-6)
    # the slower car ahead (scene 2): put the car on it for the last steps
    one = jax.tree_util.tree_map(lambda a: a[2], go)
    sc1 = jax.tree_util.tree_map(lambda a: a[2], scene)
    box = np.asarray(one.traffic.boxes[0, -5:])
    hit = dataclasses.replace(one, x=one.x.at[-5:].set(box[:, 0]), y=one.y.at[-5:].set(box[:, 1]))
    base, bad = objective(one, sc1, car), objective(hit, sc1, car)
    assert float(bad["clearance"]) > float(base["clearance"]) + 0.2
    off = dataclasses.replace(one, y=one.y + 30.0)
    assert float(objective(off, sc1, car)["road"]) > float(base["road"]) + 10.0
    g = jax.jit(jax.grad(lambda y: drive_objective(dataclasses.replace(hit, y=y), sc1, car)["total"]))(hit.y)
    assert np.all(np.isfinite(np.asarray(g))) and float(jnp.max(jnp.abs(g))) > 0


def test_soft_choice_tends_to_the_exact_choice():
    """Excluded (inf) candidates get no weight; at a small temperature the weights are the one-hot of
    the least cost; with every candidate excluded, the one-hot of the given choice."""
    sel = jnp.asarray([3.0, jnp.inf, 1.0, 1.5])
    p = soft_choice(sel, jnp.asarray(2), 1.0)
    assert float(p[1]) == 0.0 and float(jnp.sum(p)) == pytest.approx(1.0) and float(p[0]) > 0
    np.testing.assert_allclose(np.asarray(soft_choice(sel, jnp.asarray(2), 1e-3)), [0, 0, 1, 0], atol=1e-6)
    none = soft_choice(jnp.full((4,), jnp.inf), jnp.asarray(3), 1.0)
    np.testing.assert_array_equal(np.asarray(none), [0, 0, 0, 1])
    g = jax.grad(lambda c: soft_choice(jnp.asarray([c, jnp.inf, 1.0]), jnp.asarray(2), 1.0)[0])(2.0)
    assert np.isfinite(float(g)) and float(g) < 0


def test_tune_closed_loop_command_splits_by_location_and_writes_weights_drive_takes(tmp_path, capsys):
    """``jaxplan tune idm --closed-loop`` on files of several locations: training and validation by
    location, a weights file that ``jaxplan drive --weights`` accepts, the loss-curve picture; a set of
    files from one split only is refused naming the empty split."""
    from jaxplan.cli import main
    from jaxplan.scenarios.files import split_of
    from test_sim import _road_dict

    names, k = {"train": [], "validation": []}, 0
    while min(len(v) for v in names.values()) < 2:
        name = f"DEU_Town{k}-1_1_T-1"
        names[split_of(name)].append(name)
        k += 1
    folder = tmp_path / "scenes"
    folder.mkdir()
    for split, ids in names.items():
        for i, name in enumerate(ids[:2]):
            d = _road_dict(v0=8.0 + 2 * i, goal_t=(0.0, 4.0))
            d["id"] = name
            (folder / f"{name}.json").write_text(json.dumps(d))
    out = tmp_path / "w.json"
    assert main(["tune", "idm", "--closed-loop", "--scenarios", str(folder), "--steps", "1", "--drive-steps", "20",
                 "--batch", "2", "--lr", "0.05", "--out", str(out)]) == 0
    figures = json.loads(capsys.readouterr().out.rsplit("\nwrote", 1)[0])
    assert figures["train_scenes"] == 2 and figures["validation_scenes"] == 2 and figures["steps_run"] == 1
    assert figures["lr"] == 0.05
    assert figures["validation.tuned"] <= figures["validation.default"] + 1e-9
    # drives: the validation scenes at the start, then per step a training batch and the validation scenes;
    # the baselines get as many validation evaluations as those drives allow
    assert figures["drives"] == 2 + (2 + 2)
    assert figures["random_search.evaluations"] == figures["cma_es.evaluations"] == 3
    assert figures["validation.random_search"] <= figures["validation.default"] + 1e-9
    assert (tmp_path / "w.png").stat().st_size > 0
    ck = json.loads((tmp_path / "w.ckpt.json").read_text())
    assert [h["step"] for h in ck["history"]] == [0, 1]
    saved = json.loads(out.read_text())
    assert saved["weights"] == ck["weights"]
    assert set(saved["weights"]) == {"time_gap", "min_gap", "a_max", "b_comf", "delta", "b_max"}
    from jaxplan.planner import make_planner

    make_planner("idm").init_params(saved["weights"])  # what drive --weights does with it
    for p in folder.glob("*.json"):
        if split_of(p.name) == "validation":
            p.unlink()
    assert main(["tune", "idm", "--closed-loop", "--scenarios", str(folder), "--out", str(out)]) == 2
    assert "no validation scenes" in capsys.readouterr().err


def test_lattice_soft_selection_tends_to_the_exact_plan_and_has_a_gradient():
    """The lattice with ``select_temperature``: at a tiny temperature its plan is the exact choice's;
    at 1 it is another, smooth in the weights (a finite, non-zero gradient of the plan's end)."""
    from jaxplan.lattice import CostWeights, LatticeConfig, PlanState, plan
    from jaxplan.types import Obstacles
    from jaxplan.geometry.frenet import ReferenceLine

    ref = ReferenceLine.from_polyline(np.column_stack([np.linspace(-10, 200, 100), np.zeros(100)]))
    t = jnp.arange(51) * 0.1
    lead = jnp.stack([25 + 5 * t, 0 * t, 4.5 + 0 * t, 1.8 + 0 * t, 0 * t], -1)[None]
    obs = Obstacles(lead, jnp.ones((1, 51), bool), t)
    state = PlanState.make(0.0, 0.4, 0.0, v=12.0)  # 0.4 m left of the lane's centre: the choices differ in cost
    w = jax.tree_util.tree_map(jnp.asarray, CostWeights())
    run = jax.jit(lambda w, temp: plan(state, ref, obs, LatticeConfig(select_temperature=temp), w).chosen_trajectory(),
                  static_argnums=1)
    exact = run(w, 0.0)
    cold = run(w, 1e-6)
    for k in ("x", "y", "v"):
        np.testing.assert_allclose(np.asarray(getattr(cold, k)), np.asarray(getattr(exact, k)), atol=1e-3)
    warm = run(w, 1.0)
    moved = lambda a, b: max(float(jnp.max(jnp.abs(getattr(a, k) - getattr(b, k)))) for k in "xyv")  # noqa: E731
    assert moved(warm, exact) > 1e-2
    g = jax.grad(lambda w: run(w, 1.0).y[-1])(w)
    leaves = np.array([float(x) for x in jax.tree_util.tree_leaves(g)])
    assert np.all(np.isfinite(leaves)) and np.max(np.abs(leaves)) > 0
    with pytest.raises(ValueError, match="select_temperature"):
        LatticeConfig(select_temperature=-1.0).validate()


def test_a_non_finite_gradient_stops_tuning_and_keeps_the_defaults(monkeypatch):
    """An objective whose gradient is not finite at the defaults (sqrt at 0): the loop stops at that
    step, says so in its history, and keeps the default weights (it stepped to NaN weights and drove
    with them)."""
    import collections

    import jax.numpy as jnp

    from jaxplan.planner import make_planner
    from jaxplan.tuning import closed_loop as cl

    fake = lambda planner, config, objective: (  # noqa: E731
        lambda params, scenes: jnp.sqrt(jnp.maximum(params.alpha - 1.0, 0.0)) + 0.0 * jnp.sum(scenes.start))
    monkeypatch.setattr(cl, "_objective_fn", fake)
    Scenes = collections.namedtuple("Scenes", "start")
    planner = make_planner("lattice", options=(("select_temperature", 1.0),))
    res = cl.tune_closed_loop(planner, Scenes(jnp.zeros((4, 5))), Scenes(jnp.zeros((2, 5))), None, steps=3,
                              batch=2, baselines=False, progress=False)
    assert [h["step"] for h in res.history] == [0, 1] and res.history[-1]["nonfinite_gradient"]
    assert res.history[-1]["val"] is None
    assert res.weights["alpha"] == pytest.approx(float(planner.init_params().alpha))
    assert all(np.isfinite(v) for v in res.weights.values())
