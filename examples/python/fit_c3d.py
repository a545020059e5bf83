"""Import a C3D capture, fit it with lfit, and plot the per-frame marker error.

    python examples/python/fit_c3d.py trial.c3d --label-map labels.json --plot error.png

The markers become an lfit dataset for the MakeHuman body (`lfit.import_c3d`, as `lfit data
import --c3d`), every frame is fitted with the shipped markers network followed by
Levenberg-Marquardt (`neural+lm`; `--method lm` without the network, and wheels built without the
`neural` feature fall back to it), and the mean distance of the fitted markers to the captured
ones is printed per frame and, when matplotlib is installed, plotted.
"""

import argparse
from pathlib import Path

import numpy as np

import lfit

ROOT = Path(__file__).resolve().parents[2]


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("c3d", help="C3D file of marker trajectories")
    p.add_argument("--label-map", help='JSON {"C3D label": "model marker"}; default: labels equal marker names')
    p.add_argument("--up", default="y", choices=["y", "z"], help="up axis of the capture's lab frame")
    p.add_argument("--model", default="makehuman-cmu_mb", help="model file or name")
    p.add_argument("--method", default="neural+lm", help="neural+lm, lm, lbfgs, cma, ...")
    p.add_argument("--checkpoint", default=str(ROOT / "checkpoints" / "markers-makehuman"))
    p.add_argument("--budget", type=int, default=100, help="energy evaluations per frame")
    p.add_argument("--frames", help="frames to fit, e.g. 0..50 (default: all)")
    p.add_argument("--plot", default="marker_error.png", help="where to save the plot")
    args = p.parse_args()

    model = lfit.Model.load(args.model)
    data = lfit.import_c3d(args.c3d, model, label_map=args.label_map, up=args.up)
    print(f"{data}: {data.summary['visible_fraction']:.0%} of the marker samples seen")

    method = args.method
    if method.startswith("neural") and not lfit.HAS_NEURAL:
        print("this lfit build has no neural fitter: fitting with lm")
        method = "lm"
    checkpoint = args.checkpoint if method.startswith("neural") else None
    result = lfit.fit(model, data, method=method, budget=args.budget, checkpoint=checkpoint, frames=args.frames)

    error = result.observation_error  # mm, mean over the markers seen in each frame
    for frame, e, t in zip(result.frames, error, result.times):
        print(f"frame {frame:5d}  marker error {e:7.2f} mm  {1000 * t:7.1f} ms")
    print(f"{result.method}: mean {np.mean(error):.2f} mm, median {np.median(error):.2f} mm, "
          f"{np.mean(error <= 5.0):.0%} of frames within 5 mm, {np.sum(result.times):.1f} s")

    try:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
    except ImportError:
        print("matplotlib is not installed: no plot")
        return
    fig, ax = plt.subplots(figsize=(8, 3))
    ax.plot(result.frames, error, lw=1)
    ax.set_xlabel("frame")
    ax.set_ylabel("marker error (mm)")
    ax.set_title(f"{Path(args.c3d).name}: {result.method}, budget {args.budget}")
    fig.tight_layout()
    fig.savefig(args.plot, dpi=120)
    print(f"plot: {args.plot}")


if __name__ == "__main__":
    main()
