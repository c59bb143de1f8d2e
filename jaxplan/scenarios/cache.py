"""Loading many scenario files: parsed scenes cached on disk, files parsed in parallel.

Parsing a CommonRoad file and building its ``Scene`` takes 0.2-1.5 s on the host; a
collection of a thousand files takes minutes. ``load_many`` keeps every built
``SceneRecord`` in a cache folder keyed by

- the file's content (SHA-256 of its bytes, so a renamed or moved file is still found and an
  edited one is parsed again),
- the ``SceneConfig`` and the loading horizon,
- the source of the code that builds scenes (every module of ``jaxplan.scenarios`` and
  ``jaxplan.types``): a change to the loaders invalidates every entry.

Files not in the cache are parsed by ``workers`` processes. A file that cannot be loaded is
reported as ``(path, reason)``, never dropped silently.

The cache folder (``cache_dir``): ``$JAXPLAN_CACHE_DIR``, else ``$XDG_CACHE_HOME/jaxplan``,
else ``~/.cache/jaxplan``; scenes under ``scenes/``, compiled XLA programs under ``xla/``
(``enable_compilation_cache``). Deleting the folder is always safe.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import os
import pickle
import sys
import tempfile

from jaxplan.scenarios.fields import ScenarioError

CACHE_ENV = "JAXPLAN_CACHE_DIR"


def cache_dir() -> str:
    """The user cache folder of jaxplan (see the module docstring); not created here."""
    if os.environ.get(CACHE_ENV):
        return os.environ[CACHE_ENV]
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(base, "jaxplan")


def enable_compilation_cache(folder: str | None = None) -> str | None:
    """Turn on JAX's persistent compilation cache in ``folder`` (default ``cache_dir()/xla``),
    unless the user set ``JAX_COMPILATION_CACHE_DIR`` (then theirs is used). Programs that
    compiled in under a second are not stored. Returns the folder in use."""
    import jax

    if os.environ.get("JAX_COMPILATION_CACHE_DIR"):
        return os.environ["JAX_COMPILATION_CACHE_DIR"]
    folder = folder or os.path.join(cache_dir(), "xla")
    try:
        os.makedirs(folder, exist_ok=True)
    except OSError:  # a read-only home: compile every time, say nothing more
        return None
    jax.config.update("jax_compilation_cache_dir", folder)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)
    return folder


@functools.cache
def code_fingerprint() -> str:
    """SHA-256 of the source of the modules that build scenes (``jaxplan.scenarios``, ``jaxplan.types``)."""
    import jaxplan.scenarios as pkg

    h = hashlib.sha256()
    here = os.path.dirname(pkg.__file__)
    files = sorted(os.path.join(here, f) for f in os.listdir(here) if f.endswith(".py"))
    files.append(os.path.join(os.path.dirname(here), "types.py"))
    for f in files:
        with open(f, "rb") as fh:
            h.update(os.path.basename(f).encode() + b"\0" + fh.read())
    return h.hexdigest()


def file_digest(path: str) -> str:
    """SHA-256 of a file's bytes as stored (compressed files by their compressed bytes)."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def _entry_key(digest: str, config, horizon) -> str:
    h = hashlib.sha256()
    h.update(f"{digest}|{config!r}|{horizon!r}|{code_fingerprint()}".encode())
    return h.hexdigest()


def _load_one(path: str, config, horizon):
    """``("ok", record)`` or ``("error", reason)`` for one file (runs in a worker process)."""
    from jaxplan.scenarios.files import load_records

    try:
        return "ok", load_records([path], config, horizon)[0]
    except (ScenarioError, ValueError, ImportError) as e:
        return "error", str(e)


