"""Scenario files on the command line: folders expanded, one unique key per file, any format read,
scenes built from them.

Formats: the shared JSON (``.json``) and CommonRoad 2020a XML (``.xml``), each also
gzip-compressed (``.json.gz``, ``.xml.gz``: large collections are kept that way).
``load_file`` reads any of them into a ``Scenario``, ``load_folder`` every one of a folder (the
loading path of every command and suite that reads ``--scenarios DIR``); ``load_records`` reads files into
``SceneRecord``s (the scenario, its ``Scene`` from ``jaxplan.scenarios.build.build_scene``, its
route), ``load_scenes`` into their ``Scene``s, and ``world_route`` gives the route a planner drives
on in a file, in world coordinates.

A drive is written to ``DIR/<key>/driven.json``. The key is the scenario's id (the JSON
``id``; for CommonRoad XML the id commonroad-io reads, as ``load_commonroad`` does). Two files
may carry the same id (``../shared/data`` has ``DEU_Muc-3_1_T-1`` twice and ``ZAM_Over-1_1``
as JSON and as XML); the first file (in the order given, folders sorted) keeps the plain id, each
later one gets ``<id>@<file name>``, so keys stay unique and say where they came from
(``scenario_keys`` for files, ``unique_names`` for loaded records).
"""

from __future__ import annotations

import dataclasses
import fnmatch
import glob
import json
import os
import sys

import numpy as np

from jaxplan.scenarios.build import build_scene
from jaxplan.scenarios.commonroad import load_commonroad, read_commonroad
from jaxplan.scenarios.fields import ScenarioError
from jaxplan.scenarios.loader import load_scenario, read_bytes
from jaxplan.scenarios.route import RouteError
from jaxplan.scenarios.scene import SceneConfig, SceneRecord

SUFFIXES = (".json", ".xml", ".json.gz", ".xml.gz")


def scenario_format(path: str) -> str:
    """``"json"`` or ``"xml"`` by the file name (a ``.gz`` suffix is looked through).

    Raises:
        ValueError: a name without one of ``SUFFIXES``.
    """
    low = path.lower()
    if low.endswith((".json", ".json.gz")):
        return "json"
    if low.endswith((".xml", ".xml.gz")):
        return "xml"
    raise ValueError(f"{path}: not a scenario file (expected one of {', '.join(SUFFIXES)})")


def load_file(path: str, horizon: float | None = None):
    """A ``Scenario`` (``jaxplan.scenarios.loader``) from a file of any supported format.

    Args:
        path: ``.json``, ``.xml``, ``.json.gz`` or ``.xml.gz``.
        horizon: keep obstacle predictions up to this time (s); default all.

    Raises:
        ScenarioError: naming the file and field; ImportError: XML without the ``commonroad`` extra.
    """
    if scenario_format(path) == "xml":
        return load_commonroad(path, horizon)
    return load_scenario(path, horizon)


def expand_paths(paths) -> list[str]:
    """Files (``.json`` shared format, ``.xml`` CommonRoad, either gzip-compressed) and folders
    of them, in order; a folder's files and its sub-folders' files (recursively), sorted by path.

    Raises:
        ValueError: a path that does not exist, a file of another kind, or a folder without any.
    """
    out = []
    for p in paths:
        if os.path.isdir(p):
            found = sorted(
                f
                for f in glob.glob(os.path.join(p, "**", "*"), recursive=True)
                if f.lower().endswith(SUFFIXES) and os.path.isfile(f)
            )
            if not found:
                raise ValueError(f"{p}: folder holds no scenario files ({', '.join(SUFFIXES)})")
            out += found
        elif os.path.isfile(p):
            scenario_format(p)
            out.append(p)
        else:
            raise ValueError(f"{p}: no such file or folder")
    return out


def file_stem(path: str) -> str:
    """The file's name without its scenario suffix (``SUFFIXES``; ``a/b/X_1.xml.gz`` -> ``X_1``)."""
    name = os.path.basename(path)
    for suffix in sorted(SUFFIXES, key=len, reverse=True):
        if name.lower().endswith(suffix):
            return name[: -len(suffix)]
    return name


