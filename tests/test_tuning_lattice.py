"""The imitation cost: features against an independent computation, gradients against finite
differences, recovery of known weights, the planner's eligible set, model files."""
import dataclasses
import functools
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxplan.tuning.baselines import demo_traffic
from jaxplan.tuning.demos import synthetic_demos
from jaxplan.tuning.features import FEATURES, SIGNED, FeatureConfig
from jaxplan.tuning.imitation import ImitationModel, cross_entropy, direction, expected_ade, feature_scale, fit_model
from jaxplan.tuning.lattice_tuning import (LEARNED, LatticeData, choice_errors, default_weights, eligible,
                                           imitation_metrics, lattice_data, lattice_loss, nearest_eligible,
                                           synthetic_choices)
from jaxplan.tuning.run import CANDIDATE_SETS
from jaxplan.tuning.traffic import IDMParams
from jaxplan.tuning.train import fit, from_log, load_weights, random_search, save_weights, to_log
from idm_oracle import idm_step

SMALL = CANDIDATE_SETS["small"]
SIGNED_MASK = jnp.asarray([n in SIGNED for n in FEATURES])


@functools.lru_cache(maxsize=None)
def synth_and_candidates():
    # 32 synthetic road scenes, the small candidate set (75 candidates), the chunk every run uses
    return lattice_data(synthetic_demos(32, seed=1), SMALL, keep=("s", "l", "a", "lane", "offset", "v_end"))


def synth() -> LatticeData:
    return synth_and_candidates()[0]


def test_candidate_data_compiles_with_the_lattices_xla_options():
    from jaxplan.compile_options import NO_YNN, options_supported, options_key
    from jaxplan.tuning import lattice_tuning

    synth()
    assert lattice_tuning.chunk_data._cache_size() >= 1
    assert lattice_tuning.chunk_data.applied == (NO_YNN if options_supported(options_key(NO_YNN)) else {})


def _numpy_idm(ts, tl, tv, tlen, tvalid, s0, l_lane, v0, p, dt, length=4.8, band=1.75):
    """Plain-Python IDM along one lane, following whoever leads it at each step."""
    s, v, out = s0, v0, [s0]
    v_des = p.v_ratio * v0 + p.v_extra
    for k in range(ts.shape[1] - 1):
        ahead = [j for j in range(ts.shape[0]) if tvalid[j, k] and ts[j, k] > s and abs(tl[j, k] - l_lane) < band]
        if ahead:
            j = min(ahead, key=lambda j: ts[j, k] - 0.5 * tlen[j, k])
            s, v = idm_step(s, v, v_des, p, dt, ts[j, k] - s - 0.5 * (tlen[j, k] + length), tv[j, k], min_gap=0.1)
        else:
            s, v = idm_step(s, v, v_des, p, dt)
        out.append(s)
    return np.array(out)


def test_features_against_an_independent_computation():
    demos = synthetic_demos(32, seed=1)  # the demonstrations of synth(): its features are the ones checked
    data, c = synth_and_candidates()   # the features and the candidates they were computed from
    cfg = SMALL[0]
    p, fc = IDMParams(), FeatureConfig()   # synth()'s settings
    trn = jax.tree_util.tree_map(np.asarray, demo_traffic(demos)[0])
    F = np.asarray(data.features)
    col = {n: i for i, n in enumerate(FEATURES)}
    e = fc.every
    idx = np.arange(0, cfg.n_steps, e)
    tt = idx * cfg.dt
    early = (tt > 0) & (tt <= 3.0 + 1e-6)
    checked = 0
    for b in (0, 5, 11):
        v0 = float(demos.ego[b, 3])
        s_start = c["s"][b, 0, 0]
        lanes = {ln: _numpy_idm(trn.s[b][:, idx], trn.l[b][:, idx], trn.v[b][:, idx], trn.length[b][:, idx],
                                trn.valid[b][:, idx], s_start, ln * cfg.lane_width, v0, p, cfg.dt * e) - s_start
                 for ln in cfg.lanes}
        led = any(trn.valid[b][j, 0] and trn.s[b][j, 0] > s_start and abs(trn.l[b][j, 0]) < fc.band
                  for j in range(trn.s.shape[1]))
        for n in range(0, c["s"].shape[1], 4):
            s = c["s"][b, n, idx] - s_start
            lane = c["lane"][b, n]
            want = {"lane_change": abs(lane), "lane_side": lane,
                    "lane_offset": abs(c["offset"][b, n] - lane * cfg.lane_width),
                    "speed_change": c["v_end"][b, n] - v0, "speed_change_abs": abs(c["v_end"][b, n] - v0),
                    "accel": np.mean(c["a"][b, n, idx][early] ** 2),
                    "cv_dev": np.mean((s - v0 * tt)[early] ** 2), "cv_ahead": np.mean((s - v0 * tt)[early]),
                    "free_cv_dev": 0.0 if led else np.mean((s - v0 * tt)[early] ** 2),
                    "progress_dev": np.mean((s - lanes[lane])[early] ** 2),
                    "progress_dev_late": np.mean((s - lanes[lane])[~early & (tt > 0)] ** 2),
                    "progress_ahead": np.mean((s - lanes[lane])[early])}
            for k, v in want.items():
                assert F[b, n, col[k]] == pytest.approx(v, rel=2e-3, abs=2e-3), (b, n, k)
                checked += 1
    assert checked > 300


