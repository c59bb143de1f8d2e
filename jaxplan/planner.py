"""The one interface every road planner implements, and the registry of planners by name.

A planner is a frozen, hashable config object (static under ``jax.jit``: sizes, counts,
switches) with

- ``vehicle``: the ``VehicleParams`` it plans for (the simulator drives that car);
- ``dt`` and ``horizon_steps``: its trajectory's time step and length;
- ``init_params(values=None) -> params``: its tunable parameters (cost weights, model
  constants) as a pytree of arrays, the defaults with ``values`` (``{name: value}``, e.g.
  tuned weights) in their place. They are never part of the config: a planner is compiled
  once and driven with any params (``jax.grad`` and optax work on them);
- ``plan(params, scene, ego, step) -> PlanOutput``: jittable, for one scene (``jax.vmap``
  batches it). ``params`` is a pytree shaped as ``init_params()``; ``scene`` a
  ``jaxplan.scenarios.scene.Scene``; ``ego`` an ``EgoState`` (the car's reference point, as
  ``vehicle.reference`` says); ``step`` the simulation step (time ``step * scene.dt``), so the
  planner reads obstacle predictions from that step on (``scene.obstacles.window(step,
  horizon_steps)``) and the goal's time window relative to now.

A planner may also name ``compiler_options``: XLA options (a dict, ``jaxplan.compile_options``)
that its kernels run faster with; the simulator compiles a drive with them (``planner_compiler_options``).
It may also have ``describe(info) -> str``: words for the ``info`` of its last few plans (numpy,
a leading cycle axis), which the drive report gives for each drive that did not succeed.

``PlanOutput.trajectory`` holds ``horizon_steps`` points at ``t = 0, dt, ...`` from now,
starting at the ego state; ``ok`` is False when the planner knows its plan is not good
(no feasible candidate, NaN); ``info`` is a small pytree of per-plan figures.

Planners register by name (``register_planner``); the built-in ones are imported on first
use (``make_planner("lattice")``). Nothing in the simulator knows a planner's internals.
"""

from __future__ import annotations

import dataclasses
import importlib
import importlib.util
from collections.abc import Callable, Mapping
from typing import Any, Protocol

import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Bool, Float, Int, Shaped

from jaxplan.types import Trajectory, VehicleParams, pytree_dataclass

# The car every road planner and the simulator drive by default: CommonRoad's vehicle type 2 (a
# BMW 320i), the car the CommonRoad benchmarks and the peer planners use.
SIM_VEHICLE = VehicleParams(length=4.508, width=1.61, wheelbase=2.578, rear_overhang=0.8313, max_steer=0.55)
# m/s^2: the hardest braking a road planner plans with in an emergency (one figure for every planner:
# the lattice's emergency candidates, the speed planner's hardest braking)
EMERGENCY_DECEL = 8.0
# m/s^2: the most lateral acceleration a road planner plans with in an emergency (the speed planner's
# executed profile where its DP runs above the comfortable curvature limit to escape a vehicle behind)
EMERGENCY_LAT_ACCEL = 6.0


@pytree_dataclass(data_fields=("x", "y", "heading", "v", "a", "kappa"))
class EgoState:
    """The car's state, each field ``(...)``: position of its reference point (m), heading
    (rad), speed (m/s, >= 0 forward), acceleration (m/s^2), curvature (1/m)."""

    x: Float[Any, " ..."]
    y: Float[Any, " ..."]
    heading: Float[Any, " ..."]
    v: Float[Any, " ..."]
    a: Float[Any, " ..."] = 0.0
    kappa: Float[Any, " ..."] = 0.0

    @classmethod
    def from_box_centre(cls, start: Float[ArrayLike, "... 5"], vehicle: VehicleParams) -> EgoState:
        """From a box-centre state ``start (..., 5)`` = [x, y, heading, v, a] (a ``Scene``'s start)."""
        start = jnp.asarray(start)
        h = start[..., 2]
        off = jnp.asarray(vehicle.center_offset, start.dtype)
        return cls(
            start[..., 0] - off * jnp.cos(h),
            start[..., 1] - off * jnp.sin(h),
            h,
            start[..., 3],
            start[..., 4],
            jnp.zeros_like(h),
        )

    def box_centre(self, vehicle: VehicleParams) -> Float[Array, "... 2"]:
        """``(..., 2)`` centre of the car's box."""
        off = jnp.asarray(vehicle.center_offset, jnp.result_type(self.x))
        return jnp.stack([self.x + off * jnp.cos(self.heading), self.y + off * jnp.sin(self.heading)], -1)

    @classmethod
    def at(cls, traj: Trajectory, k) -> EgoState:
        """The state at index ``k`` of a trajectory ``(..., T)``."""
        f = lambda a: jnp.take(a, k, axis=-1)
        return cls(f(traj.x), f(traj.y), f(traj.theta), f(traj.v), f(traj.a), f(traj.kappa))


