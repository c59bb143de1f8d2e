"""Closed-loop tuning: a smooth objective of a drive, differentiable in the planner's params
through ``jaxplan.sim.rollout``.

``drive_objective(log, scene, vehicle, weights)`` scores one drive (add a leading axis for a
batch: it is vmapped) by the terms users ask of a drive, each ``()`` per drive and smooth in
the driven states:

- ``short``: metres the car's box centre ends short of the goal region's near end along the
  route (``Goal.s_range``; without a region, of the distance the drive's time allows at the
  first speed limit), through a softplus of width ``SOFT`` m;
- ``jerk``, ``lat_acc``: mean squared longitudinal jerk (m^2/s^6) and lateral acceleration
  (``v^2 kappa``, m^2/s^4) over the drive's steps;
- ``clearance``: the car's intrusion into a ``margin`` around every obstacle (the signed box
  separation of the geometry core, ``box_separation``), summed over obstacles and averaged over
  steps (softplus of width ``SOFT``); a collision is a large intrusion;
- ``road``: the car's intrusion past the road's edges (``Scene.road_left / road_right``),
  averaged over steps;
- ``human``: mean squared distance (m^2) to a recording of the same car, where one is given.

``ObjectiveWeights`` weighs them (the one place they are set). With the lattice's soft
selection (``LatticeConfig.select_temperature > 0``) a drive is smooth in the cost weights, and
``jax.grad(lambda p: objective(rollout(planner, scenes, config, p)))`` is the gradient that
``tune_closed_loop`` follows (optax).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from jaxplan.geometry.boxes import box_separation
from jaxplan.geometry.frenet import to_frenet

SOFT = 0.2  # m: width of the softplus that makes the one-sided terms smooth


def _soft_pos(x, width: float = SOFT):
    """``(...)`` a smooth ``max(x, 0)`` (softplus of width ``width``; ``width * log 2`` at 0)."""
    return width * jax.nn.softplus(x / width)


@dataclasses.dataclass(frozen=True)
class ObjectiveWeights:
    """Weights of the closed-loop objective's terms (module docstring) and the clearance margin."""

    short: float = 1.0  # per metre short of the goal region
    jerk: float = 0.002  # per m^2/s^6
    lat_acc: float = 0.02  # per m^2/s^4
    clearance: float = 50.0  # per metre of intrusion into the margin, per obstacle
    road: float = 20.0  # per metre past the road's edges
    human: float = 0.1  # per m^2 from the recording
    margin: float = 0.5  # m kept from every obstacle

    def total(self, terms: dict):
        """``(...)`` the weighted sum of ``terms`` (``drive_objective``'s dict)."""
        return sum(getattr(self, k) * terms[k] for k in ("short", "jerk", "lat_acc", "clearance", "road", "human"))


