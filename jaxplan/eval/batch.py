"""Chunked, device-sharded, resumable batch runs.

A batch run maps a jitted per-scene function over many scenes. Scenes are
processed in chunks; each chunk is split over every local device along its
leading axis (``jax.sharding.Mesh`` + ``NamedSharding``), and its results are
written to ``OUT/chunk_00000.npz`` through a temporary file and an atomic
rename, so an interrupted run resumes at the first missing chunk and never
leaves a corrupt file. Memory stays bounded by the chunk size.

``OUT/manifest.json`` records what the chunks are results of: a hash of the
function and of the chunk maker (module, name, source, simple closure values),
the scene count, the chunk size and a fingerprint of the ``inputs`` the caller
passes (seeds, configs, arrays). A run resumes only when all of them match; any
other run into the same folder is refused with a message saying how to start
fresh (``fresh=True`` deletes the old chunks).

Several hosts: start every process with ``jax.distributed.initialize()`` (for
example from ``JAXPLAN_COORDINATOR=host:port JAXPLAN_NUM_PROCESSES=N
JAXPLAN_PROCESS_ID=i``, see ``maybe_init_distributed``); process ``i`` then
runs chunks ``i, i + N, i + 2N, ...`` on its own devices into the shared
output folder, and ``load_results`` gathers them in order.
"""

from __future__ import annotations

import dataclasses
import glob
import hashlib
import inspect
import json
import os
import time
from collections.abc import Callable
from typing import Any

import jax
import numpy as np
from jax.sharding import Mesh

from jaxplan.sim.devices import scene_mesh, sharded_map  # noqa: F401  (re-exported: the batch runner uses them)


def maybe_init_distributed() -> None:
    """Call ``jax.distributed.initialize`` when the JAXPLAN_* variables say so."""
    addr = os.environ.get("JAXPLAN_COORDINATOR")
    if addr:
        jax.distributed.initialize(
            coordinator_address=addr,
            num_processes=int(os.environ["JAXPLAN_NUM_PROCESSES"]),
            process_id=int(os.environ["JAXPLAN_PROCESS_ID"]),
        )


def _chunk_path(out_dir: str, i: int) -> str:
    return os.path.join(out_dir, f"chunk_{i:05d}.npz")


MANIFEST = "manifest.json"
_SIMPLE = (int, float, str, bool, bytes, type(None))


def _feed(h, obj) -> None:
    """Feed a canonical serialisation of ``obj`` to the hash ``h``."""
    if isinstance(obj, _SIMPLE):
        h.update(f"{type(obj).__name__}:{obj!r};".encode())
    elif isinstance(obj, dict):
        h.update(b"{")
        for k in sorted(obj, key=repr):
            _feed(h, k)
            _feed(h, obj[k])
        h.update(b"}")
    elif isinstance(obj, (list, tuple)):
        h.update(f"{type(obj).__name__}[".encode())
        for x in obj:
            _feed(h, x)
        h.update(b"]")
    elif hasattr(obj, "shape") and hasattr(obj, "dtype"):  # numpy / jax arrays
        a = np.ascontiguousarray(np.asarray(obj))
        h.update(f"array:{a.dtype.str}:{a.shape}:".encode())
        h.update(a.tobytes())
    elif dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        h.update(f"{type(obj).__module__}.{type(obj).__qualname__}(".encode())
        for f in dataclasses.fields(obj):
            _feed(h, f.name)
            _feed(h, getattr(obj, f.name))
        h.update(b")")
    else:
        r = repr(obj)
        if " at 0x" in r:
            raise TypeError(
                f"run_chunked inputs: cannot fingerprint {type(obj).__name__} (its repr names a memory "
                f"address); pass numbers, strings, arrays, dataclasses or containers of them"
            )
        h.update(f"{type(obj).__qualname__}:{r};".encode())


def fingerprint(obj: Any) -> str:
    """A hash (hex) of numbers, strings, arrays, dataclasses and dicts / lists / tuples of them."""
    h = hashlib.sha256()
    _feed(h, obj)
    return h.hexdigest()[:16]