def _store(folder: str, key: str, record) -> None:
    os.makedirs(folder, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=folder, suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as f:
            pickle.dump(record, f, protocol=pickle.HIGHEST_PROTOCOL)
        os.replace(tmp, os.path.join(folder, key + ".pkl"))
    except OSError:
        if os.path.exists(tmp):
            os.remove(tmp)


def _fetch(folder: str, key: str):
    path = os.path.join(folder, key + ".pkl")
    if not os.path.isfile(path):
        return None
    try:
        with open(path, "rb") as f:
            return pickle.load(f)
    except Exception:  # a truncated or foreign file: parse again
        return None


@dataclasses.dataclass
class Loaded:
    """What ``load_many`` returns.

    Attributes:
        records: ``SceneRecord``s of the files that loaded, in the input order.
        errors: ``(path, reason)`` of every file that did not.
        cached: how many records came from the cache.
        parse_s: wall time spent parsing (cache misses), seconds.
    """

    records: list
    errors: list
    cached: int
    parse_s: float


def load_many(
    paths: list,
    config=None,
    horizon: float | None = None,
    workers: int | None = None,
    use_cache: bool = True,
    progress: bool = True,
) -> Loaded:
    """Load scenario files into ``SceneRecord``s (``jaxplan.scenarios.files.load_records``), from
    the cache where possible, parsing the rest in ``workers`` processes.

    Args:
        paths: scenario files (``jaxplan.scenarios.files.expand_paths``).
        config: ``SceneConfig`` (default ``SceneConfig()``).
        horizon: keep obstacle predictions up to this time (s); default all.
        workers: parsing processes (default: the CPU count, at most 8; 1 parses in this process).
        use_cache: read and write the scene cache.
        progress: show a progress bar on stderr.

    Returns:
        ``Loaded``.
    """
    import time

    from jaxplan.scenarios.scene import SceneConfig

    config = config or SceneConfig()
    folder = os.path.join(cache_dir(), "scenes")
    records: dict = {}
    errors: dict = {}
    keys: dict = {}
    todo = []
    for p in paths:
        try:
            keys[p] = _entry_key(file_digest(p), config, horizon)
        except OSError as e:
            errors[p] = f"{p}: not readable ({e.strerror or e})"
            continue
        hit = _fetch(folder, keys[p]) if use_cache else None
        if hit is not None:
            records[p] = dataclasses.replace(hit, path=p)
        else:
            todo.append(p)
    cached = len(records)
    t0 = time.perf_counter()
    if todo:
        n = workers if workers is not None else min(8, os.cpu_count() or 1)
        n = max(1, min(n, len(todo) // 4))  # a worker process costs ~2 s to start (it imports JAX)
        bar = _bar(len(todo), progress)
        if n == 1:
            results = []
            for p in todo:
                results.append((p, _load_one(p, config, horizon)))
                bar.update(1)
            for p, (status, value) in results:
                if status == "ok":
                    records[p] = value
                    if use_cache:
                        _store(folder, keys[p], value)
                else:
                    errors[p] = value
        else:
            out = folder if use_cache else tempfile.mkdtemp(prefix="jaxplan-scenes-")
            for p, (status, value) in _parse_in_workers(todo, [keys[p] for p in todo], out, config, horizon, n, bar):
                if status == "ok":
                    rec = _fetch(out, keys[p])
                    if rec is None:
                        errors[p] = f"{p}: the parsing process wrote no scene"
                    else:
                        records[p] = dataclasses.replace(rec, path=p)
                else:
                    errors[p] = value
            if not use_cache:
                import shutil

                shutil.rmtree(out, ignore_errors=True)
        bar.close()
    return Loaded(
        [records[p] for p in paths if p in records],
        [(p, errors[p]) for p in paths if p in errors],
        cached,
        time.perf_counter() - t0,
    )


def _parse_in_workers(paths: list, keys: list, folder: str, config, horizon, n: int, bar):
    """Parse ``paths`` in ``n`` child processes (``python -m jaxplan.scenarios.cache``), each writing
    its records into ``folder`` under ``keys``; yields ``(path, (status, reason))`` as they finish.

    Child processes, not ``multiprocessing``: a pool that spawns re-imports the caller's main
    module, which fails for code run from stdin and needs a ``__main__`` guard in scripts."""
    import json
    import subprocess
    import threading

    job = {"config": pickle.dumps(config).hex(), "horizon": horizon, "folder": folder}
    procs, lines = [], []
    lock = threading.Lock()

    def read(proc):
        for line in proc.stdout:
            msg = json.loads(line)
            with lock:
                lines.append(msg)
            bar.update(1)

    readers = []
    for w in range(n):
        part = list(zip(paths[w::n], keys[w::n]))
        proc = subprocess.Popen(
            [sys.executable, "-m", "jaxplan.scenarios.cache"], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
        )
        assert proc.stdin is not None  # stdin=PIPE
        proc.stdin.write(json.dumps(dict(job, files=part)))
        proc.stdin.close()
        t = threading.Thread(target=read, args=(proc,), daemon=True)
        t.start()
        procs.append(proc)
        readers.append(t)
    for proc, t in zip(procs, readers):
        proc.wait()
        t.join()
    done = {m["path"]: (m["status"], m.get("reason", "")) for m in lines}
    for p in paths:
        yield p, done.get(p, ("error", f"{p}: the parsing process stopped before this file"))


def _worker_main() -> None:
    """A parsing process: reads its job (JSON) from stdin, writes one JSON line per file to stdout."""
    import json

    job = json.loads(sys.stdin.read())
    config = pickle.loads(bytes.fromhex(job["config"]))
    for path, key in job["files"]:
        status, value = _load_one(path, config, job["horizon"])
        if status == "ok":
            _store(job["folder"], key, value)
            msg = {"path": path, "status": "ok"}
        else:
            msg = {"path": path, "status": "error", "reason": value}
        print(json.dumps(msg), flush=True)


def _bar(total: int, show: bool):
    from tqdm import tqdm

    return tqdm(
        total=total,
        desc="parsing scenarios",
        unit="file",
        disable=not show or total < 2,
        file=sys.stderr,
        dynamic_ncols=True,
    )


if __name__ == "__main__":
    _worker_main()