def test_imitation_loss_gradients_match_finite_differences():
    data = synth()
    scale = jnp.asarray(feature_scale(data))
    rng = np.random.default_rng(0)
    params = {"theta": jnp.asarray(rng.normal(0, 0.5, len(FEATURES)), jnp.float32), "log_tau": jnp.log(0.5)}
    for loss in (lambda p: expected_ade(p, data, scale, SIGNED_MASK),
                 lambda p: cross_entropy(p, data, scale, SIGNED_MASK, 0.5)):
        vg = jax.jit(jax.value_and_grad(loss))
        f = lambda p: vg(p)[0]
        g = vg(params)[1]
        for key, i in [("log_tau", None)] + [("theta", i) for i in range(0, len(FEATURES), 3)]:
            eps = 1e-2
            bump = (lambda d: {**params, "log_tau": params["log_tau"] + d}) if i is None else \
                (lambda d: {**params, "theta": params["theta"].at[i].add(d)})
            fd = (float(f(bump(eps))) - float(f(bump(-eps)))) / (2 * eps)
            got = float(g[key]) if i is None else float(g[key][i])
            assert got == pytest.approx(fd, rel=0.05, abs=2e-3), (key, i)
    # the rule's softmin (positive log weights), both targets
    rp = {k: v for k, v in to_log(default_weights()).items() if k in LEARNED}
    for sigma in (None, 0.5):
        vg = jax.jit(jax.value_and_grad(lambda p: lattice_loss(p, data, sigma=sigma, temperature=0.5)))
        f = lambda p: vg(p)[0]
        g = vg(rp)[1]
        for k in rp:
            fd = (float(f({**rp, k: rp[k] + 1e-2})) - float(f({**rp, k: rp[k] - 1e-2}))) / 2e-2
            assert float(g[k]) == pytest.approx(fd, rel=0.05, abs=2e-3), (sigma, k)


def test_softmin_expected_ade_tends_to_the_exact_choice():
    data = synth()
    scale = jnp.asarray(feature_scale(data))
    theta = jnp.asarray(np.random.default_rng(1).normal(0, 1, len(FEATURES)), jnp.float32)
    model = ImitationModel(FEATURES, np.asarray(theta), np.asarray(scale), 1.0)
    exact = choice_errors(model.choose(data), data)["ade3"].mean()
    ea = jax.jit(lambda lt: expected_ade({"theta": theta, "log_tau": lt}, data, scale, SIGNED_MASK))
    gaps = [abs(float(ea(jnp.log(tau))) - exact) for tau in (1.0, 1e-2, 1e-5)]
    assert gaps[2] < 1e-3 and gaps[0] > gaps[2]


def test_fitting_recovers_a_hidden_drivers_weights():
    names = ("progress_dev", "lane_change", "jerk", "d_lrp", "speed_change")  # little correlated
    data = synth()
    data = dataclasses.replace(data, features=data.features[..., [FEATURES.index(n) for n in names]])
    scale = jnp.asarray(feature_scale(data))
    signed = jnp.asarray([n in SIGNED for n in names])
    true = jnp.asarray(np.r_[np.log([1.0, 0.6, 0.4, 0.2]), -0.5], jnp.float32)  # and a taste for speeding up
    w_true = np.asarray(direction(true, signed))
    logits = jnp.where(eligible(data), -jnp.einsum("bnf,f->bn", data.features / scale, jnp.asarray(w_true)) / 0.05,
                       -jnp.inf)
    reps = []
    for s in range(16):
        pick = jax.random.categorical(jax.random.PRNGKey(s), logits, axis=-1)
        reps.append(dataclasses.replace(data, ade3=1.0 - jax.nn.one_hot(pick, logits.shape[-1])))
    many = jax.tree_util.tree_map(lambda *x: jnp.concatenate(x), *reps)
    model, hist = fit_model(many, steps=200, lr=0.1, ce_weight=1.0, sigma=0.05, l2=0.0, log_every=50, names=names)
    w = np.array([model.weights()[n] for n in names])
    assert hist["loss"][-1] < hist["loss"][0]
    assert w[-1] < 0 and (w[:-1] > 0).all()
    assert float(w @ w_true) > 0.95  # unit vectors: cosine similarity
    assert model.temperature == pytest.approx(0.05, rel=0.5)