def function_id(fn: Callable) -> str:
    """A hash (hex) of a function's identity: module, qualified name, source (or bytecode) and
    the closure values that are plain numbers or strings (a seed captured by a factory).
    ``jax.jit`` wrappers and ``functools.partial`` are looked through (partial arguments included)."""
    parts: list[Any] = []
    while True:
        if hasattr(fn, "func") and hasattr(fn, "args"):  # functools.partial
            parts.append(("partial", fn.args, dict(getattr(fn, "keywords", None) or {})))
            fn = fn.func
        elif hasattr(fn, "__wrapped__"):
            fn = fn.__wrapped__
        else:
            break
    parts.append((getattr(fn, "__module__", None) or "", getattr(fn, "__qualname__", type(fn).__qualname__)))
    try:
        parts.append(inspect.getsource(fn))
    except (OSError, TypeError):
        code = getattr(fn, "__code__", None)
        parts.append(code.co_code if code is not None else repr(type(fn)))
    cells = getattr(fn, "__closure__", None) or ()
    parts.append(tuple(c.cell_contents for c in cells if isinstance(getattr(c, "cell_contents", None), _SIMPLE)))
    h = hashlib.sha256()
    try:
        _feed(h, parts)
    except TypeError:  # partial arguments without a stable serialisation
        h.update(repr(parts[1:]).encode())
    return h.hexdigest()[:16]


_LABELS = {
    "fn": "the function",
    "make_chunk": "the chunk maker",
    "n_scenes": "the number of scenes",
    "chunk_size": "the chunk size",
    "inputs": "the inputs",
}


def _write_json(path: str, obj) -> None:
    tmp = f"{path}.{os.getpid()}.tmp"
    with open(tmp, "w") as f:
        json.dump(obj, f, indent=1, sort_keys=True)
    os.replace(tmp, path)


def _chunk_files(out_dir: str) -> list[str]:
    return sorted(f for f in glob.glob(os.path.join(out_dir, "chunk_*.npz")) if not f.endswith(".tmp.npz"))


def _read_manifest(out_dir: str) -> dict | None:
    path = os.path.join(out_dir, MANIFEST)
    if not os.path.exists(path):
        return None
    try:
        with open(path) as f:
            m = json.load(f)
        if not isinstance(m, dict):
            raise ValueError("not an object")
        return m
    except (OSError, ValueError) as e:
        raise ValueError(
            f"{path}: unreadable run manifest ({type(e).__name__}: {e}); delete {out_dir} to start fresh"
        ) from None


def _claim(out_dir: str, settings: dict, fresh: bool) -> None:
    """Resume only the run ``settings`` describe; refuse any other (see the module docstring)."""
    path = os.path.join(out_dir, MANIFEST)
    if fresh:
        for f in _chunk_files(out_dir) + ([path] if os.path.exists(path) else []):
            os.remove(f)
    old = _read_manifest(out_dir)
    how = (
        f"to start fresh delete {out_dir} (or its chunk_*.npz and {MANIFEST}), choose another output folder, "
        f"or pass fresh=True"
    )
    if old is None:
        if _chunk_files(out_dir):
            raise ValueError(
                f"{out_dir}: holds chunk files but no {MANIFEST}, so which run wrote them is unknown; {how}"
            )
        _write_json(path, settings)
        return
    diff = [k for k in settings if old.get(k) != settings[k]]
    if diff:
        what = "; ".join(f"{_LABELS.get(k, k)} ({old.get(k)} then, {settings[k]} now)" for k in diff)
        raise ValueError(f"{out_dir}: holds the chunks of another run: {what}; {how}")


