"""Chunked, sharded, resumable batch runs."""
import os
import subprocess
import sys
import textwrap

import numpy as np
from conftest import cpu_devices_env

SCRIPT = textwrap.dedent("""
    import os, sys, json
    import jax, jax.numpy as jnp, numpy as np
    from jaxplan.eval.batch import run_chunked, load_results
    from jaxplan.geometry import box_corners, overlap_area, box_separation

    @jax.jit
    def fn(scene):
        car, obs = scene["car"], scene["obs"]            # (B, 5), (B, K, 5)
        a = overlap_area(box_corners(car)[:, None], box_corners(obs))
        return {"area": a.sum(-1), "min_sep": box_separation(car[:, None], obs).min(-1)}

    def make_chunk(start, stop):
        if int(os.environ.get("FAIL_AT", -1)) in range(start, stop):
            raise KeyboardInterrupt("killed")
        rng = np.random.default_rng(start)
        n = stop - start
        car = np.column_stack([rng.normal(size=(n, 2)), np.full(n, 4.5), np.full(n, 1.8), rng.normal(size=n)])
        obs = np.concatenate([rng.normal(size=(n, 6, 2)) * 3, np.full((n, 6, 1), 4.0),
                              np.full((n, 6, 1), 2.0), rng.normal(size=(n, 6, 1))], -1)
        return {"car": car.astype(np.float32), "obs": obs.astype(np.float32)}

    out = sys.argv[1]
    try:
        info = run_chunked(fn, make_chunk, 70, out, chunk_size=16, progress=False)
    except KeyboardInterrupt:
        print("INTERRUPTED"); sys.exit(3)
    r = load_results(out)
    np.savez(os.path.join(out, "all.npz"), **r)
    print(json.dumps({"devices": jax.device_count(), **info}))
""")


def _run(tmp_path, out, devices, fail_at=None):
    script = tmp_path / "job.py"
    script.write_text(SCRIPT)
    env = cpu_devices_env(devices)
    if fail_at is not None:
        env["FAIL_AT"] = str(fail_at)
    return subprocess.run([sys.executable, str(script), str(out)], env=env, capture_output=True, text=True,
                          timeout=300)


def test_sharded_equals_single_device_and_resume(tmp_path):
    single = _run(tmp_path, tmp_path / "one", 1)
    assert single.returncode == 0, single.stderr
    assert '"devices": 1' in single.stdout
    four = _run(tmp_path, tmp_path / "four", 4)
    assert four.returncode == 0, four.stderr
    assert '"devices": 4' in four.stdout
    a, b = np.load(tmp_path / "one" / "all.npz"), np.load(tmp_path / "four" / "all.npz")
    assert a["area"].shape == (70,) and np.any(a["area"] > 0)
    np.testing.assert_array_equal(a["area"], b["area"])
    np.testing.assert_array_equal(a["min_sep"], b["min_sep"])
    # Killed midway (in chunk 2 of 5), then restarted: same results, no corrupt files.
    killed = _run(tmp_path, tmp_path / "resume", 4, fail_at=40)
    assert killed.returncode == 3 and "INTERRUPTED" in killed.stdout
    files = sorted(os.listdir(tmp_path / "resume"))
    assert files == ["chunk_00000.npz", "chunk_00001.npz", "manifest.json"]
    again = _run(tmp_path, tmp_path / "resume", 4)
    assert again.returncode == 0, again.stderr
    assert '"chunks_skipped": 2' in again.stdout and '"chunks_run": 3' in again.stdout
    c = np.load(tmp_path / "resume" / "all.npz")
    np.testing.assert_array_equal(a["area"], c["area"])
