"""lfit.fit (Python) against lfit fit (CLI): the neural fitter on 1,000 markers frames of the MakeHuman
body, alternated 3 times; wall time of the whole call and the fitter's own per-frame times.

    python python/bench/fit_fps.py PATH/TO/release/lfit [OUT]
"""
import json, os, subprocess, sys, time
from pathlib import Path
import lfit
ROOT = Path(__file__).resolve().parents[2]
CLI = sys.argv[1]
OUT = Path(sys.argv[2] if len(sys.argv) > 2 else "target/fit-fps")
data = OUT / "markers-1000.npz"
model = ROOT / "models/makehuman-cmu_mb.npz"
ck = ROOT / "checkpoints/markers-makehuman"
OUT.mkdir(parents=True, exist_ok=True)
if not data.exists():
    subprocess.run([CLI, "-q", "synth", "--modality", "markers", "--scenario", "local", "--frames", "1000",
                    "--seed", "77", "--model", model, "--out", data], check=True)
body = lfit.Model.load(model)
rows = []
for rep in range(3):
    t = time.perf_counter()
    subprocess.run([CLI, "-q", "fit", "--data", data, "--model", model, "--method", "neural", "--checkpoint", ck,
                    "--neural-start", "given", "--budget", "10", "--out", OUT / "cli.json"], check=True)
    cli_wall = time.perf_counter() - t
    cli_fit = sum(f["time_s"] for f in json.load(open(OUT / "cli.json"))["frames"])
    t = time.perf_counter()
    r = lfit.fit(body, str(data), method="neural", budget=10, checkpoint=ck, neural_start="given")
    py_wall = time.perf_counter() - t
    py_fit = float(sum(r.times))
    rows.append((cli_wall, cli_fit, py_wall, py_fit))
    print(f"rep {rep}: CLI wall {cli_wall:.2f} s (fitter {cli_fit:.2f} s), Python wall {py_wall:.2f} s (fitter {py_fit:.2f} s)", flush=True)
best = lambda k: min(r[k] for r in rows)
print(f"frames/s, best of 3: CLI {1000/best(0):.1f} (wall) {1000/best(1):.1f} (fitter); Python {1000/best(2):.1f} (wall) {1000/best(3):.1f} (fitter); Python/CLI wall {best(0)/best(2):.3f}, fitter {best(1)/best(3):.3f}")
