"""Scenario files on the command line: folders expanded, one unique key per file.

A drive is written to ``DIR/<key>/driven.json``. The key is the scenario's id (the JSON
``id``; for CommonRoad XML the id commonroad-io reads, as ``load_commonroad`` does). Two files
may carry the same id (``../shared/data`` has ``DEU_Muc-3_1_T-1`` twice and ``ZAM_Over-1_1``
as JSON and as XML); the first file (in the order given, folders sorted) keeps the plain id, each
later one gets ``<id>@<file name>``, so keys stay unique and say where they came from.
"""
from __future__ import annotations

import glob
import json
import os

SUFFIXES = (".json", ".xml")


def expand_paths(paths) -> list[str]:
    """Files (``.json`` shared format, ``.xml`` CommonRoad) and folders of them, in order.

    Raises:
        ValueError: a path that does not exist, a file of another kind, or a folder without any.
    """
    out = []
    for p in paths:
        if os.path.isdir(p):
            found = sorted(f for f in glob.glob(os.path.join(p, "*")) if f.endswith(SUFFIXES))
            if not found:
                raise ValueError(f"{p}: folder holds no .json or .xml scenario files")
            out += found
        elif os.path.isfile(p):
            if not p.endswith(SUFFIXES):
                raise ValueError(f"{p}: not a scenario file (.json shared format or .xml CommonRoad)")
            out.append(p)
        else:
            raise ValueError(f"{p}: no such file or folder")
    return out


def scenario_id(path: str) -> str:
    """The id a scenario file carries (read without building the scenario where possible)."""
    if path.endswith(".json"):
        try:
            with open(path) as f:
                d = json.load(f)
        except (OSError, ValueError) as e:
            raise ValueError(f"{path}: not a readable scenario JSON file ({e})") from None
        return str(d.get("id", os.path.basename(path)[:-5])) if isinstance(d, dict) else os.path.basename(path)
    import warnings

    from commonroad.common.file_reader import CommonRoadFileReader

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sc, _ = CommonRoadFileReader(path).open()
    return str(sc.scenario_id)


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
