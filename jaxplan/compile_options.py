"""Per-kernel XLA compiler options: ``jit`` is ``jax.jit`` with options measured to pay off.

XLA's CPU backend hands small reductions (e.g. a max over a candidate's 31 steps) to its
YNN fusions, which on the lattice's shapes are slower than XLA's own loops: the lattice
plan with 20 obstacles (``experiments/bench_lattice.py``'s scene), timed against plain
``jax.jit`` in one process, took 12.3 -> 8.1 ms (N = 994) and 28.2 -> 15.5 ms (N = 4992)
with them off on the 2-core CI machine (medians of 30), with the same choice. The speed DP is slower with them off, so this is opt-in per kernel, not global.
A planner names the options its drives are compiled with (``compiler_options``, ``jaxplan.planner``): the
lattice planner's closed-loop drives of 1, 4, 8 and 16 built-in scenes (60 steps, alternated in one
process) made 567 / 588 / 536 / 389 scenario-steps/s plain and 708 / 865 / 779 / 448 with ``NO_YNN``.

The options are applied only where this JAX accepts them (they are checked once, at the
first call, never at import): on other JAX versions or backends ``jit`` is plain
``jax.jit``. Inside a user's own ``jax.jit`` or ``grad``, where JAX refuses compiler options
(they are taken only at the top level, and the user's apply), it is plain ``jax.jit``, inlined
there; under a top-level ``vmap`` the options apply.

``use_fast_compile`` has a process (and its children) compile with XLA CPU's loop emitters
(``FAST_COMPILE_FLAGS``) instead of its MLIR fusion emitters: jaxplan's commands call it before
they compile (see there for the measurements).

``release_compiled`` frees the compiled programs a long-running process has accumulated before
the kernel's limit on memory maps is reached (see there).
"""

from __future__ import annotations

import functools
import gc
import os
import subprocess
import sys

import jax

NO_YNN = {"xla_cpu_experimental_ynn_fusion_type": ""}  # XLA CPU: no YNN fusions


def options_key(options: dict) -> tuple:
    """The hashable form of XLA ``options`` (sorted ``(name, value)`` pairs): one key per set of
    options, whatever order its dict was written in (``options_supported``'s and the simulator's caches)."""
    return tuple(sorted(options.items()))


@functools.cache
def options_supported(items: tuple) -> bool:
    """Whether this JAX and default backend compile a trivial function with these options."""
    try:
        jax.jit(lambda x: x + 1, compiler_options=dict(items)).lower(1.0).compile()
    except Exception:  # an unknown option, an older jax.jit without compiler_options
        return False
    return True


class _LazyJit:
    """``jax.jit(fun, **kwargs)`` built at the first use, with ``options`` when supported."""

    def __init__(self, fun, options: dict, kwargs: dict):
        self._fun, self._options, self._kwargs, self._jitted = fun, dict(options), kwargs, None
        self._plain = None  # plain jax.jit, for calls under another trace
        self.applied = None  # the options compiled with (set at the first use; {} = plain jax.jit)
        functools.update_wrapper(self, fun)

    @property
    def jitted(self):
        if self._jitted is None:
            opts = self._options if self._options and options_supported(options_key(self._options)) else {}
            kw = dict(self._kwargs, compiler_options=opts) if opts else self._kwargs
            self.applied = opts
            self._jitted = jax.jit(self._fun, **kw)
        return self._jitted

    def __call__(self, *args, **kwargs):
        try:
            return self.jitted(*args, **kwargs)
        except ValueError:
            # inside another jit / grad JAX refuses compiler options (before tracing ``fun``): then
            # plain jax.jit, inlined there. Looking for tracers only here keeps the walk over every
            # argument (about 14 us for the lattice plan's 29 arrays) off the top-level call.
            if not self.applied or not any(
                isinstance(x, jax.core.Tracer) for x in jax.tree_util.tree_leaves((args, kwargs))
            ):
                raise
        if self._plain is None:
            self._plain = jax.jit(self._fun, **self._kwargs)
        return self._plain(*args, **kwargs)

    def __getattr__(self, name):  # lower, eval_shape, _cache_size, ...
        if name.startswith("__"):
            raise AttributeError(name)
        return getattr(self.jitted, name)


