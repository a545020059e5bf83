"""V2V of `scripts/eval-c3d.sh`'s fits against the frames the C3D files were written from.

The imported datasets carry no ground truth (a user's captures have none), so `lfit fit` reports
marker RMS only; the synthetic frames behind them (`OUT/<source>-truth.npz`, in the same order)
do; `far`'s are the captured frames moved 3.6 m (MOVED). Needs the lfit Python module and
numpy (./scripts/test.sh installs both into its venv).

    python3 scripts/c3d-v2v.py OUT ROW...    # ROW as eval-c3d.sh names them, e.g. captured-lm
"""
import json
import sys

import numpy as np

import lfit


# Sources eval-c3d.sh writes moved: the frames of another source, moved by this vector (metres).
MOVED = {"far": ("captured", (3.0, 0.0, -2.0))}


def main(out, rows):
    model = lfit.Model.load("models/makehuman-cmu_mb.npz")
    truths = {}
    print("| source, method | frames | V2V (mm) | median V2V (mm) |")
    print("|---|---|---|---|")
    for row in rows:
        source, offset = MOVED.get(row.split("-", 1)[0], (row.split("-", 1)[0], (0.0, 0.0, 0.0)))
        if source not in truths:
            truths[source] = model.pose(lfit.Dataset.load(f"{out}/{source}-truth.npz").gt_params)[0]
        frames = json.load(open(f"{out}/{row}.json"))["frames"]
        params = np.array([f["pose"] + f.get("shape", []) for f in frames])
        params[:, :3] -= offset
        verts = model.pose(params)[0]
        truth = truths[source][[f["frame"] for f in frames]]
        v2v = 1000 * np.linalg.norm(verts - truth, axis=2).mean(axis=1)
        print(f"| {row} | {len(frames)} | {v2v.mean():.1f} | {np.median(v2v):.1f} |")


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2:])
