"""Chunked, device-sharded, resumable batch runs.

A batch run maps a jitted per-scene function over many scenes. Scenes are
processed in chunks; each chunk is split over every local device along its
leading axis (``jax.sharding.Mesh`` + ``NamedSharding``), and its results are
written to ``OUT/chunk_00000.npz`` through a temporary file and an atomic
rename, so an interrupted run resumes at the first missing chunk and never
leaves a corrupt file. Memory stays bounded by the chunk size.

Several hosts: start every process with ``jax.distributed.initialize()`` (for
example from ``JAXPLAN_COORDINATOR=host:port JAXPLAN_NUM_PROCESSES=N
JAXPLAN_PROCESS_ID=i``, see ``maybe_init_distributed``); process ``i`` then
runs chunks ``i, i + N, i + 2N, ...`` on its own devices into the shared
output folder, and ``load_results`` gathers them in order.
"""
from __future__ import annotations

import glob
import os
import time
from typing import Callable

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec


def maybe_init_distributed() -> None:
    """Call ``jax.distributed.initialize`` when the JAXPLAN_* variables say so."""
    addr = os.environ.get("JAXPLAN_COORDINATOR")
    if addr:
        jax.distributed.initialize(coordinator_address=addr,
                                   num_processes=int(os.environ["JAXPLAN_NUM_PROCESSES"]),
                                   process_id=int(os.environ["JAXPLAN_PROCESS_ID"]))


def scene_mesh(devices=None) -> Mesh:
    """A 1-D mesh over the local devices with axis name ``"scenes"``."""
    devices = jax.local_devices() if devices is None else devices
    return Mesh(np.asarray(devices), ("scenes",))


def sharded_map(fn: Callable, batch, mesh: Mesh | None = None, pad_to: int | None = None):
    """Apply a jitted batched ``fn`` to ``batch`` split over the mesh's devices.

    Args:
        fn: jitted function of a pytree whose leaves have a leading scene axis.
        batch: pytree of arrays ``(B, ...)``.
        pad_to: pad the scene axis to at least this size (one compiled shape for
            every chunk, the last one included).

    Returns:
        ``fn(batch)`` as numpy arrays ``(B, ...)``; the leading axis is padded to
        a multiple of the device count (repeating the last scene) and cut back.
    """
    mesh = mesh or scene_mesh()
    n_dev = mesh.devices.size
    leaves = jax.tree_util.tree_leaves(batch)
    B = leaves[0].shape[0]
    size = max(B, pad_to or 0)
    pad = size - B + (-size) % n_dev

    def place(x):
        x = np.asarray(x)
        if pad:
            x = np.concatenate([x, np.repeat(x[-1:], pad, axis=0)], axis=0)
        spec = PartitionSpec("scenes", *([None] * (x.ndim - 1)))
        return jax.device_put(x, NamedSharding(mesh, spec))

    out = fn(jax.tree_util.tree_map(place, batch))
    return jax.tree_util.tree_map(lambda y: np.asarray(y)[:B], out)


def _chunk_path(out_dir: str, i: int) -> str:
    return os.path.join(out_dir, f"chunk_{i:05d}.npz")


def run_chunked(fn: Callable, make_chunk: Callable[[int, int], object], n_scenes: int, out_dir: str,
                chunk_size: int = 1024, mesh: Mesh | None = None, progress: bool = True,
                process_index: int | None = None, process_count: int | None = None) -> dict:
    """Run ``fn`` over ``n_scenes`` scenes in chunks, resuming from ``out_dir``.

    Args:
        fn: jitted batched function; returns a dict of arrays with a leading scene axis.
        make_chunk: ``(start, stop) -> batch pytree`` for scenes ``start..stop-1``.
        n_scenes: how many scenes in all.
        out_dir: folder for the chunk files (created).
        chunk_size: scenes per chunk (bounds memory).

    Returns:
        dict with ``chunks_run``, ``chunks_skipped``, ``scenes_per_s`` (of the chunks run).
    """
    os.makedirs(out_dir, exist_ok=True)
    pi = jax.process_index() if process_index is None else process_index
    pc = jax.process_count() if process_count is None else process_count
    n_chunks = -(-n_scenes // chunk_size)
    mine = [i for i in range(n_chunks) if i % pc == pi]
    todo = [i for i in mine if not os.path.exists(_chunk_path(out_dir, i))]
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=sum(min(chunk_size, n_scenes - i * chunk_size) for i in todo), unit="scene",
                   desc=os.path.basename(out_dir.rstrip("/")) or "batch")
    t0, done = time.perf_counter(), 0
    for i in todo:
        start, stop = i * chunk_size, min(n_scenes, (i + 1) * chunk_size)
        res = sharded_map(fn, make_chunk(start, stop), mesh, pad_to=chunk_size)
        path = _chunk_path(out_dir, i)
        tmp = path + ".tmp.npz"
        np.savez(tmp, _start=np.int64(start), **{k: np.asarray(v) for k, v in res.items()})
        os.replace(tmp, path)
        done += stop - start
        if bar is not None:
            bar.update(stop - start)
    if bar is not None:
        bar.close()
    dt = time.perf_counter() - t0
    return {"chunks_run": len(todo), "chunks_skipped": len(mine) - len(todo),
            "scenes_per_s": done / dt if done and dt > 0 else 0.0}


def load_results(out_dir: str) -> dict:
    """Concatenate every chunk file in ``out_dir`` in scene order."""
    files = sorted(glob.glob(os.path.join(out_dir, "chunk_*.npz")))
    files = [f for f in files if not f.endswith(".tmp.npz")]
    if not files:
        return {}
    parts = [dict(np.load(f)) for f in files]
    parts.sort(key=lambda p: int(p["_start"]))
    keys = [k for k in parts[0] if k != "_start"]
    return {k: np.concatenate([p[k] for p in parts], axis=0) for k in keys}


def peak_rss_mb() -> float:
    """Peak resident memory of this process in MiB (Linux ``ru_maxrss``)."""
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