def drive_objective(log, scene, vehicle, weights: ObjectiveWeights = ObjectiveWeights(), human=None) -> dict:
    """The terms of the closed-loop objective and their ``total`` (module docstring).

    Args:
        log: ``DriveLog`` of one drive (fields ``(N,)``; its ``traffic`` the obstacles as driven) or a
            batch (a leading axis on ``log`` and ``scene``).
        scene: the ``Scene`` it was driven in.
        vehicle: the car's ``VehicleParams``.
        weights: ``ObjectiveWeights``.
        human: None, or ``(xy (N, 2), valid (N,))`` a recording of the same car (box centre).

    Returns:
        ``{"short", "jerk", "lat_acc", "clearance", "road", "human", "total"}``, each ``()`` (or
        ``(B,)`` for a batch).
    """
    if jnp.ndim(log.end_step) > 0:
        return jax.vmap(lambda lg, sc, h: drive_objective(lg, sc, vehicle, weights, h))(log, scene, human)
    f = log.x.dtype
    valid = log.valid
    n = jnp.maximum(jnp.sum(valid), 1).astype(f)
    dt = log.t[1] - log.t[0]
    xy = jnp.stack([log.x, log.y], -1)
    s, l = to_frenet(scene.route, xy)
    end = log.end_step
    goal = scene.goal
    horizon_m = scene.speed_limit[0] * log.t[-1]
    target = jnp.where(jnp.isfinite(goal.s_range[0]) & goal.has_region, goal.s_range[0], s[0] + horizon_m)
    short = _soft_pos(target - s[end])
    # comfort over the driven steps
    jerk = jnp.diff(log.a) / dt
    jerk2 = jnp.sum(jnp.where(valid[1:], jerk**2, 0.0)) / n
    lat2 = jnp.sum(jnp.where(valid, (log.v**2 * log.kappa) ** 2, 0.0)) / n
    # clearance to every obstacle at every step (the traffic as driven)
    obs = log.traffic
    car = jnp.concatenate(
        [xy, jnp.broadcast_to(jnp.asarray([vehicle.length, vehicle.width], f), xy.shape), log.heading[:, None]], -1
    )  # (N, 5)
    sep = box_separation(car[None], obs.boxes[:, : car.shape[0]])  # (K, N)
    ok = obs.valid[:, : car.shape[0]] & valid[None]
    clear = jnp.sum(jnp.where(ok, _soft_pos(weights.margin - sep), 0.0)) / n
    # the road's edges about the route at the car's station
    half = 0.5 * jnp.asarray(vehicle.width, f)
    left = jnp.interp(s, scene.route.s, scene.road_left)
    right = jnp.interp(s, scene.route.s, scene.road_right)
    past = _soft_pos(l + half - left) + _soft_pos(right - (l - half))
    road = jnp.sum(jnp.where(valid, past, 0.0)) / n
    if human is None:
        hum = jnp.zeros((), f)
    else:
        h_xy, h_ok = human
        m = valid & h_ok
        hum = jnp.sum(jnp.where(m, jnp.sum((xy - h_xy) ** 2, -1), 0.0)) / jnp.maximum(jnp.sum(m), 1).astype(f)
    terms = {"short": short, "jerk": jerk2, "lat_acc": lat2, "clearance": clear, "road": road, "human": hum}
    terms["total"] = weights.total(terms)
    return terms


# ----------------------------------------------------------------------------- tuning

TUNED = ("alpha", "beta", "delta", "jerk_lon", "jerk_lat", "obstacle", "v_offset", "goal")  # the lattice's
# trade-off weights; the rule's structural penalties (collision, level, infeasible, unsafe_end) stay


@dataclasses.dataclass
class TuneResult:
    """What ``tune_closed_loop`` found: ``weights`` (``{name: value}`` for the planner's
    ``init_params``), the ``history`` (per step: train loss, validation loss, drives so far; a
    step whose gradient was not finite ends the loop with ``nonfinite_gradient`` and no validation),
    the best validation loss and the baselines' (``{"default", "random_search", "cma_es"}``:
    best validation loss and weights found in the same budget of closed-loop drives)."""

    weights: dict
    history: list
    best_val: float
    baselines: dict


def exact_form(planner):
    """The planner as users drive it: a lattice without its ``select_temperature`` option (the
    exact choice); any other planner as it is."""
    options = getattr(planner, "options", None)
    if not options:
        return planner
    return dataclasses.replace(planner, options=tuple((k, v) for k, v in options if k != "select_temperature"))


def _objective_fn(planner, config, weights: ObjectiveWeights):
    from jaxplan.sim.rollout import driven_scene, rollout

    def f(params, scenes):
        log = rollout(planner, scenes, config, params)
        return jnp.mean(drive_objective(log, driven_scene(log, scenes), planner.vehicle, weights)["total"])

    return f


def _with(params, names, log_w):
    return dataclasses.replace(
        params, **{k: jnp.exp(log_w[i]).astype(jnp.result_type(getattr(params, k))) for i, k in enumerate(names)}
    )


