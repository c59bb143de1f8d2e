"""Suite ``tune``: learn a cost that imitates human drivers and measure it, in one run and on
one metric, against constant velocity, constant acceleration, the IDM driven by the
recorded leader, the lattice's default weights, a grid and a random search over the
weights, and the best candidate in the lattice (``jaxplan.tuning.run``).

With ``--scenarios DIR`` the demonstrations are the recorded vehicles, split disjoint by
vehicle (figures per location); without ``--quick`` also trained on all other locations
and tested on each held-out location, and the speed planner's weights through the soft
DP. Without ``--scenarios`` the demonstrations are synthetic (a hidden driver with known
weights). Figures carry 95 % bootstrap intervals over scenarios (``*_ci_lo``, ``*_ci_hi``).
"""

from __future__ import annotations

import os

import numpy as np

from jaxplan.eval.registry import SuiteArgs, register

LABELS = {
    "constant_velocity": "constant velocity",
    "constant_acceleration": "constant accel.",
    "idm": "IDM (recorded leader)",
    "default": "lattice, default weights",
    "grid": "lattice, grid search",
    "random_search": "lattice, random search",
    "weights": "lattice, tuned weights",
    "oracle": "best in lattice",
}


def _finish(fig, path):
    """Save and close ``fig`` when ``path`` is given; otherwise return it (notebooks)."""
    if path is None:
        return fig
    import matplotlib.pyplot as plt

    fig.savefig(path, dpi=100)
    plt.close(fig)
    return None


def _plt():
    import matplotlib.pyplot as plt

    return plt


def plot_learning_curve(history: dict, metrics: dict, path: str | None, title: str = "lattice imitation"):
    """Training loss and the exact choice's ADE3 on the training and held-out demonstrations over
    the optimiser's steps, with the held-out baselines as horizontal lines."""
    plt = _plt()
    fig, ax = plt.subplots(1, 2, figsize=(11, 3.8))
    ax[0].plot(history["step"], history["loss"], "C0")
    ax[0].set(xlabel="optimiser step", ylabel="training loss: expected ADE3 (m)", title=f"{title}: loss")
    ax[1].plot(history["step"], history["train_ade3"], "C0--", label="tuned, training demos")
    if history.get("val_ade3"):
        ax[1].plot(history["step"], history["val_ade3"], "C0", lw=2, label="tuned, held-out demos")
    for i, name in enumerate(("default", "constant_velocity", "idm", "oracle")):
        if f"{name}.ade3" in metrics:
            ax[1].axhline(metrics[f"{name}.ade3"], color=f"C{i + 1}", ls=":", label=f"{LABELS[name]} (held out)")
    ax[1].set(xlabel="optimiser step", ylabel="ADE3 of the chosen candidate (m)", title=f"{title}: ADE at 3 s")
    ax[1].legend(fontsize=7)
    fig.tight_layout()
    return _finish(fig, path)


def plot_heldout(
    metrics: dict,
    path: str | None,
    groups=None,
    methods=None,
    metric: str = "ade3",
    title: str = "held-out demonstrations",
):
    """Bar chart of ``metric`` per method with its 95 % interval, one group of bars per
    ``(label, prefix)`` of ``groups`` (e.g. the locations)."""
    from jaxplan.tuning.run import METHODS

    plt = _plt()
    methods = [m for m in (methods or METHODS) if any(f"{p}{m}.{metric}" in metrics for _, p in groups or [("", "")])]
    groups = groups or [("all", "")]
    groups = [(g, p) for g, p in groups if any(f"{p}{m}.{metric}" in metrics for m in methods)]
    fig, ax = plt.subplots(figsize=(max(6, 1.6 * len(groups) * max(1, len(methods)) / 3), 4))
    w = 0.8 / max(1, len(methods))
    for j, m in enumerate(methods):
        xs, ys, lo, hi = [], [], [], []
        for i, (_, p) in enumerate(groups):
            k = f"{p}{m}.{metric}"
            if k in metrics and np.isfinite(metrics[k]):
                xs.append(i + (j - (len(methods) - 1) / 2) * w)
                ys.append(metrics[k])
                lo.append(metrics[k] - metrics.get(f"{k}_ci_lo", metrics[k]))
                hi.append(metrics.get(f"{k}_ci_hi", metrics[k]) - metrics[k])
        ax.bar(xs, ys, w, yerr=[lo, hi], capsize=2, label=LABELS.get(m, m), color=f"C{j}")
    ax.set_xticks(range(len(groups)))
    ax.set_xticklabels([f"{g}\n({metrics.get(p + 'demos', '?')} demos)" for g, p in groups], fontsize=8)
    ax.set(ylabel=f"{metric.upper()} (m), 95 % interval over scenarios", title=title)
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    return _finish(fig, path)