def folder_files(directory: str, pattern: str | None = None) -> list[str]:
    """The scenario files of a folder and its sub-folders (``expand_paths``), those whose
    ``file_stem`` matches ``pattern`` (``fnmatch``; None: all); a ``ScenarioError`` names a folder
    that does not exist, is a file, or holds no such file."""
    if not os.path.exists(directory):
        raise ScenarioError(f"{directory}: no such folder")
    if not os.path.isdir(directory):
        raise ScenarioError(f"{directory}: is a file, not a folder of scenarios")
    try:
        files = expand_paths([directory])
    except ValueError as e:
        raise ScenarioError(str(e)) from None
    files = [f for f in files if pattern is None or fnmatch.fnmatch(file_stem(f), pattern)]
    if not files:
        raise ScenarioError(f"{directory}: no scenario files named {pattern} ({', '.join(SUFFIXES)})")
    return files


@dataclasses.dataclass(frozen=True)
class Folder:
    """Scenarios loaded from a folder by ``load_folder``.

    Attributes:
        directory: the folder.
        scenarios: the scenarios that loaded, in path order (sub-folders included).
        files: their files.
        skipped: ``(file, reason)`` of every file that did not load.
    """

    directory: str
    scenarios: tuple
    files: tuple
    skipped: tuple

    def __len__(self) -> int:
        return len(self.scenarios)


def load_folder(
    directory: str, pattern: str | None = None, horizon: float | None = None, limit: int | None = None, stderr=None
) -> Folder:
    """Every loadable scenario of a folder, in any format (``folder_files``, ``load_file``); each
    file that fails is named on stderr and counted.

    The one loading path of every command and suite that reads ``--scenarios DIR`` (their
    metrics report ``skipped_files = len(folder.skipped)``).

    Args:
        directory: folder of scenario files (its sub-folders too).
        pattern: file names (without the suffix) to read, e.g. ``"USA_US101-*"``; None: all.
        horizon: keep obstacle predictions up to this time (s); default all.
        limit: read at most this many files (the first by path).
        stderr: where skipped files are named (default ``sys.stderr``).

    Raises:
        ScenarioError: the folder does not exist, holds no matching file, or none of them loads;
        ImportError: CommonRoad XML without the ``commonroad`` extra.
    """
    out = sys.stderr if stderr is None else stderr
    files = folder_files(directory, pattern)[:limit]
    scenarios, loaded, skipped = [], [], []
    for f in files:
        try:
            scenarios.append(load_file(f, horizon=horizon))
            loaded.append(f)
        except ScenarioError as e:
            skipped.append((f, str(e)))
            print(f"jaxplan: skipping {e}", file=out)
    if not scenarios:
        raise ScenarioError(
            f"{directory}: none of its {len(files)} scenario files could be loaded (first: {skipped[0][1]})"
        )
    return Folder(directory, tuple(scenarios), tuple(loaded), tuple(skipped))


def first_loadable(directory: str, pattern: str | None = None) -> str:
    """The first file of a folder that loads (a cheap check before heavy work); a
    ``ScenarioError`` names the folder when none does."""
    files = folder_files(directory, pattern)
    first = None
    for f in files:
        try:
            load_file(f)
            return f
        except ScenarioError as e:
            first = first or str(e)
    raise ScenarioError(f"{directory}: none of its {len(files)} scenario files could be loaded (first: {first})")


def scenario_id(path: str) -> str:
    """The id a scenario file carries (read without building the scenario where possible)."""
    if scenario_format(path) == "json":
        try:
            d = json.loads(read_bytes(path))
        except ValueError as e:
            raise ValueError(f"{path}: not a readable scenario JSON file ({e})") from None
        return str(d.get("id", os.path.basename(path)[:-5])) if isinstance(d, dict) else os.path.basename(path)
    return str(read_commonroad(path)[0].scenario_id)


def scenario_keys(paths) -> dict[str, str]:
    """``{key: file}`` for the given files and folders, keys unique (see the module docstring)."""
    keys: dict[str, str] = {}
    for f in expand_paths(paths):
        sid = scenario_id(f)
        key = sid if sid not in keys else f"{sid}@{os.path.basename(f)}"
        if key in keys:
            raise ValueError(f"{f}: given twice")
        keys[key] = f
    return keys


def location(path_or_name: str) -> str:
    """The location a scenario comes from: the prefix of its id or file name before the first
    ``-`` (``DEU_Flensburg-10_1_T-1`` -> ``DEU_Flensburg``; ``USA_US101-5_1_T-1`` -> ``USA_US101``)."""
    base = os.path.basename(path_or_name)
    return base.split("-", 1)[0].split(".", 1)[0]


