"""Measurements of the Python package against the Rust library and the CLI (not a test: speed is
measured, never asserted). Prints one JSON object.

    python python/bench/bench.py [--cli PATH] [--frames 1000] [--wheel PATH]

- overhead: one `Energy.residuals_and_jacobian` call from Python (argument check, conversion,
  the call, the numpy arrays back; also `residuals` + `jacobian` as scipy calls them) against the
  same library call timed inside Rust (`_rust_seconds_per_residuals_and_jacobian`), markers on the
  MakeHuman body, 400 single calls of each, alternated;
- neural: frames per second of `lfit.fit(method="neural")` on N synthetic markers frames against
  `lfit fit` (the whole process) on the same file, same batch, best of 3;
- import: `python -c "import lfit"` wall time (best of 5) and the wheel's size.
"""

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import lfit

ROOT = Path(__file__).resolve().parents[2]
MH = ROOT / "models" / "makehuman-cmu_mb.npz"


def overhead(model, calls=400):
    """Single calls, Rust and Python alternated (the machine's load drifts; a loop of many calls
    measures the allocator's reuse more than the call): median and best per call."""
    data = lfit.synth("markers", model, frames=1, seed=1)
    e = lfit.Energy(model, data, 0)
    x = e.x0 + 0.01
    rust, py, split = [], [], []
    for _ in range(calls):
        rust.append(e._rust_seconds_per_residuals_and_jacobian(x, 1))
        t = time.perf_counter()
        e.residuals_and_jacobian(x)
        py.append(time.perf_counter() - t)
        t = time.perf_counter()
        e.residuals(x)
        e.jacobian(x)
        split.append(time.perf_counter() - t)
    med = lambda v: float(np.median(v)) * 1e6  # noqa: E731
    return {
        "residuals": e.residual_count,
        "free": e.dim,
        "rust_median_us": med(rust),
        "python_median_us": med(py),
        "ratio_median": med(py) / med(rust),
        "ratio_best": min(py) / min(rust),
        "python_residuals_then_jacobian_median_us": med(split),
    }


def neural(cli, frames, batch):
    ck = ROOT / "checkpoints" / "markers-makehuman"
    with tempfile.TemporaryDirectory() as tmp:
        data = Path(tmp) / "m.npz"
        subprocess.run([cli, "synth", "--modality", "markers", "--model", MH, "--frames", str(frames),
                        "--seed", "7", "--out", data, "-q"], check=True)
        args = ["--method", "neural", "--checkpoint", ck, "--budget", "10", "--batch", str(batch)]
        cli_s, py_s = [], []
        for _ in range(3):
            t = time.perf_counter()
            subprocess.run([cli, "fit", "--data", data, "--model", MH, *map(str, args), "--out",
                            Path(tmp) / "r.json", "-q"], check=True, capture_output=True)
            cli_s.append(time.perf_counter() - t)
            t = time.perf_counter()
            r = lfit.fit(MH, data, method="neural", budget=10, checkpoint=ck, batch=batch)
            py_s.append(time.perf_counter() - t)
            assert len(r) == frames
        return {
            "frames": frames,
            "batch": batch,
            "cli_fps": frames / min(cli_s),
            "python_fps": frames / min(py_s),
            "ratio": min(cli_s) / min(py_s),
        }


def import_time():
    times = []
    for _ in range(5):
        t = time.perf_counter()
        subprocess.run([sys.executable, "-c", "import lfit"], check=True, env=os.environ)
        times.append(time.perf_counter() - t)
    t = time.perf_counter()
    subprocess.run([sys.executable, "-c", "pass"], check=True)
    bare = time.perf_counter() - t
    return {"import_lfit_s": min(times), "python_startup_s": bare}


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--cli", default=str(Path(os.environ.get("CARGO_TARGET_DIR", Path.home() / ".cache/lfit-target")) / "release" / "lfit"))
    p.add_argument("--frames", type=int, default=1000)
    p.add_argument("--batch", type=int, default=256)
    p.add_argument("--wheel", help="the wheel file, for its size")
    p.add_argument("--skip-neural", action="store_true")
    args = p.parse_args()
    model = lfit.Model.load(MH)
    out = {"overhead": overhead(model), "import": import_time()}
    if args.wheel:
        out["wheel_bytes"] = os.path.getsize(args.wheel)
    if not args.skip_neural and lfit.HAS_NEURAL:
        out["neural"] = neural(args.cli, args.frames, args.batch)
    print(json.dumps(out, indent=2))


if __name__ == "__main__":
    main()