def plot_weights(model, path: str | None):
    """The learned weights (unit vector over normalised features; signed ones may be negative),
    each labelled with its weight per unit of the raw feature."""
    from jaxplan.tuning.features import UNITS

    plt = _plt()
    w = model.weights()
    pw = model.physical_weights()
    names = list(w)
    fig, ax = plt.subplots(figsize=(8, 0.32 * len(names) + 1.2))
    vals = [w[n] for n in names]
    ax.barh(range(len(names)), vals, color=["C3" if v < 0 else "C0" for v in vals])
    ax.set_yticks(range(len(names)))
    ax.set_yticklabels([f"{n} [{UNITS.get(n, '')}]  ({pw[n]:+.3g} per unit)" for n in names], fontsize=7)
    ax.axvline(0, color="k", lw=0.5)
    ax.invert_yaxis()
    ax.set(
        xlabel="weight on the normalised feature (unit vector; negative = preferred larger)",
        title=f"learned cost weights (temperature {model.temperature:.3g})",
    )
    fig.tight_layout()
    return _finish(fig, path)


def plot_lattice_demos(run, path: str | None, n: int = 4):
    """A few held-out demonstrations: the candidates, the human path, constant velocity, the IDM,
    and the candidates chosen with the default and the tuned weights (axes in metres)."""
    from jaxplan.tuning.baselines import constant_velocity, idm, predict
    from jaxplan.tuning.lattice_tuning import candidate_xy, default_weights, rule_choice
    from jaxplan.tuning.run import CANDIDATE_SETS

    plt = _plt()
    data, val = run.val_data, run.val
    i0 = rule_choice(default_weights(), data)
    i1 = run.model.choose(data)
    gain = run.errors["default"]["ade3"] - run.errors["weights"]["ade3"]
    order = np.argsort(-np.abs(gain))
    pick = order[:n]
    sub = val.take(pick).demos
    xy = np.asarray(candidate_xy(sub, CANDIDATE_SETS[run.model.meta.get("candidate_set", "rich")]))
    cv, im = predict(constant_velocity, sub), predict(lambda d: idm(d, run.idm), sub)
    fig, axes = plt.subplots(1, len(pick), figsize=(4.2 * len(pick), 4), squeeze=False)
    for j, (ax, b) in enumerate(zip(axes[0], pick)):
        for c in xy[j, ::3]:
            ax.plot(c[:31, 0], c[:31, 1], color="0.85", lw=0.5)
        ok = np.asarray(sub.obstacle_valid[j, :, 0])
        for box in np.asarray(sub.obstacles[j, ok, 0]):
            ax.plot(box[0], box[1], "s", color="C3", ms=5)
        h = np.asarray(sub.human_xy[j])[:31]
        ax.plot(h[:, 0], h[:, 1], "k", lw=2.5, label="human (3 s)")
        ax.plot(cv[j, :31, 0], cv[j, :31, 1], "C1:", lw=1.5, label="constant velocity")
        ax.plot(im[j, :31, 0], im[j, :31, 1], "C4-.", lw=1.5, label="IDM")
        ax.plot(xy[j, i0[b], :31, 0], xy[j, i0[b], :31, 1], "C0--", lw=1.8, label="lattice, default weights")
        ax.plot(xy[j, i1[b], :31, 0], xy[j, i1[b], :31, 1], "C2", lw=1.8, label="lattice, tuned weights")
        ax.set_aspect("equal", "datalim")
        ax.set(xlabel="x (m)", ylabel="y (m)")
        ax.set_title(
            f"{val.index.scenario[b]} vehicle {val.index.obstacle_id[b]}\nADE3 default "
            f"{run.errors['default']['ade3'][b]:.2f} m, tuned {run.errors['weights']['ade3'][b]:.2f} m",
            fontsize=8,
        )
    axes[0, 0].legend(fontsize=6)
    fig.tight_layout()
    return _finish(fig, path)


def plot_speed_demos(run, path: str | None, n: int = 4):
    """Station over time of a few held-out examples: human, the exact DP with default and tuned
    weights, constant velocity and the IDM."""
    from jaxplan.tuning.speed_tuning import default_speed_weights, station_profiles

    plt = _plt()
    data = run.val_data
    s0, s1 = station_profiles(default_speed_weights(), data), station_profiles(run.weights, data)
    t = np.arange(s0.shape[1]) * 1.0
    v0 = np.asarray(data.v0)
    fig, axes = plt.subplots(1, n, figsize=(3.6 * n, 3.4), squeeze=False)
    for ax, b in zip(axes[0], np.linspace(0, len(s0) - 1, n).astype(int)):
        ok = np.asarray(data.valid[b])
        ax.plot(t[ok], np.asarray(data.s_human[b])[ok], "k", lw=2.5, label="human")
        ax.plot(t, v0[b] * t, "C1:", label="constant velocity")
        ax.plot(t, s0[b], "C0--o", ms=3, label="DP, default weights")
        ax.plot(t, s1[b], "C2-o", ms=3, label="DP, tuned weights")
        ax.set(xlabel="t (s)", ylabel="station along the human path (m)", title=f"held-out example {b}")
    axes[0, 0].legend(fontsize=7)
    fig.tight_layout()
    return _finish(fig, path)