def run_chunked(
    fn: Callable,
    make_chunk: Callable[[int, int], object],
    n_scenes: int,
    out_dir: str,
    chunk_size: int = 1024,
    mesh: Mesh | None = None,
    progress: bool = True,
    process_index: int | None = None,
    process_count: int | None = None,
    inputs: Any = None,
    fresh: bool = False,
) -> dict:
    """Run ``fn`` over ``n_scenes`` scenes in chunks, resuming from ``out_dir``.

    Args:
        fn: jitted batched function; returns a dict of arrays with a leading scene axis.
        make_chunk: ``(start, stop) -> batch pytree`` for scenes ``start..stop-1``.
        n_scenes: how many scenes in all (positive).
        out_dir: folder for the chunk files (created).
        chunk_size: scenes per chunk (bounds memory).
        inputs: what else the results depend on (seeds, configs, arrays, file lists): its
            fingerprint goes into ``OUT/manifest.json`` with the hashes of ``fn`` and
            ``make_chunk``, ``n_scenes`` and ``chunk_size``; a folder holding another run's
            chunks is refused (``ValueError``).
        fresh: delete the folder's chunks and manifest first (start over). With several
            processes, pass it from one only.

    Returns:
        dict with ``chunks_run``, ``chunks_skipped``, ``scenes_per_s`` (of the chunks run).
    """
    for name, v in (("n_scenes", n_scenes), ("chunk_size", chunk_size)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
            raise ValueError(f"run_chunked: {name} must be a positive integer, got {v!r}")
    if os.path.exists(out_dir) and not os.path.isdir(out_dir):
        raise ValueError(f"{out_dir}: is a file, not an output folder")
    os.makedirs(out_dir, exist_ok=True)
    _claim(
        out_dir,
        {
            "fn": function_id(fn),
            "make_chunk": function_id(make_chunk),
            "n_scenes": int(n_scenes),
            "chunk_size": int(chunk_size),
            "inputs": fingerprint(inputs),
        },
        fresh,
    )
    pi = jax.process_index() if process_index is None else process_index
    pc = jax.process_count() if process_count is None else process_count
    n_chunks = -(-n_scenes // chunk_size)
    mine = [i for i in range(n_chunks) if i % pc == pi]
    todo = [i for i in mine if not os.path.exists(_chunk_path(out_dir, i))]
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(
            total=sum(min(chunk_size, n_scenes - i * chunk_size) for i in todo),
            unit="scene",
            desc=os.path.basename(out_dir.rstrip("/")) or "batch",
        )
    t0, done = time.perf_counter(), 0
    for i in todo:
        start, stop = i * chunk_size, min(n_scenes, (i + 1) * chunk_size)
        res = sharded_map(fn, make_chunk(start, stop), mesh, pad_to=chunk_size)
        path = _chunk_path(out_dir, i)
        tmp = path + ".tmp.npz"
        arrays: dict[str, Any] = {k: np.asarray(v) for k, v in res.items()}
        np.savez(tmp, _start=np.int64(start), **arrays)
        os.replace(tmp, path)
        done += stop - start
        if bar is not None:
            bar.update(stop - start)
    if bar is not None:
        bar.close()
    dt = time.perf_counter() - t0
    return {
        "chunks_run": len(todo),
        "chunks_skipped": len(mine) - len(todo),
        "scenes_per_s": done / dt if done and dt > 0 else 0.0,
    }


def load_results(out_dir: str) -> dict:
    """Concatenate the chunk files of the run in ``out_dir`` (its ``manifest.json``) in scene order.

    A chunk that does not belong to the recorded run (a start that is not a multiple of
    its chunk size, or past its scenes) raises ``ValueError`` naming the file."""
    files = _chunk_files(out_dir)
    if not files:
        return {}
    m = _read_manifest(out_dir)
    parts = []
    for f in files:
        try:
            p = dict(np.load(f))
        except (OSError, ValueError) as e:
            raise ValueError(f"{f}: unreadable chunk file ({type(e).__name__}: {e})") from None
        if m is not None:
            start, size, n = int(p["_start"]), int(m["chunk_size"]), int(m["n_scenes"])
            if start % size or start >= n or f != _chunk_path(out_dir, start // size):
                raise ValueError(
                    f"{f}: not a chunk of the run recorded in {os.path.join(out_dir, MANIFEST)} "
                    f"({n} scenes in chunks of {size})"
                )
        parts.append(p)
    parts.sort(key=lambda p: int(p["_start"]))
    keys = [k for k in parts[0] if k != "_start"]
    return {k: np.concatenate([p[k] for p in parts], axis=0) for k in keys}


def peak_rss_mb() -> float:
    """Peak resident memory of this process in MiB (Linux ``ru_maxrss``)."""
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
