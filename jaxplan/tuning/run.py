"""End-to-end tuning runs (used by ``jaxplan tune``, ``jaxplan eval tune`` and the notebooks).

``tune_lattice`` / ``tune_speed``: demonstrations -> training with optax -> figures on
the held-out demonstrations before (defaults) and after tuning, and for a random
search over the weights with the same number of loss evaluations.
"""
from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp

from jaxplan.tuning.demos import Demo, DemoConfig, load_demos, synthetic_demos
from jaxplan.tuning.lattice_tuning import (LEARNED, _chosen, default_weights, imitation_metrics, lattice_data,
                                           lattice_loss, weights_pytree)
from jaxplan.tuning.train import fit, from_log, random_search, to_log

# Weights of the hidden "driver" that generates synthetic demonstrations.
SYNTHETIC_DRIVER = {"alpha": 1.0, "beta": 200.0, "delta": 2.0}


@dataclasses.dataclass
class TuneResult:
    """What a tuning run produced.

    Attributes:
        weights: the tuned positive weights (all of them, learned and fixed).
        history: ``fit``'s history (step, loss, weights).
        metrics: flat figures: ``before.*``, ``after.*``, ``random.*`` on the validation set,
            plus sizes and losses.
        extra: data for plots (validation data, chosen indices).
    """

    weights: dict
    history: dict
    metrics: dict
    extra: dict


def demonstrations(scenarios, n_synthetic: int = 48, max_files: int | None = None,
                   seed: int = 0) -> tuple[Demo, Demo, str]:
    """Train / validation demonstrations from a scenario folder, or synthetic ones.

    Args:
        scenarios: a folder of recorded scenarios (files that fail to load are named on
            stderr and skipped, ``jaxplan.scenarios.loader.load_folder``), a ``Folder`` it
            returned (so a caller can count ``skipped``), or None for synthetic
            demonstrations: the human is a lattice driver with the hidden weights
            ``SYNTHETIC_DRIVER`` (its choice by the exact rule is the recorded future).
    """
    if scenarios:
        from jaxplan.scenarios.loader import Folder, load_folder

        folder = scenarios if isinstance(scenarios, Folder) else load_folder(scenarios)
        scs = list(folder.scenarios)
        if max_files:  # the files with the most recorded vehicles, from both sides of the split
            from jaxplan.tuning.demos import is_validation

            scs = sorted(scs, key=lambda s: -s.obstacles.boxes.shape[0])
            n_val = max(1, max_files // 3)
            scs = ([s for s in scs if not is_validation(s.id)][:max_files - n_val]
                   + [s for s in scs if is_validation(s.id)][:n_val])
        train, val, _ = load_demos(scs, DemoConfig())
        if train is None or val is None:
            raise ValueError(f"{folder.directory}: too few demonstrations for a train / validation split")
        return train, val, "recorded"
    demos = synthetic_demos(2 * n_synthetic, seed=seed)
    data = lattice_data(demos, chunk=n_synthetic)
    truth = {**default_weights(), **SYNTHETIC_DRIVER}
    pick = _chosen(weights_pytree(truth), data)
    human = jnp.take_along_axis(data.xy, pick[:, None, None, None], axis=1)[:, 0]
    demos = dataclasses.replace(demos, human_xy=human.astype(jnp.float32))
    half = lambda d, sl: jax.tree_util.tree_map(lambda x: x[sl], d)
    return half(demos, slice(0, n_synthetic)), half(demos, slice(n_synthetic, None)), "synthetic"


def tune_lattice(train: Demo, val: Demo, steps: int = 200, lr: float = 0.1, seed: int = 0,
                 sigma: float | None = 0.5) -> TuneResult:
    """Learn the lattice weights ``LEARNED`` from demonstrations."""
    dtr, dva = lattice_data(train), lattice_data(val)
    start = {k: v for k, v in to_log(default_weights()).items() if k in LEARNED}
    loss = lambda p, d: lattice_loss(p, d, sigma=sigma)
    params, hist = fit(loss, start, dtr, steps=steps, lr=lr, seed=seed)
    rs_params, rs_loss = random_search(loss, start, dtr, steps, seed=seed)
    full = lambda p: {**default_weights(), **{k: float(v) for k, v in from_log(p).items()}}
    tuned, rand = full(params), full(rs_params)
    m = {"train_demos": int(dtr.features.shape[0]), "val_demos": int(dva.features.shape[0]),
         "candidates": int(dtr.features.shape[1]), "steps": steps,
         "loss_start": hist["loss"][0], "loss_end": hist["loss"][-1], "loss_random_search": rs_loss,
         "val_loss_before": float(loss(start, dva)), "val_loss_after": float(loss(params, dva))}
    for name, w in (("before", default_weights()), ("after", tuned), ("random", rand)):
        m.update({f"{name}.{k}": v for k, v in imitation_metrics(w, dva).items()})
    m["ade3_change"] = m["after.ade3"] / m["before.ade3"] - 1.0
    m.update({f"weight.{k}": tuned[k] for k in LEARNED})
    return TuneResult(tuned, hist, m, {"val_data": dva, "val": val})


def tune_speed(train: Demo, val: Demo, steps: int = 40, lr: float = 0.1, seed: int = 0,
               batch_size: int = 32) -> TuneResult:
    """Learn the speed planner's weights ``SPEED_LEARNED`` from recorded speed profiles."""
    from jaxplan.tuning.speed_tuning import SPEED_LEARNED, default_speed_weights, speed_data, speed_loss, \
        speed_metrics

    dtr, _ = speed_data(train)
    dva, _ = speed_data(val)
    start = {k: v for k, v in to_log(default_speed_weights()).items() if k in SPEED_LEARNED}
    params, hist = fit(speed_loss, start, dtr, steps=steps, lr=lr, batch_size=batch_size, seed=seed,
                       log_every=max(1, steps // 20))
    evals = max(2, steps * batch_size // max(1, dtr.v0.shape[0]))  # same number of example evaluations
    rs_params, rs_loss = random_search(speed_loss, start, dtr, evals, scale=1.0, seed=seed)
    full = lambda p: {**default_speed_weights(), **{k: float(v) for k, v in from_log(p).items()}}
    tuned, rand = full(params), full(rs_params)
    m = {"train_demos": int(dtr.v0.shape[0]), "val_demos": int(dva.v0.shape[0]), "steps": steps,
         "loss_start": hist["loss"][0], "loss_end": hist["loss"][-1], "loss_random_search": rs_loss,
         "val_loss_before": float(speed_loss(start, dva)), "val_loss_after": float(speed_loss(params, dva))}
    for name, w in (("before", default_speed_weights()), ("after", tuned), ("random", rand)):
        m.update({f"{name}.{k}": v for k, v in speed_metrics(w, dva).items()})
    m.update({f"weight.{k}": tuned[k] for k in SPEED_LEARNED})
    return TuneResult(tuned, hist, m, {"val_data": dva})
