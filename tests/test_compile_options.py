"""jaxplan.compile_options: ``jit`` is jax.jit with per-kernel XLA options, plain jax.jit where refused;
``use_fast_compile`` adds the loop-emitter flag to XLA_FLAGS where it can, and the commands call it."""
import os
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxplan.compile_options import NO_YNN, _supported, jit


def _f(x, n):
    return jnp.max(jnp.cumsum(x, -1), -1) * n


def test_options_applied_where_accepted_and_results_equal():
    x = jnp.asarray(np.random.default_rng(0).normal(size=(50, 31)), jnp.float32)
    fast = jit(_f, options=NO_YNN, static_argnames=("n",))
    np.testing.assert_allclose(np.asarray(fast(x, n=2)), np.asarray(jax.jit(_f, static_argnames=("n",))(x, n=2)),
                               rtol=1e-6)
    assert fast.applied == (NO_YNN if _supported(tuple(NO_YNN.items())) else {})
    if jax.default_backend() == "cpu" and jax.__version_info__ >= (0, 10):
        assert fast.applied == NO_YNN  # XLA CPU of JAX 0.10 has the option (measured there)
    assert fast._cache_size() == 1  # attributes of the jitted function pass through
    fast(x, n=2)
    assert fast._cache_size() == 1


def test_refused_option_falls_back_to_plain_jit():
    bogus = {"xla_cpu_experimental_ynn_fusion_type": "no such value"}
    assert not _supported(tuple(bogus.items()))
    g = jit(_f, options=bogus, static_argnames=("n",))
    assert float(g(jnp.ones((2, 3)), n=1)[0]) == 3.0
    assert g.applied == {}


def test_inside_another_jit_and_grad():
    """JAX refuses compiler options on a nested jit: under a trace the plain jit is used."""
    fast = jit(_f, options=NO_YNN, static_argnames=("n",))
    x = jnp.arange(6.0).reshape(2, 3)
    outer = jax.jit(lambda y: fast(y, n=2).sum())
    assert float(outer(x)) == float(_f(x, 2).sum())
    g = jax.grad(lambda y: fast(y, n=1).sum())(x)
    np.testing.assert_allclose(np.asarray(g), np.asarray(jax.grad(lambda y: _f(y, 1).sum())(x)))


def test_vmap_and_the_function_s_own_errors_pass_through():
    """Under a top-level vmap the options stay; a ValueError of the function itself reaches the
    caller unchanged, at the top level and inside another jit (the fallback is for the refusal only)."""
    fast = jit(_f, options=NO_YNN, static_argnames=("n",))
    x = jnp.asarray(np.random.default_rng(1).normal(size=(4, 5, 31)), jnp.float32)
    np.testing.assert_allclose(np.asarray(jax.vmap(lambda y: fast(y, n=3))(x)), np.asarray(_f(x, 3)), rtol=1e-6)

    def bad(y):
        raise ValueError("bad input y")

    b = jit(bad, options=NO_YNN)
    for call in (b, jax.jit(b)):
        with pytest.raises(ValueError, match="bad input y"):
            call(x)


FLAG = "--xla_cpu_use_fusion_emitters=false"


def _child(code: str, xla_flags: str | None) -> list[str]:
    """Run ``code`` in a fresh interpreter with ``XLA_FLAGS`` set to ``xla_flags`` (unset: None);
    the words it printed."""
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    if xla_flags is not None:
        env["XLA_FLAGS"] = xla_flags
    r = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    return r.stdout.split()


def _use(flags: str = "", before: str = "pass") -> str:
    """A child's code: ``before``, then ``use_fast_compile(flags)`` twice, then a computation;
    prints the two results and XLA_FLAGS."""
    arg = f"({flags!r},)" if flags else ""
    return (f"import os, jax.numpy as jnp, jaxplan.compile_options as co; {before}; "
            f"a = co.use_fast_compile({arg}); b = co.use_fast_compile({arg}); jnp.zeros(1).block_until_ready(); "
            f"print(a, b, '|', os.environ.get('XLA_FLAGS', ''))")


def test_fast_compile_flags_are_added_once_beside_the_users_flags():
    out = _child(_use(), None)
    assert out[:3] == ["True", "True", "|"] and out[3:] == [FLAG]  # added once, not twice
    out = _child(_use(), "--xla_force_host_platform_device_count=2")
    assert out[3:] == ["--xla_force_host_platform_device_count=2", FLAG]  # the user's flags kept


def test_fast_compile_leaves_the_users_choice_a_started_backend_and_unknown_flags():
    assert _child(_use(), "--xla_cpu_use_fusion_emitters=true")[:2] == ["False", "False"]
    out = _child(_use(before="jnp.ones(2).sum()"), None)  # XLA has read XLA_FLAGS already
    assert out == ["False", "False", "|"]
    # XLA ends a process whose XLA_FLAGS names an unknown flag: this one is tried in a child first
    out = _child(_use("--xla_cpu_no_such_flag_in_any_jaxlib=1"), None)
    assert out == ["False", "False", "|"]


def test_commands_that_compile_ask_for_fast_compile_first(monkeypatch, tmp_path):
    import jaxplan.compile_options as co
    from jaxplan import cli

    class Asked(Exception):
        pass

    def asked():
        raise Asked

    monkeypatch.setattr(co, "use_fast_compile", asked)
    with pytest.raises(Asked):
        cli.main(["drive", "--builtin", "--quick", "--planner", "idm", "--out", str(tmp_path / "d")])
    assert not (tmp_path / "d").exists()
