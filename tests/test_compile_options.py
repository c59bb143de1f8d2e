"""jaxplan.compile_options: ``jit`` is jax.jit with per-kernel XLA options, plain jax.jit where refused;
``use_fast_compile`` adds the loop-emitter flag to XLA_FLAGS where it can, and the commands call it."""
import os
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxplan.compile_options import NO_YNN, options_supported, jit


def _f(x, n):
    return jnp.max(jnp.cumsum(x, -1), -1) * n


def test_options_applied_where_accepted_and_results_equal():
    x = jnp.asarray(np.random.default_rng(0).normal(size=(50, 31)), jnp.float32)
    fast = jit(_f, options=NO_YNN, static_argnames=("n",))
    np.testing.assert_allclose(np.asarray(fast(x, n=2)), np.asarray(jax.jit(_f, static_argnames=("n",))(x, n=2)),
                               rtol=1e-6)
    assert fast.applied == (NO_YNN if options_supported(tuple(NO_YNN.items())) else {})
    if jax.default_backend() == "cpu" and jax.__version_info__ >= (0, 10):
        assert fast.applied == NO_YNN  # XLA CPU of JAX 0.10 has the option (measured there)
    assert fast._cache_size() == 1  # attributes of the jitted function pass through
    fast(x, n=2)
    assert fast._cache_size() == 1


def test_refused_option_falls_back_to_plain_jit():
    bogus = {"xla_cpu_experimental_ynn_fusion_type": "no such value"}
    assert not options_supported(tuple(bogus.items()))
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


def test_fast_compile_adds_its_flags_once_where_it_can_and_leaves_them_where_it_cannot():
    """In a fresh interpreter with the user's other flags: the flags are added once, beside the
    user's; a flag this jaxlib does not know is tried in a child and not added (XLA would end the
    process); after the first computation nothing is added (XLA has read XLA_FLAGS)."""
    code = ("import os, jax.numpy as jnp, jaxplan.compile_options as co; "
            "r = [co.use_fast_compile(), co.use_fast_compile(), co.use_fast_compile(('--xla_cpu_no_such_flag=1',))]; "
            "jnp.zeros(1).block_until_ready(); r.append(co.use_fast_compile(('--xla_cpu_enable_fast_math=false',))); "
            "print(*r, '|', os.environ['XLA_FLAGS'])")
    user = "--xla_force_host_platform_device_count=2"
    assert _child(code, user) == ["True", "True", "False", "False", "|", user, FLAG]
    # a user's XLA_FLAGS naming the flag is the user's choice
    code = "import os, jaxplan.compile_options as co; print(co.use_fast_compile(), '|', os.environ['XLA_FLAGS'])"
    assert _child(code, "--xla_cpu_use_fusion_emitters=true") == ["False", "|", "--xla_cpu_use_fusion_emitters=true"]


@pytest.mark.parametrize("flags", ["--xla_cpu_use_fusion_emitters=false", ("xla_cpu_x=1",), ("--xla_a=1 --xla_b=2",),
                                   ("--xla_cpu_x",), (1,)])
def test_fast_compile_refuses_what_is_not_a_sequence_of_xla_flags(flags):
    from jaxplan.compile_options import use_fast_compile

    with pytest.raises(ValueError, match="use_fast_compile: flags must be"):
        use_fast_compile(flags)


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
