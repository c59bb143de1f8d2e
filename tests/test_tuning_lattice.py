"""Learning the lattice weights: gradients, recovery of known weights, real data."""
import glob
import json
import os

import jax
import jax.numpy as jnp
import pytest

from conftest import shared_data_or_skip
from jaxplan.tuning.demos import DemoConfig, load_demos, synthetic_demos
from jaxplan.tuning.lattice_tuning import (LEARNED, default_weights, imitation_metrics, lattice_data, lattice_loss,
                                           synthetic_choices)
from jaxplan.tuning.train import fit, from_log, load_weights, random_search, save_weights, to_log


@pytest.fixture(scope="module")
def synth():
    return lattice_data(synthetic_demos(32, seed=1), chunk=32)


def test_loss_gradient_matches_finite_differences(synth):
    params = {k: v for k, v in to_log(default_weights()).items() if k in LEARNED}
    for sigma in (None, 0.5):
        f = lambda p: lattice_loss(p, synth, sigma=sigma, temperature=0.5)
        g = jax.grad(f)(params)
        for k in params:
            eps = 1e-2
            hi = f({**params, k: params[k] + eps})
            lo = f({**params, k: params[k] - eps})
            fd = float(hi - lo) / (2 * eps)
            assert float(g[k]) == pytest.approx(fd, rel=0.05, abs=2e-3), (sigma, k)


def test_training_recovers_known_weights(synth):
    true = dict(default_weights(), alpha=2.0, beta=200.0, delta=0.5, gamma=1.0)
    reps = [synthetic_choices(synth, true, 0.3, seed=s) for s in range(32)]
    data = jax.tree_util.tree_map(lambda *x: jnp.concatenate(x), *reps)
    start = {k: v for k, v in to_log(default_weights()).items() if k in LEARNED}  # alpha 1, beta 10, delta 0.1
    loss = lambda p, b: lattice_loss(p, b, sigma=None, temperature=0.3)
    p, hist = fit(loss, start, data, steps=300, lr=0.1, frozen=("gamma",))
    w = from_log(p)
    assert hist["loss"][-1] < hist["loss"][0]
    assert float(w["beta"] / w["alpha"]) == pytest.approx(100.0, rel=0.1)
    assert float(w["delta"] / w["alpha"]) == pytest.approx(0.25, rel=0.1)
    assert float(w["gamma"]) == pytest.approx(default_weights()["gamma"])  # frozen
    # The same budget of random search does no better on the training loss.
    _, rs = random_search(loss, start, data, 300, frozen=("gamma",))
    assert hist["loss"][-1] <= rs + 1e-3


def test_loss_goes_down_on_recorded_traffic():
    files = sorted(glob.glob(os.path.join(shared_data_or_skip(), "USA_US101-1[0-2]_1_T-1.json")))
    from jaxplan.scenarios.loader import load_scenario

    train, _, _ = load_demos([load_scenario(f) for f in files], DemoConfig())
    data = lattice_data(train, chunk=32)
    start = {k: v for k, v in to_log(default_weights()).items() if k in LEARNED}
    p, hist = fit(lattice_loss, start, data, steps=60, lr=0.1)
    assert hist["loss"][-1] < 0.99 * hist["loss"][0]
    m = imitation_metrics({**default_weights(), **{k: float(v) for k, v in from_log(p).items()}}, data)
    assert 0 <= m["top1"] <= 1 and m["ade3"] > 0 and m["oracle_ade3"] <= m["ade3"] + 1e-6


def test_weights_file_round_trip_and_errors(tmp_path):
    path = str(tmp_path / "w.json")
    save_weights(path, {"alpha": 2.0, "beta": 3.5}, meta={"steps": 10})
    assert load_weights(path) == {"alpha": 2.0, "beta": 3.5}
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"weights": {"alpha": -1.0}}))
    with pytest.raises(ValueError, match="positive"):
        load_weights(str(bad))
    bad.write_text("{")
    with pytest.raises(ValueError, match="bad.json"):
        load_weights(str(bad))