def jit(fun=None, *, options: dict | None = None, **kwargs):
    """``jax.jit(fun, **kwargs)`` compiled with the XLA ``options`` (e.g. ``NO_YNN``) where
    this JAX accepts them; usable as a decorator (``@jit(options=NO_YNN, static_argnames=...)``)."""
    if fun is None:
        return lambda f: jit(f, options=options, **kwargs)
    return _LazyJit(fun, options or {}, kwargs)


MAP_SHARE = 0.5  # of the kernel's limit on a process's memory maps: release compiled programs above it


def memory_maps() -> tuple[int, int] | None:
    """``(memory regions this process maps, the most the kernel allows)`` where ``/proc`` says
    (Linux: ``/proc/self/maps``, ``vm.max_map_count``); None elsewhere."""
    try:
        with open("/proc/self/maps", "rb") as f:
            n = sum(1 for _ in f)
        with open("/proc/sys/vm/max_map_count") as f:
            limit = int(f.read())
    except (OSError, ValueError):
        return None
    return n, limit


def release_compiled(share: float = MAP_SHARE) -> bool:
    """Free JAX's compiled programs (``jax.clear_caches``) when this process maps more than
    ``share`` of the memory regions the kernel allows; returns whether it did.

    XLA's CPU backend maps each executable's code in regions of its own, and JAX keeps every
    program a process compiled: a process that compiles thousands (a test run, a drive of several
    planners over many scene sizes) reaches the kernel's limit (65,530 by default) and XLA aborts
    ("LLVM ERROR: Unable to allocate section memory"). Programs freed are compiled again when
    next called (from the persistent compilation cache where it is on)."""
    m = memory_maps()
    if m is None or m[0] <= share * m[1]:
        return False
    jax.clear_caches()
    gc.collect()
    return True


# XLA CPU's loop emitters in place of its MLIR fusion emitters (the default of recent jaxlibs).
FAST_COMPILE_FLAGS = ("--xla_cpu_use_fusion_emitters=false",)


def _flag_names(flags) -> set[str]:
    """The names of XLA ``flags`` (``--name=value`` strings)."""
    return {f.split("=", 1)[0] for f in flags}


def _backends_started() -> bool:
    """Whether JAX has started its backends (False where this JAX does not say)."""
    try:
        from jax._src import xla_bridge

        return bool(xla_bridge.backends_are_initialized())
    except (ImportError, AttributeError):
        return False


def use_fast_compile(flags: tuple[str, ...] = FAST_COMPILE_FLAGS) -> bool:
    """Compile this process's programs, and those of the processes it starts, with XLA ``flags``
    (``FAST_COMPILE_FLAGS``: XLA CPU's loop emitters), added to ``XLA_FLAGS``; returns whether
    they are in effect. Call it before the first JAX computation: jaxplan's commands do.

    On jaxlib 0.10.2 (2-core CPU) the loop emitters compiled jaxplan's drives a third faster than
    XLA CPU's MLIR fusion emitters, and the drives ran about as fast (a lattice rollout 6 % slower,
    a pathspeed one 5 % faster; ``docs/drive.md``, "Compiling").

    Changes nothing where ``XLA_FLAGS`` names any of the flags already (the user's choice), where
    JAX has started its backends (XLA reads ``XLA_FLAGS`` once, then), or where this jaxlib does
    not know a flag: XLA ends a process whose ``XLA_FLAGS`` names an unknown flag, so the flags
    are first tried in a child process (about a second). Anything but ``--xla_name=value`` strings
    in ``flags`` is refused with a ``ValueError``.
    """
    bad = [f for f in flags if not (isinstance(f, str) and f.startswith("--xla_") and "=" in f and " " not in f)]
    if isinstance(flags, str) or bad:
        raise ValueError(f"use_fast_compile: flags must be a sequence of '--xla_name=value' strings, got {flags!r}")
    current = os.environ.get("XLA_FLAGS", "")
    if set(flags) <= set(current.split()):
        return True  # set already (by an earlier call, or the parent process's)
    if _flag_names(flags) & _flag_names(current.split()) or _backends_started():
        return False
    merged = f"{current} {' '.join(flags)}".strip()
    probe = "import jax.numpy as jnp; jnp.zeros(1).block_until_ready()"
    env = {**os.environ, "XLA_FLAGS": merged}
    try:
        ok = subprocess.run([sys.executable, "-c", probe], env=env, capture_output=True, timeout=120).returncode == 0
    except (OSError, subprocess.TimeoutExpired):
        ok = False
    if ok:
        os.environ["XLA_FLAGS"] = merged
    return ok