@pytree_dataclass(data_fields=("trajectory", "ok", "info"))
class PlanOutput:
    """A plan: ``trajectory`` (``Trajectory`` with fields ``(..., H)``, t from now), ``ok (...)``
    bool, ``info``: a dict of ``(...)`` arrays (e.g. mode, candidates rejected)."""

    trajectory: Trajectory
    ok: Bool[Any, " ..."]
    info: dict[str, Shaped[Any, " ..."]]


class Planner(Protocol):
    """What the simulator needs of a planner (see the module docstring)."""

    vehicle: VehicleParams
    dt: float

    @property
    def horizon_steps(self) -> int: ...

    def init_params(self, values: Mapping | None = None, /) -> Any: ...

    def plan(self, params, scene, ego: EgoState, step: Int[ArrayLike, ""]) -> PlanOutput: ...


def check_params(planner, params) -> Any:
    """``params`` for ``planner``: its defaults (``init_params()``) when None, else ``params``
    checked against them (the same pytree structure and leaf shapes; a ``ValueError`` names the
    planner and what differs, before anything compiles) and cast to their dtypes (so that a
    Python float or a float64 array does not compile another program)."""
    want = planner.init_params()
    if params is None:
        return want
    # Any: jaxlib ships no stubs for PyTreeDef, and mypy cannot compare its placeholder type
    t_want: Any = jax.tree_util.tree_structure(want)
    t_got: Any = jax.tree_util.tree_structure(params)
    if t_want != t_got:
        raise ValueError(
            f"{type(planner).__name__} params: expected the structure of init_params() ({t_want}), got {t_got}"
        )
    for a, b in zip(jax.tree_util.tree_leaves(want), jax.tree_util.tree_leaves(params)):
        if jnp.shape(a) != jnp.shape(b):
            raise ValueError(
                f"{type(planner).__name__} params: a leaf of shape {jnp.shape(b)} where init_params() "
                f"has {jnp.shape(a)}"
            )
    return jax.tree_util.tree_map(lambda a, b: jnp.asarray(b, jnp.result_type(a)), want, params)


def tally(what: str, names: list[str]) -> str:
    """Words for a planner's ``describe``: how often each of ``names`` (one per plan) occurs, in
    order of first appearance: ``"{what} of the last 3 plans: free x2, risk x1"``."""
    counts = {n: names.count(n) for n in dict.fromkeys(names)}
    return f"{what} of the last {len(names)} plans: " + ", ".join(f"{n} x{c}" for n, c in counts.items())


def planner_compiler_options(planner) -> dict:
    """The XLA options a drive with ``planner`` is compiled with: its ``compiler_options``
    (none when it names none)."""
    options = getattr(planner, "compiler_options", None) or {}
    if not isinstance(options, Mapping):
        raise TypeError(
            f"{type(planner).__name__}.compiler_options: needs a dict of XLA options (name -> value), got {options!r}"
        )
    return dict(options)