def plot_training(history: dict, path: str | None, title: str):
    """Loss and the weights over training of ``train.fit`` (speed tuning)."""
    plt = _plt()
    fig, ax = plt.subplots(1, 2, figsize=(10, 3.8))
    ax[0].plot(history["step"], history["loss"])
    ax[0].set(xlabel="optimiser step", ylabel="training loss (Huber, m)", title=f"{title}: loss")
    for k in history["params"][0]:
        ax[1].semilogy(history["step"], [p[k] for p in history["params"]], label=k)
    ax[1].set(xlabel="optimiser step", ylabel="weight", title=f"{title}: weights")
    ax[1].legend(fontsize=7)
    fig.tight_layout()
    return _finish(fig, path)


def load_suite_weights(args: SuiteArgs):
    """The cost in ``--weights`` (or None): an ``ImitationModel`` or the lattice rule's
    weights; unknown names and weights of another planner are refused (``run.load_cost``)."""
    if not args.weights:
        return None
    from jaxplan.tuning.run import load_cost

    return load_cost(args.weights)


LOCATION_GROUPS = [("all", ""), ("US-101", "us101."), ("Lankershim", "lankershim."), ("German roads", "german_roads.")]


@register("tune")
def tune_suite(args: SuiteArgs) -> dict:
    from jaxplan.tuning.baselines import IDM_GRID
    from jaxplan.tuning.run import (
        RECORDED_LR,
        RECORDED_STEPS,
        SMALL_IDM_GRID,
        compare_lattice,
        demonstrations,
        held_out_locations,
        recorded_set,
        tune_speed,
    )

    n = args.n or (24 if args.quick else 64)
    folder = None
    if args.scenarios:
        from jaxplan.scenarios.files import load_folder

        folder = load_folder(args.scenarios)
    train, val, source = demonstrations(
        folder, n_synthetic=n, seed=args.seed, pattern="USA_US101-1[0-2]*" if args.quick and args.scenarios else None
    )
    quick = args.quick
    recorded = source == "recorded" and not quick
    run = compare_lattice(
        train,
        val,
        steps=60 if quick else RECORDED_STEPS if recorded else 400,
        lr=RECORDED_LR if recorded else 0.05,
        seed=args.seed,
        candidate_set="small" if quick or source == "synthetic" else "rich",
        idm_grid=SMALL_IDM_GRID if quick or source == "synthetic" else IDM_GRID,
        ce_weight=1.0 if source == "synthetic" else 0.0,
        n_boot=200 if quick else 1000,
    )
    m = {f"lattice.{k}": v for k, v in run.metrics.items()}
    m["source_recorded"] = int(source == "recorded")
    if folder is not None:
        m["skipped_files"] = len(folder.skipped)
    run.model.save(os.path.join(args.out, "tune_lattice_model.json"))  # `jaxplan eval lattice --weights` reads it
    plot_learning_curve(run.history, run.metrics, os.path.join(args.out, "tune_learning_curve.png"))
    plot_heldout(
        run.metrics, os.path.join(args.out, "tune_heldout.png"), LOCATION_GROUPS, title="held-out vehicles: ADE at 3 s"
    )
    plot_weights(run.model, os.path.join(args.out, "tune_weights.png"))
    plot_lattice_demos(run, os.path.join(args.out, "tune_lattice_demos.png"))
    if source == "recorded" and not quick:
        loc = held_out_locations(recorded_set(folder), seed=args.seed)
        m.update({f"lattice.heldout_location.{k}": v for k, v in loc.items()})
        plot_heldout(
            loc,
            os.path.join(args.out, "tune_heldout_locations.png"),
            [(g, p) for g, p in LOCATION_GROUPS if p],
            title="held-out locations: ADE at 3 s",
        )
    if not quick:
        sres = tune_speed(train, val, seed=args.seed, idm_params=run.idm)
        m.update({f"speed.{k}": v for k, v in sres.metrics.items()})
        plot_training(sres.history, os.path.join(args.out, "tune_speed_training.png"), "speed")
        plot_speed_demos(sres, os.path.join(args.out, "tune_speed_demos.png"))
        plot_heldout(
            sres.metrics,
            os.path.join(args.out, "tune_speed_heldout.png"),
            title="speed planner, held-out vehicles: station ADE at 3 s along the human path",
        )
    return {k: (float(v) if isinstance(v, (float, np.floating)) else v) for k, v in m.items()}
