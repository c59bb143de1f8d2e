"""``import jaxplan`` is one public surface: every name in ``__all__`` resolves, the import is light
(no matplotlib, no planner packages), and every module of the package imports on its own (an
import cycle fails here)."""
import importlib
import json
import os
import subprocess
import sys
import textwrap

import numpy as np

import jaxplan

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

# The public subpackages whose ``__init__`` lists its names.
SUBPACKAGES = ("baselines", "bounds", "eval", "geometry", "lattice", "models", "parking", "replan", "scenarios",
               "sim", "sim.metrics", "solvers", "speed", "tuning")


def _python(code: str, timeout: float = 300) -> dict:
    """Run ``code`` in a fresh interpreter (the repository on its path); the JSON it prints last."""
    env = dict(os.environ, PYTHONPATH=ROOT + os.pathsep + os.environ.get("PYTHONPATH", ""))
    out = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True, text=True, check=False,
                         timeout=timeout, cwd=ROOT, env=env)
    assert out.returncode == 0, out.stderr[-4000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_every_name_in_all_resolves():
    names = jaxplan.__all__
    assert len(names) == len(set(names)) and all(isinstance(n, str) for n in names)
    for n in ("Scene", "load_scenes", "stack_scenes", "Planner", "make_planner", "EgoState", "PlanOutput",
              "rollout", "SimConfig", "evaluate", "evaluate_batch", "VehicleParams", "Trajectory", "Obstacles",
              "ReferenceLine", "has_overlap", "vehicle_corners", "box_corners"):
        assert n in names, n
    listed = dir(jaxplan)
    for n in names:
        assert getattr(jaxplan, n) is not None, n
        assert n in listed, n
    # the names are the defining modules' own objects (the planner's EgoState, not the loader's)
    mod = importlib.import_module
    assert jaxplan.EgoState is mod("jaxplan.planner").EgoState
    assert jaxplan.make_planner is mod("jaxplan.planner").make_planner
    assert jaxplan.Scene is mod("jaxplan.scenarios.scene").Scene
    assert jaxplan.load_scenes is mod("jaxplan.scenarios.files").load_scenes
    assert jaxplan.rollout is mod("jaxplan.sim.rollout").rollout
    assert jaxplan.evaluate is mod("jaxplan.sim.metrics.registry").evaluate
    for sub in ("lattice", "speed", "sim", "tuning", "scenarios"):
        assert sub in listed and getattr(jaxplan, sub) is importlib.import_module(f"jaxplan.{sub}")


def test_from_jaxplan_import_star():
    ns = {}
    exec("from jaxplan import *", ns)
    assert set(jaxplan.__all__) <= set(ns)


def test_subpackages_list_their_names():
    for sub in SUBPACKAGES:
        mod = importlib.import_module(f"jaxplan.{sub}")
        assert isinstance(getattr(mod, "__all__", None), (list, tuple)), f"jaxplan.{sub} has no __all__"
        assert len(mod.__all__) == len(set(mod.__all__)), f"jaxplan.{sub}.__all__ repeats a name"
        for n in mod.__all__:
            assert getattr(mod, n, None) is not None, f"jaxplan.{sub}.{n}"


def test_import_is_light():
    got = _python("""
        import json, sys, time
        t = time.perf_counter()
        import jaxplan
        seconds = time.perf_counter() - t
        first = {"matplotlib": "matplotlib" in sys.modules, "seconds": seconds,
                 "jaxplan": sorted(m for m in sys.modules if m.startswith("jaxplan."))}
        from jaxplan import *  # every public name: scenes, planners, the closed loop, the metrics
        print(json.dumps({"first": first, "star_matplotlib": "matplotlib" in sys.modules,
                          "star_lattice": "jaxplan.lattice" in sys.modules}))
    """)
    first = got["first"]
    assert not first["matplotlib"]
    # the geometry core and the pytrees only: scenes, planners and the simulator load on first use
    assert {m.split(".")[1] for m in first["jaxplan"]} <= {"geometry", "types"}, first["jaxplan"]
    assert first["seconds"] < 60
    assert not got["star_matplotlib"]  # nor does the whole public surface need it
    assert not got["star_lattice"]  # the planners load when made (make_planner)


def test_every_module_imports_on_its_own():
    """Every module under jaxplan/ imported first in a clean state: one fresh interpreter, every
    ``jaxplan`` module dropped from ``sys.modules`` before each import (as a fresh interpreter would
    import it; third-party modules stay loaded). A circular import fails here; a module whose
    optional third-party dependency is not installed is skipped."""
    got = _python("""
        import importlib, json, os, pkgutil, sys, traceback
        import jaxplan

        def names(path, prefix):
            for m in pkgutil.iter_modules([path]):
                yield prefix + m.name
                if m.ispkg:
                    yield from names(os.path.join(path, m.name), prefix + m.name + ".")

        mods = ["jaxplan"] + [n for n in names(os.path.dirname(jaxplan.__file__), "jaxplan.")
                              if n != "jaxplan.__main__"]  # (__main__ runs the command)
        failed, skipped = {}, {}
        for name in mods:
            for k in [k for k in sys.modules if k == "jaxplan" or k.startswith("jaxplan.")]:
                del sys.modules[k]
            try:
                importlib.import_module(name)
            except ModuleNotFoundError as e:
                if (e.name or "").split(".")[0] == "jaxplan":
                    failed[name] = traceback.format_exc()
                else:
                    skipped[name] = e.name
            except Exception:
                failed[name] = traceback.format_exc()
        print(json.dumps({"modules": mods, "failed": failed, "skipped": skipped}))
    """)
    assert not got["failed"], "\n".join(f"{k}:\n{v}" for k, v in got["failed"].items())
    assert len(got["modules"]) > 100  # the walk found the package
    assert {"jaxplan.sim.rollout", "jaxplan.scenarios.scene", "jaxplan.planner"} <= set(got["modules"])


def test_load_scenes_reads_files_as_load_records(tmp_path):
    from jaxplan.scenarios.builtin import scene_dict

    rng = np.random.default_rng(3)
    paths = []
    for i, kind in enumerate(("stopped_car", "cut_in")):
        p = tmp_path / f"scene{i}.json"
        p.write_text(json.dumps(scene_dict(kind, rng, i)))
        paths.append(str(p))
    scenes = jaxplan.load_scenes(paths)
    records = jaxplan.load_records(paths)
    assert len(scenes) == 2 and all(isinstance(s, jaxplan.Scene) for s in scenes)
    for s, r in zip(scenes, records):
        assert np.array_equal(np.asarray(s.start), np.asarray(r.scene.start))
        K, T, five = np.shape(s.obstacles.boxes)
        assert five == 5 and np.shape(s.obstacles.valid) == (K, T) and np.shape(s.drivable)[-1] == 2
    batch = jaxplan.stack_scenes(scenes)
    assert batch.start.shape == (2, 5)


def test_builtin_scenes():
    kinds = ("stopped_car", "slow_leader")
    a = jaxplan.builtin_scenes(n_per_kind=2, kinds=kinds, check=False)
    b = jaxplan.builtin_scenes(n_per_kind=2, kinds=kinds, check=False)
    assert len(a) == 4 and all(isinstance(s, jaxplan.Scene) for s in a)
    for x, y in zip(a, b):  # deterministic in the seed
        assert np.array_equal(np.asarray(x.obstacles.boxes), np.asarray(y.obstacles.boxes))
    other = jaxplan.builtin_scenes(n_per_kind=2, kinds=kinds, seed=1, check=False)
    assert not np.array_equal(np.asarray(a[0].start), np.asarray(other[0].start))
    checked = jaxplan.builtin_scenes(n_per_kind=1, kinds=("stopped_car",))  # survivable ones (a brake drive)
    assert len(checked) == 1 and isinstance(checked[0], jaxplan.Scene)


# The layers, lowest first: a package imports (at module level or inside a function) only from its
# own layer or the ones below. ``jaxplan`` itself (the lazy public surface) and ``__main__`` are the top.
LAYERS = (
    ("types", "geometry", "solvers", "models", "compile_options", "weights", "planner"),
    ("scenarios", "plan_context"),
    ("lattice", "bounds", "speed", "baselines", "parking", "replan"),
    ("sim",),
    ("tuning",),
    ("eval", "cli", "cli_args", "jaxplan", "__main__"),
)
# command-line front-ends (``cli.py`` wherever it sits) are the top layer: they read arguments for
# every part
# the one known exception: the built-in scenes keep only those that braking in lane survives, which
# the simulator decides
LAYER_EXCEPTIONS = {("jaxplan/scenarios/builtin.py", "baselines"), ("jaxplan/scenarios/builtin.py", "sim")}


def _imports_of(path: str) -> set:
    import ast

    out = set()
    for node in ast.walk(ast.parse(open(path).read())):
        names = [node.module] if isinstance(node, ast.ImportFrom) and node.module else []
        if isinstance(node, ast.ImportFrom) and node.module == "jaxplan":  # from jaxplan import cli_args
            names = [f"jaxplan.{a.name}" if a.name.islower() and a.name.isidentifier() and not a.name.startswith("_")
                     else "jaxplan" for a in node.names]
        names += [a.name for a in node.names] if isinstance(node, ast.Import) else []
        for n in names:
            if n.startswith("jaxplan."):
                out.add(n.split(".")[1])
            elif n == "jaxplan":
                out.add("jaxplan")
    return out


def test_packages_import_only_from_their_layer_or_below():
    """Every import of ``jaxplan/`` (function-local ones included) goes down the layers: core <-
    scenarios <- planners <- simulator <- tuning <- evaluation and command line (so no import cycle
    between packages)."""
    rank = {p: i for i, layer in enumerate(LAYERS) for p in layer}
    bad = []
    for dirpath, _, files in os.walk(os.path.join(ROOT, "jaxplan")):
        for f in files:
            if not f.endswith(".py"):
                continue
            path = os.path.join(dirpath, f)
            rel = os.path.relpath(path, ROOT)
            parts = rel[:-3].split(os.sep)
            own = "jaxplan" if parts[1] == "__init__" else "cli" if parts[-1] == "cli" else parts[1]
            assert own in rank, f"{rel}: package {own!r} is in no layer"
            for dep in _imports_of(path):
                assert dep in rank, f"{rel}: imports jaxplan.{dep}, in no layer"
                if dep != "jaxplan" and rank[dep] > rank[own] and (rel, dep) not in LAYER_EXCEPTIONS:
                    bad.append(f"{rel} -> jaxplan.{dep}")
    assert not bad, bad
