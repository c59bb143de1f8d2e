"""The files the peer harness reads and writes: CommonRoad XML in (``.xml`` or gzip-compressed
``.xml.gz``, read with commonroad-io, which every environment has), JSON out (through a temporary
file where an interrupted run must not leave half a file)."""

from __future__ import annotations

import json
import os


def _write_json(path: str, obj) -> None:
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    with open(path, "w") as f:
        json.dump(obj, f)


def _write_json_atomic(path: str, obj) -> None:
    """``_write_json`` through a temporary file, so an interrupted run leaves no half-written file."""
    tmp = path + ".part"
    _write_json(tmp, obj)
    os.replace(tmp, path)


def _read_xml_set(xml: str):
    """commonroad-io's ``(Scenario, PlanningProblemSet)`` of a CommonRoad XML file, ``.xml`` or
    gzip-compressed ``.xml.gz`` (decompressed in memory; the peers' venvs have no jaxplan)."""
    import gzip
    import warnings

    from commonroad.common.file_reader import CommonRoadFileReader
    from commonroad.common.util import FileFormat

    if xml.lower().endswith(".gz"):
        try:
            with gzip.open(xml, "rb") as f:
                src = f.read()
        except (OSError, EOFError) as e:
            raise ValueError(f"{xml}: not a readable gzip file ({e})") from None
    else:
        src = xml
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return CommonRoadFileReader(src, FileFormat.XML).open()


def _read_xml(xml: str):
    sc, pps = _read_xml_set(xml)
    problems = list(pps.planning_problem_dict.values())
    if not problems:
        raise ValueError(f"{xml}: no planning problem")
    return sc, problems[0]