def test_rule_weights_are_recovered_from_their_own_choices():
    data = synth()
    true = dict(default_weights(), alpha=2.0, beta=200.0, delta=0.5, gamma=1.0)
    many = jax.tree_util.tree_map(lambda *x: jnp.concatenate(x),
                                  *[synthetic_choices(data, true, 0.3, seed=s) for s in range(16)])
    start = {k: v for k, v in to_log(default_weights()).items() if k in LEARNED}
    loss = lambda p, b: lattice_loss(p, b, sigma=None, temperature=0.3)
    p, hist = fit(loss, start, many, steps=200, lr=0.1, frozen=("gamma",))
    w = from_log(p)
    assert float(w["beta"] / w["alpha"]) == pytest.approx(100.0, rel=0.15)
    assert float(w["delta"] / w["alpha"]) == pytest.approx(0.25, rel=0.15)
    assert float(w["gamma"]) == pytest.approx(default_weights()["gamma"])  # frozen
    _, rs = random_search(loss, start, many, 200, frozen=("gamma",))
    assert hist["loss"][-1] <= rs + 1e-3


def test_the_planner_never_chooses_a_colliding_candidate_and_top1_ignores_them(rng):
    B, N = 6, 10
    ade = rng.uniform(1, 3, (B, N)).astype(np.float32)
    ade[:, 3] = 0.1                                   # the nearest candidate ...
    collided = np.zeros((B, N), bool)
    collided[:4, 3] = True                            # ... collides in four scenes
    collided[5] = True                                # and in the last scene every candidate collides
    f = rng.normal(size=(B, N, len(FEATURES))).astype(np.float32)
    f[:, 3] -= 10.0                                   # a cost that loves the colliding one
    j = lambda x: jnp.asarray(x)
    data = LatticeData(j(f), j(np.zeros((B, N, 6), np.float32)), j(collided), j(np.zeros((B, N), np.int32)),
                       j(ade), j(ade), j(ade), j(ade), j(np.ones(B, bool)))
    near = nearest_eligible(data)
    assert (near[:4] != 3).all() and near[4] == 3 and near[5] == 3
    model = ImitationModel(FEATURES, np.zeros(len(FEATURES), np.float32), np.ones(len(FEATURES), np.float32), 1.0)
    pick = model.choose(data)
    assert not collided[np.arange(5), pick[:5]].any()
    e = choice_errors(pick, data)
    assert e["top1"].tolist() == (pick == near).tolist()
    assert not e["collided"][:5].any() and e["collided"][5]


def test_model_file_round_trip_and_bad_files(tmp_path):
    m = ImitationModel(FEATURES, np.linspace(-1, 1, len(FEATURES)).astype(np.float32),
                       np.linspace(0.5, 2, len(FEATURES)).astype(np.float32), 0.3, {"candidate_set": "small"})
    path = str(tmp_path / "m.json")
    m.save(path)
    back = ImitationModel.load(path)
    np.testing.assert_allclose(back.theta, m.theta)
    assert back.weights() == pytest.approx(m.weights()) and back.meta == m.meta
    assert sum(v * v for v in m.weights().values()) == pytest.approx(1.0)
    for n in SIGNED:  # signed weights keep the sign of theta, the others are positive
        assert np.sign(m.weights()[n]) == np.sign(m.theta[FEATURES.index(n)]) or m.theta[FEATURES.index(n)] == 0
    assert all(m.weights()[n] > 0 for n in FEATURES if n not in SIGNED)
    d = json.load(open(path))
    for bad, match in (({**d, "kind": "x"}, "not an imitation model"), ({**d, "features": ["nope"] + list(FEATURES[1:])},
                                                                       "unknown features"),
                       ({**d, "theta": d["theta"][:-1]}, "one value per feature"),
                       ({**d, "temperature": -1}, "positive")):
        (tmp_path / "bad.json").write_text(json.dumps(bad))
        with pytest.raises(ValueError, match=match):
            ImitationModel.load(str(tmp_path / "bad.json"))
    save_weights(str(tmp_path / "w.json"), {"alpha": 2.0, "beta": 3.5}, meta={"steps": 10})
    assert load_weights(str(tmp_path / "w.json")) == {"alpha": 2.0, "beta": 3.5}
    (tmp_path / "w.json").write_text(json.dumps({"weights": {"alpha": -1.0}}))
    with pytest.raises(ValueError, match="positive"):
        load_weights(str(tmp_path / "w.json"))


def test_tuning_on_recorded_traffic_lowers_the_loss():
    import os

    from conftest import shared_data_or_skip
    from jaxplan.scenarios.loader import load_scenario
    from jaxplan.tuning.demos import DemoConfig, demo_set

    sc = load_scenario(os.path.join(shared_data_or_skip(), "USA_US101-10_1_T-1.json"))
    ds = demo_set([sc], DemoConfig())
    data = lattice_data(ds.take(np.arange(min(32, len(ds)))).demos, SMALL)   # the compiled shape of synth()
    default = imitation_metrics(default_weights(), data)
    model, hist = fit_model(data, steps=150, lr=0.1, log_every=149)
    tuned = choice_errors(model.choose(data), data)["ade3"].mean()
    # five end speeds are coarse: on 32 demonstrations keeping the speed stays the best choice
    assert hist["loss"][-1] < hist["loss"][0] and tuned <= default["ade3"] + 1e-6
    assert default["oracle_ade3"] <= tuned
