"""A drive run's folder as a resumable store: what was asked, and one row per finished drive.

``OUT/run.json`` holds the run's settings (planners, simulation settings, step cap, weights,
the library's version and a fingerprint of its code) and its scenes (key -> file digest).
``OUT/rows.jsonl`` holds one JSON line per finished drive, appended and flushed as each
drive's outputs are written, so a run that is killed keeps every drive it finished.

Started again with the same settings and scenes, a run skips the drives it has rows for and
drives the rest. Other settings, other scenes or another version of the library in the same
folder are refused with one line (``RunMismatch``) before any work: results of two runs are
never mixed. ``fresh=True`` starts over (the old rows are removed).
"""

from __future__ import annotations

import json
import math
import os


class RunMismatch(ValueError):
    """The output folder holds a run with other settings or scenes; the message says which."""


def strict(obj):
    """``obj`` with every non-finite float replaced by ``None`` (strict JSON: no NaN or Infinity)."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: strict(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [strict(v) for v in obj]
    return obj


def write_json(path: str, obj, indent: int | None = 1) -> None:
    """Write ``obj`` as strict JSON (``strict``) through a temporary file and an atomic rename."""
    tmp = path + ".tmp"
    with open(tmp, "w") as f:
        json.dump(strict(obj), f, indent=indent, allow_nan=False)
    os.replace(tmp, path)


def _settings_mismatch(out: str, old: dict, settings: dict) -> str | None:
    diff = sorted(k for k in set(old) | set(settings) if old.get(k) != settings.get(k))
    if not diff:
        return None
    k = diff[0]
    more = f", and {len(diff) - 1} more" if len(diff) > 1 else ""
    return (
        f"{out}: holds a run with other settings ({k}: {old.get(k)!r} there, {settings.get(k)!r} now{more}); "
        f"give another --out, or --fresh to start over"
    )


def _read_run(out: str):
    path = os.path.join(out, RunStore.RUN)
    if not os.path.exists(path):
        return None
    try:
        with open(path) as f:
            old = json.load(f)
    except (OSError, ValueError):
        old = None
    if not isinstance(old, dict) or "settings" not in old:
        raise RunMismatch(f"{out}: holds a {RunStore.RUN} this version cannot read; give another --out or --fresh")
    return old


def check_settings(out: str, settings: dict) -> None:
    """Refuse (``RunMismatch``) when ``out`` holds a run with other settings; a cheap check before loading."""
    old = _read_run(out)
    if old is not None:
        msg = _settings_mismatch(out, old["settings"], strict(settings))
        if msg:
            raise RunMismatch(msg)


class RunStore:
    """The rows of a run in folder ``out`` (see the module docstring).

    Args:
        out: the output folder (created).
        settings: a JSON-able dict of everything that decides a drive's result.
        scenes: ``{scene key: file digest}`` (``""`` for scenes without a file).
        fresh: discard a previous run in ``out``.

    Raises:
        RunMismatch: ``out`` holds a run with other settings or scenes (and not ``fresh``).
    """

    RUN = "run.json"
    ROWS = "rows.jsonl"

    def __init__(self, out: str, settings: dict, scenes: dict, fresh: bool = False):
        self.out = out
        os.makedirs(out, exist_ok=True)
        run_path, rows_path = os.path.join(out, self.RUN), os.path.join(out, self.ROWS)
        settings = strict(settings)
        self.resumed = False
        old = None if fresh else _read_run(out)
        if old is not None:
            msg = _settings_mismatch(out, old["settings"], settings)
            if msg:
                raise RunMismatch(msg)
            if old.get("scenes") != scenes:
                a, b = set(old.get("scenes", {}).items()), set(scenes.items())
                raise RunMismatch(
                    f"{out}: holds a run of other scenes ({len(a - b)} there not here, {len(b - a)} here "
                    f"not there); give another --out, or --fresh to start over"
                )
            self.resumed = True
        elif fresh and os.path.exists(rows_path):
            os.remove(rows_path)
        self.settings, self.scenes = settings, scenes
        write_json(run_path, {"settings": settings, "scenes": scenes})
        self._rows: dict = {}
        if os.path.exists(rows_path):
            with open(rows_path) as f:
                for line in f:
                    try:
                        row = json.loads(line)
                    except ValueError:  # the last line of a killed run may be cut off
                        continue
                    if isinstance(row, dict) and row.get("scenario") in scenes:
                        self._rows[(row["planner"], row["scenario"])] = row
        self._file = open(rows_path, "a")

    def done(self, planner: str, key: str) -> bool:
        """Whether the drive of ``key`` by ``planner`` is finished."""
        return (planner, key) in self._rows

    def add(self, row: dict) -> None:
        """Record a finished drive (``row`` has ``planner`` and ``scenario``)."""
        row = strict(row)
        self._file.write(json.dumps(row, allow_nan=False) + "\n")
        self._file.flush()
        self._rows[(row["planner"], row["scenario"])] = row

    def rows(self, planner: str) -> list:
        """The finished rows of ``planner``, in the order of the run's scenes."""
        return [self._rows[(planner, k)] for k in self.scenes if (planner, k) in self._rows]

    def close(self) -> None:
        self._file.close()