def tune_closed_loop(
    planner,
    train,
    val,
    config,
    steps: int = 20,
    lr: float = 0.1,
    batch: int = 8,
    names: tuple = TUNED,
    objective: ObjectiveWeights = ObjectiveWeights(),
    seed: int = 0,
    patience: int = 5,
    baselines: bool = True,
    progress: bool = True,
    checkpoint: str | None = None,
) -> TuneResult:
    """Tune a planner's cost weights by gradient through closed-loop drives (optax Adam on their
    logarithms), with early stopping on the validation scenes, and the baselines given the same
    number of closed-loop drives.

    Args:
        planner: a planner whose smooth form is driven for the gradient (the lattice with
            ``select_temperature > 0``); validation and the baselines drive its exact form
            (``exact_form``), as a user drives it. Its params must be a dataclass pytree with the
            fields ``names`` (positive).
        train, val: batched ``Scene``s (a leading axis; split by location before tuning).
        config: ``SimConfig`` of the drives.
        steps: optimiser steps at most; lr: Adam's step on log-weights; batch: training scenes per step.
        names: the ``CostWeights`` fields tuned (others keep their defaults).
        objective: ``ObjectiveWeights`` of the closed-loop objective.
        patience: stop after this many steps without a better validation loss.
        baselines: also run random search and CMA-ES (the ``cma`` package) with the same budget.
        checkpoint: a JSON file written after every step (the best weights so far and the history).

    Returns:
        ``TuneResult``.
    """
    import json

    import numpy as np
    import optax
    from tqdm import tqdm

    exact = exact_form(planner)
    f_soft = _objective_fn(planner, config, objective)
    f_exact = _objective_fn(exact, config, objective)
    p0 = planner.init_params()
    x = jnp.log(jnp.stack([jnp.asarray(getattr(p0, k), jnp.result_type(float)) for k in names]))
    # one compiled program each for a training step's objective and gradient and for validation
    grad_fn = jax.jit(jax.value_and_grad(lambda lw, sc: f_soft(_with(p0, names, lw), sc)))
    val_exact = jax.jit(lambda lw, sc: f_exact(_with(p0, names, lw), sc))
    val_fn = lambda lw: float(val_exact(jnp.asarray(lw, x.dtype), val))  # noqa: E731
    n_train = int(train.start.shape[0])
    n_val = int(val.start.shape[0])
    rng = np.random.default_rng(seed)
    opt = optax.adam(lr)
    state = opt.init(x)
    best_val = val_fn(x)
    best_x, history, since, drives = x, [], 0, n_val
    history.append({"step": 0, "train": None, "val": best_val, "drives": drives})
    bar = tqdm(range(steps), desc="closed-loop tuning", unit="step", disable=not progress)
    for k in bar:
        idx = rng.choice(n_train, size=min(batch, n_train), replace=False)
        part = jax.tree_util.tree_map(lambda a: a[idx], train)
        loss, g = grad_fn(x, part)
        if not bool(jnp.all(jnp.isfinite(g))):  # never step to NaN weights: stop, keeping the best so far
            history.append(
                {
                    "step": k + 1,
                    "train": float(loss),
                    "val": None,
                    "drives": drives + len(idx),
                    "nonfinite_gradient": True,
                }
            )
            bar.set_postfix_str(f"non-finite gradient at step {k + 1}: stopped")
            break
        upd, state = opt.update(g, state, x)
        x = optax.apply_updates(x, upd)
        v = val_fn(x)
        drives += len(idx) + n_val
        history.append({"step": k + 1, "train": float(loss), "val": v, "drives": drives})
        if v < best_val - 1e-9:
            best_val, best_x, since = v, x, 0
        else:
            since += 1
        bar.set_postfix_str(f"train {float(loss):.3f} val {v:.3f} best {best_val:.3f}")
        if checkpoint:
            with open(checkpoint, "w") as fh:
                json.dump({"weights": _named(names, best_x), "history": history}, fh, indent=1)
        if since >= patience:
            break
    bar.close()
    base = {"default": {"val": history[0]["val"], "weights": {k: float(getattr(p0, k)) for k in names}}}
    if baselines:
        budget = max(1, drives // max(n_val, 1))  # evaluations of the validation set in the same drives
        base["random_search"] = _random_search(val_fn, base["default"], names, budget, rng)
        base["cma_es"] = _cma_es(val_fn, names, p0, budget, seed)
        for b in ("random_search", "cma_es"):
            base[b]["evaluations"] = budget
    return TuneResult(_named(names, best_x), history, best_val, base)


def _named(names, log_w) -> dict:
    return {k: float(jnp.exp(log_w[i])) for i, k in enumerate(names)}


def _random_search(val_fn, default: dict, names, budget: int, rng) -> dict:
    """Log-uniform perturbations (a factor up to e^1 either way) of the defaults."""
    import numpy as np

    x0 = np.log(np.array([default["weights"][k] for k in names]))
    best_x, best = x0, default["val"]
    for _ in range(max(0, budget - 1)):
        cand = x0 + rng.uniform(-1.0, 1.0, size=x0.shape)
        v = val_fn(jnp.asarray(cand))
        if v < best:
            best, best_x = v, cand
    return {"val": best, "weights": {k: float(np.exp(best_x[i])) for i, k in enumerate(names)}}


def _cma_es(val_fn, names, p0, budget: int, seed: int) -> dict:
    """CMA-ES (the ``cma`` package) on the log-weights from the defaults, step 0.5."""
    import cma
    import numpy as np

    x0 = np.log(np.array([float(getattr(p0, k)) for k in names]))
    es = cma.CMAEvolutionStrategy(x0, 0.5, {"seed": seed + 1, "verbose": -9, "maxfevals": max(budget, 2)})
    best_x, best = x0, float("inf")
    used = 0
    while not es.stop() and used < budget:
        xs = es.ask()
        xs = xs[: max(1, budget - used)]
        vals = [val_fn(jnp.asarray(xi)) for xi in xs]
        used += len(xs)
        if len(xs) == es.popsize:
            es.tell(xs, vals)
        i = int(np.argmin(vals))
        if vals[i] < best:
            best, best_x = vals[i], xs[i]
    return {"val": best, "weights": {k: float(np.exp(best_x[i])) for i, k in enumerate(names)}}


CLOSED_LOOP_PLANNERS = ("lattice", "idm")  # the planners whose drives are smooth in their params


def tune_files(
    paths,
    planner_name: str,
    out: str,
    scenes: int = 24,
    drive_steps: int = 80,
    steps: int = 20,
    batch: int = 8,
    lr: float = 0.1,
    temperature: float = 1.0,
    seed: int = 0,
    progress: bool = True,
) -> dict:
    """``jaxplan tune PLANNER --closed-loop``: tune on scenario files, split by location.

    The files (``expand_paths``) are split by location (``jaxplan.scenarios.files.split_of``, a
    rule fixed before any tuning) into training and validation; a seeded sample of ``scenes`` of
    them is driven, a quarter (at least 2) from the validation split, each part stratified by
    folder. Writes ``out`` (the tuned weights for ``jaxplan drive --weights``, with the figures as
    ``meta``), ``<out stem>.png`` (the loss curves and the baselines), ``<out stem>.ckpt.json``
    (after every step).

    Returns:
        the figures: validation objective of the defaults, of the tuned weights, of random search and
        of CMA-ES in the same drives, the steps run, the drives used, the scenes per split.

    Raises:
        ValueError: an unknown planner, no files, or a split without scenes (named).
    """
    import os

    from jaxplan.planner import make_planner
    from jaxplan.scenarios.batch import stack_scenes
    from jaxplan.scenarios.cache import enable_compilation_cache, load_many
    from jaxplan.scenarios.files import expand_paths, sample_files, split_of
    from jaxplan.sim import sizes
    from jaxplan.sim.rollout import SimConfig
    from jaxplan.weights import save_weights

    if planner_name not in CLOSED_LOOP_PLANNERS:
        raise ValueError(
            f"closed-loop tuning takes a planner whose drives are smooth in its params "
            f"({', '.join(CLOSED_LOOP_PLANNERS)}), got {planner_name!r}"
        )
    files = expand_paths(list(paths))
    split = {
        "train": [f for f in files if split_of(os.path.basename(f)) == "train"],
        "validation": [f for f in files if split_of(os.path.basename(f)) == "validation"],
    }
    for k, v in split.items():
        if not v:
            raise ValueError(
                f"--scenarios: no {k} scenes among the {len(files)} files (the split is by location: "
                f"give files of more locations)"
            )
    # three quarters of the sample for training, a quarter (at least 2) for validation, each stratified by folder
    n_val = min(len(split["validation"]), max(2, scenes // 4))
    for k, n in (("train", max(1, scenes - n_val)), ("validation", n_val)):
        if len(split[k]) > n:
            split[k] = sample_files(split[k], n, seed)
    files = split["train"] + split["validation"]
    enable_compilation_cache()
    loaded = load_many(files, progress=progress)
    if loaded.errors:
        raise ValueError(loaded.errors[0][1])
    recs = {k: [r for r in loaded.records if r.path in v] for k, v in split.items()}
    run = sizes.run_sizes([r.scene for r in loaded.records])
    stack = lambda rs: sizes.for_drive(stack_scenes([r.scene for r in rs], min_sizes=run))  # noqa: E731
    train, val = stack(recs["train"]), stack(recs["validation"])
    names: tuple[str, ...]
    if planner_name == "lattice":
        planner = make_planner("lattice", options=(("select_temperature", temperature),))
        names = TUNED
    else:
        planner = make_planner(planner_name)
        names = tuple(f.name for f in dataclasses.fields(planner.init_params()))
    config = SimConfig(n_steps=drive_steps, remat=True)
    stem = os.path.splitext(out)[0]
    res = tune_closed_loop(
        planner,
        train,
        val,
        config,
        steps=steps,
        lr=lr,
        batch=batch,
        names=names,
        seed=seed,
        progress=progress,
        checkpoint=stem + ".ckpt.json",
    )
    figures = {
        "planner": planner_name,
        "train_scenes": len(recs["train"]),
        "validation_scenes": len(recs["validation"]),
        "drive_steps": drive_steps,
        "lr": lr,
        "temperature": temperature,
        "steps_run": len(res.history) - 1,
        "nonfinite_gradient": any(h.get("nonfinite_gradient", False) for h in res.history),
        "drives": res.history[-1]["drives"],
        "validation.default": res.baselines["default"]["val"],
        "validation.tuned": res.best_val,
    }
    for b in ("random_search", "cma_es"):
        figures[f"validation.{b}"] = res.baselines[b]["val"]
        figures[f"{b}.evaluations"] = res.baselines[b]["evaluations"]
    save_weights(
        out,
        res.weights,
        meta={**figures, "kind": "closed-loop", "baselines": {k: v["weights"] for k, v in res.baselines.items()}},
    )
    plot_history(res, stem + ".png")
    return figures


def plot_history(res: TuneResult, path: str) -> None:
    """The loss curves (training batch, validation) against closed-loop drives, with the
    baselines' best validation objective as lines."""
    import matplotlib.pyplot as plt

    h = res.history
    fig, ax = plt.subplots(figsize=(7, 4))
    ax.plot([r["drives"] for r in h[1:]], [r["train"] for r in h[1:]], "o-", label="training batch (soft selection)")
    hv = [r for r in h if r["val"] is not None]  # a step stopped by a non-finite gradient has none
    ax.plot([r["drives"] for r in hv], [r["val"] for r in hv], "s-", label="validation (exact choice)")
    for name, style in (("default", "k--"), ("random_search", "g:"), ("cma_es", "m-.")):
        if name in res.baselines:
            ax.axhline(
                res.baselines[name]["val"],
                color=style[0],
                linestyle=style[1:],
                label=f"{name.replace('_', ' ')} (validation, same drives)",
            )
    ax.set_xlabel("closed-loop drives")
    ax.set_ylabel("objective (lower is better)")
    ax.set_title("closed-loop tuning")
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
