"""Suite ``tune``: learn the lattice (and, without ``--quick``, the speed) weights from
demonstrations; imitation figures before / after tuning and for a random search.

Without ``--scenarios`` the demonstrations are synthetic (a lattice driver with
known hidden weights); with ``--scenarios DIR`` they are the recorded vehicles.
"""
from __future__ import annotations

import os

import jax.numpy as jnp
import numpy as np

from jaxplan.eval.registry import SuiteArgs, register
from jaxplan.tuning.run import TuneResult, demonstrations, tune_lattice, tune_speed


def _finish(fig, path):
    """Save and close ``fig`` when ``path`` is given; otherwise return it (notebooks)."""
    if path is None:
        return fig
    import matplotlib.pyplot as plt

    fig.savefig(path, dpi=110)
    plt.close(fig)
    return None


def plot_training(res: TuneResult, path: str | None, title: str):
    """Loss curve and the weights over training (returns the figure when ``path`` is None)."""
    import matplotlib.pyplot as plt

    h = res.history
    fig, ax = plt.subplots(1, 2, figsize=(10, 3.8))
    ax[0].plot(h["step"], h["loss"])
    ax[0].set(xlabel="step", ylabel="training loss", title=f"{title}: loss")
    for k in h["params"][0]:
        ax[1].semilogy(h["step"], [p[k] for p in h["params"]], label=k)
    ax[1].set(xlabel="step", ylabel="weight", title=f"{title}: weights")
    ax[1].legend(fontsize=7)
    fig.tight_layout()
    return _finish(fig, path)


def plot_lattice_demos(res: TuneResult, before: dict, path: str | None, n: int = 4):
    """A few validation demonstrations: candidates, the human path, the chosen one before / after."""
    import matplotlib.pyplot as plt

    from jaxplan.tuning.lattice_tuning import _chosen, weights_pytree

    data, val = res.extra["val_data"], res.extra["val"]
    i0 = np.asarray(_chosen(weights_pytree(before), data))
    i1 = np.asarray(_chosen(weights_pytree(res.weights), data))
    changed = np.nonzero(i0 != i1)[0]
    pick = list(changed[:n]) + [i for i in range(len(i0)) if i not in changed][: n - min(n, len(changed))]
    fig, axes = plt.subplots(1, len(pick), figsize=(4 * len(pick), 4), squeeze=False)
    for ax, b in zip(axes[0], pick):
        xy = np.asarray(data.xy[b])
        for c in xy:
            ax.plot(c[:, 0], c[:, 1], color="0.85", lw=0.6)
        ok = np.asarray(val.obstacle_valid[b, :, 0])
        for box in np.asarray(val.obstacles[b, ok, 0]):
            ax.plot(box[0], box[1], "s", color="C3", ms=5)
        hxy = np.asarray(val.human_xy[b])
        ax.plot(hxy[:, 0], hxy[:, 1], "k", lw=2.5, label="human")
        ax.plot(xy[i0[b], :, 0], xy[i0[b], :, 1], "C0--", lw=1.8, label="chosen, default weights")
        ax.plot(xy[i1[b], :, 0], xy[i1[b], :, 1], "C2", lw=1.8, label="chosen, tuned weights")
        ax.set_aspect("equal", "datalim")
        ax.set_title(f"validation demo {b}", fontsize=9)
    axes[0, 0].legend(fontsize=7)
    fig.tight_layout()
    return _finish(fig, path)


def plot_speed_demos(res: TuneResult, before: dict, path: str | None, n: int = 4):
    """Station over time of a few validation demonstrations: human, exact DP before / after tuning."""
    import matplotlib.pyplot as plt

    from jaxplan.tuning.speed_tuning import station_profiles

    data = res.extra["val_data"]
    s0, s1 = station_profiles(before, data), station_profiles(res.weights, data)
    t = np.arange(s0.shape[1]) * 1.0
    fig, axes = plt.subplots(1, n, figsize=(3.6 * n, 3.4), squeeze=False)
    for ax, b in zip(axes[0], np.linspace(0, len(s0) - 1, n).astype(int)):
        ax.plot(t, np.asarray(data.s_human[b]), "k", lw=2.5, label="human")
        ax.plot(t, s0[b], "C0--o", ms=3, label="default weights")
        ax.plot(t, s1[b], "C2-o", ms=3, label="tuned weights")
        ax.set(xlabel="t (s)", ylabel="station (m)", title=f"validation demo {b}")
    axes[0, 0].legend(fontsize=7)
    fig.tight_layout()
    return _finish(fig, path)


def load_suite_weights(args: SuiteArgs) -> dict | None:
    """Lattice weights from ``--weights`` (or None); unknown names and weights of another planner are refused."""
    if not args.weights:
        return None
    from jaxplan.tuning.lattice_tuning import WEIGHT_NAMES
    from jaxplan.tuning.train import load_weights

    return load_weights(args.weights, allowed=WEIGHT_NAMES, planner="lattice")


@register("tune")
def tune_suite(args: SuiteArgs) -> dict:
    from jaxplan.tuning.lattice_tuning import default_weights

    n = args.n or (24 if args.quick else 64)
    folder = None
    if args.scenarios:
        from jaxplan.scenarios.loader import load_folder

        folder = load_folder(args.scenarios)
    train, val, source = demonstrations(folder, n_synthetic=n, max_files=6 if args.quick else None,
                                        seed=args.seed)
    res = tune_lattice(train, val, steps=60 if args.quick else 300, seed=args.seed)
    m = {f"lattice.{k}": v for k, v in res.metrics.items()}
    m["source_recorded"] = int(source == "recorded")
    if folder is not None:
        m["skipped_files"] = len(folder.skipped)
    plot_training(res, os.path.join(args.out, "tune_lattice_training.png"), "lattice")
    plot_lattice_demos(res, default_weights(), os.path.join(args.out, "tune_lattice_demos.png"))
    if source == "synthetic":
        from jaxplan.tuning.run import SYNTHETIC_DRIVER

        w = res.weights
        m["lattice.recovered_beta_over_alpha"] = w["beta"] / w["alpha"]
        m["lattice.true_beta_over_alpha"] = SYNTHETIC_DRIVER["beta"] / SYNTHETIC_DRIVER["alpha"]
        m["lattice.recovered_delta_over_alpha"] = w["delta"] / w["alpha"]
        m["lattice.true_delta_over_alpha"] = SYNTHETIC_DRIVER["delta"] / SYNTHETIC_DRIVER["alpha"]
    if not args.quick:
        sres = tune_speed(train, val, seed=args.seed)
        m.update({f"speed.{k}": v for k, v in sres.metrics.items()})
        plot_training(sres, os.path.join(args.out, "tune_speed_training.png"), "speed")
        from jaxplan.tuning.speed_tuning import default_speed_weights

        plot_speed_demos(sres, default_speed_weights(), os.path.join(args.out, "tune_speed_demos.png"))
    return {k: (float(v) if isinstance(v, (float, np.floating, jnp.ndarray)) else v) for k, v in m.items()}