# name -> "module:attribute" of a factory (a class, or a function) taking keyword options
_BUILTIN = {
    "lattice": "jaxplan.lattice.planner:LatticePlanner",
    "pathspeed": "jaxplan.speed.planner:PathSpeedPlanner",
    "brake": "jaxplan.baselines:BrakePlanner",
    "idm": "jaxplan.baselines:IDMPlanner",
}
PLANNERS: dict[str, Callable[..., Any]] = {}
# The road planners; the baselines (brake, idm) are the references they are read against.
ROAD_PLANNERS = ("lattice", "pathspeed")
BASELINES = ("idm", "brake")


def register_planner(name: str):
    """Decorator: a planner factory (``**options -> Planner``) becomes planner ``name``."""

    def wrap(factory):
        PLANNERS[name] = factory
        return factory

    return wrap


def planner_names() -> list[str]:
    """Every planner that can be made: the registered ones and the built-in ones that import."""
    names = set(PLANNERS)
    for name, target in _BUILTIN.items():
        mod = target.split(":")[0]
        if importlib.util.find_spec(mod) is not None:
            names.add(name)
    return sorted(names)


def loadable_planners() -> list[str]:
    """Road planners, then baselines, then other registered planners: every one whose module imports."""
    out = []
    for name in list(ROAD_PLANNERS) + list(BASELINES) + sorted(PLANNERS):
        if name in out:
            continue
        try:
            get_factory(name)
        except ValueError:
            continue
        out.append(name)
    return out


def get_factory(name: str):
    """The factory of planner ``name`` (imports a built-in planner on first use)."""
    if name not in PLANNERS and name in _BUILTIN:
        mod, attr = _BUILTIN[name].split(":")
        try:
            PLANNERS[name] = getattr(importlib.import_module(mod), attr)
        except (ImportError, AttributeError):
            pass
    if name not in PLANNERS:
        raise ValueError(f"unknown planner {name!r}; known: {', '.join(planner_names())}")
    return PLANNERS[name]


def planner_spec(spec: str) -> tuple[str, dict]:
    """``(name, options)`` of a planner spec ``NAME[:OPTION=VALUE]...`` (e.g.
    ``"pathspeed:nonblocking=false"``): values ``true`` / ``false``, numbers, else strings.

    Raises:
        ValueError: naming the part that is not ``OPTION=VALUE``.
    """
    name, *parts = spec.strip().split(":")
    options: dict[str, Any] = {}
    for part in parts:
        key, eq, raw = part.partition("=")
        if not eq or not key.strip() or not raw.strip():
            raise ValueError(f"planner {spec!r}: {part!r} is not OPTION=VALUE")
        raw = raw.strip()
        value: Any = {"true": True, "false": False}.get(raw.lower(), raw)
        if isinstance(value, str):
            for kind in (int, float):
                try:
                    value = kind(raw)
                    break
                except ValueError:
                    pass
        options[key.strip()] = value
    return name.strip(), options


def _kind_of(value):
    """``"true or false"``, ``"a number"`` or None (any other value) for a config option's value."""
    if isinstance(value, bool):
        return "true or false"
    return "a number" if isinstance(value, (int, float)) else None


def make_planner(name: str, **options) -> Planner:
    """A planner by name or spec (``planner_spec``: ``"pathspeed:nonblocking=false"``), with
    keyword options for its config (e.g. ``vehicle=...``) over the spec's.

    Raises:
        ValueError: an unknown planner, an option its config does not have, or a spec value of
            another kind than the option's default (a word for a switch or a number; named).
    """
    base, spec_options = planner_spec(name)
    factory = get_factory(base)
    given = {**spec_options, **options}
    if dataclasses.is_dataclass(factory):
        defaults = {f.name: f.default for f in dataclasses.fields(factory)}
        unknown = sorted(set(given) - set(defaults))
        if unknown:
            raise ValueError(
                f"planner {name!r}: no option {', '.join(unknown)}; options: {', '.join(sorted(defaults))}"
            )
        for key, value in spec_options.items():
            want = _kind_of(defaults[key])
            if want is not None and _kind_of(value) != want:
                raise ValueError(f"planner {name!r}: option {key} needs {want}, got {value!r}")
    return factory(**given)