def sample_files(files: list, n: int, seed: int = 0) -> list:
    """A seeded sample of ``n`` files, stratified by folder (each folder contributes in proportion
    to its size, at least one file), returned in the input order.

    Args:
        files: file paths (``expand_paths``).
        n: sample size; all files when ``n >= len(files)``.
        seed: the sample's seed (the same seed and files give the same sample).
    """
    files = list(files)
    if n >= len(files):
        return files
    if n < 1:
        raise ValueError(f"sample size must be >= 1, got {n}")
    groups: dict = {}
    for i, f in enumerate(files):
        groups.setdefault(os.path.dirname(os.path.abspath(f)), []).append(i)
    names = sorted(groups)
    sizes = np.array([len(groups[g]) for g in names], float)
    quota = np.maximum(1, np.floor(n * sizes / sizes.sum())).astype(int)
    rest = n - quota.sum()
    order = np.argsort(-(n * sizes / sizes.sum() - quota))  # largest remainders first
    for j in order[: max(0, rest)]:
        quota[j] += 1
    rng = np.random.default_rng(seed)
    keep = []
    for g, q in zip(names, quota):
        idx = groups[g]
        keep += [idx[k] for k in rng.choice(len(idx), size=min(q, len(idx)), replace=False)]
    return [files[i] for i in sorted(keep)[:n]]


SPLIT_SALT = "jaxplan-split-3"


def split_of(name: str) -> str:
    """``"train"`` or ``"validation"``: the location split of a scenario (by its file name or id).

    A location (``location``) is in the validation split when the SHA-256 of ``SPLIT_SALT`` followed
    by its name is divisible by 3: a fixed rule made before any parameter was chosen on it, so
    that whole locations (maps, recording sites, scene families) are held out. On the 928
    development scenarios it holds out 210 (DEU_BadWaldsee, DEU_Flensburg, DEU_Meckenheim,
    ESP_Inca, ITA_CarpiCentro, ITA_Foggia, USA_Lanker, ZAM_Urban, ZAM_Zip).
    """
    import hashlib

    h = int(hashlib.sha256((SPLIT_SALT + location(name)).encode()).hexdigest(), 16)
    return "validation" if h % 3 == 0 else "train"


def load_records(paths: list, config: SceneConfig = SceneConfig(), horizon: float | None = None) -> list:
    """``SceneRecord``s from scenario files (``.json`` shared format, ``.xml`` CommonRoad, either
    gzip-compressed: ``load_file``).

    Names are the scenario ids; give several files to ``unique_names`` to make them unique.

    Raises:
        ValueError: naming the file, for unreadable files, scenarios without a planning
            problem, without lanelets, or with a goal region of an unknown kind.
    """
    recs = []
    for p in paths:
        sc = load_file(p, horizon)
        try:
            scene, route = build_scene(sc, config)
        except RouteError as e:
            raise ScenarioError(f"{p}: {e}") from None
        recs.append(SceneRecord(sc.id, scene, sc, route, p))
    return recs


def load_scenes(paths: list, config: SceneConfig = SceneConfig(), horizon: float | None = None) -> list:
    """The ``Scene`` of each scenario file, in order: ``[r.scene for r in load_records(paths, ...)]``
    (``load_records`` also keeps the scenario, its route and a name).

    Args:
        paths: scenario files (``.json`` shared format, ``.xml`` CommonRoad, either gzip-compressed).
        config: ``SceneConfig``; horizon: seconds of obstacle recording kept (default all).

    Returns:
        unbatched numpy ``Scene``s of their own sizes (obstacles ``(K, T, 5)``, ``drivable (M, V, 2)``,
        ...; the layout in ``jaxplan.scenarios.scene``); ``jaxplan.scenarios.batch.stack_scenes`` pads
        them into one batch with a leading scene axis.

    Raises:
        ValueError: naming the file (as ``load_records``).
    """
    return [r.scene for r in load_records(paths, config, horizon)]


def unique_names(records: list) -> list:
    """The records renamed as ``scenario_keys`` keys files: the first of each id keeps it, later
    ones become ``<id>@<file name>``."""
    seen, out = set(), []
    for r in records:
        name = r.name if r.name not in seen else f"{r.name}@{os.path.basename(r.path)}"
        seen.add(name)
        out.append(dataclasses.replace(r, name=name))
    return out


def world_route(path: str) -> np.ndarray:
    """The route a jaxplan planner drives on in scenario ``path``, in world coordinates ``(R, 2)``
    (for other planners run on the same route, ``experiments/compare_peers.py``)."""
    rec = load_records([path])[0]
    return np.asarray(rec.scene.route.xy, float) + np.asarray(rec.scenario.origin, float)
