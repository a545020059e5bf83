#!/usr/bin/env python3
"""Issue 4's comparison: the shipped neural fitters against L-BFGS, CMA-ES and PSO on held-out
test sets, all on the same energy (the differentiable variant: EJ off, hinge EA) and the same
start poses. Writes neural_vs_baselines.md and .json next to this script (or --out).

    python3 docs/results/neural_vs_baselines.py --lfit $CARGO_TARGET_DIR/release/lfit

Test sets: `lfit synth --scenario local --frames 500 --seed 500000+k` (noise and occlusion at
their defaults); training used seeds derived from seed*0x9E3779B97F4A7C15 + 1e6 + step, so
neither the seeds nor the sampled motions overlap.
"""
import argparse, json, os, subprocess, sys, time

MODALITIES = {"markers": 0, "keypoints2d": 1, "hmd": 2}

def run(cmd):
    t = time.time()
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        sys.exit(f"failed: {' '.join(cmd)}\n{r.stderr.strip()}")
    return time.time() - t

def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--lfit", required=True)
    ap.add_argument("--frames", type=int, default=500)
    ap.add_argument("--modalities", default="markers,keypoints2d,hmd")
    ap.add_argument("--checkpoints", default="checkpoints")
    ap.add_argument("--out", default=os.path.dirname(os.path.abspath(__file__)))
    ap.add_argument("--work", default="out/neural_table")
    a = ap.parse_args()
    os.makedirs(a.work, exist_ok=True)
    energy = os.path.join(a.work, "energy_gradient.json")
    # The one energy every method minimises (EnergyConfig::default().for_gradient()).
    json.dump({"angle_prior": "hinge", "penetration_stride": 16, "robust": {"delta": 3.0, "kind": "huber"},
               "scales": {"pixel": 4.0, "position": 0.01, "rotation": 0.05}, "silhouette_width": 128,
               "silhouettes": False, "weights": {"data": 1.0, "ea": 1.0, "ed": 1.0, "ej": 0.1, "ep": 1.0, "es": 0.01}},
              open(energy, "w"))
    methods = [  # (label, fit arguments)
        ("neural N=5 from Φ(D)", ["--method", "neural", "--neural-start", "phi", "--budget", "10"]),
        ("neural N=5 from start pose", ["--method", "neural", "--neural-start", "given", "--budget", "10"]),
        ("L-BFGS (≤1000 evals)", ["--method", "lbfgs", "--budget", "1000"]),
        ("Levenberg–Marquardt (≤1000 evals)", ["--method", "lm", "--budget", "1000"]),
        ("Gauss-Newton (≤1000 evals)", ["--method", "gn", "--budget", "1000"]),
        ("CMA-ES @4000", ["--method", "cma", "--budget", "4000"]),
        ("PSO @4000", ["--method", "pso", "--budget", "4000"]),
    ]
    report, lines = {}, []
    for m in a.modalities.split(","):
        data = os.path.join(a.work, f"{m}.npz")
        run([a.lfit, "-q", "synth", "--modality", m, "--scenario", "local", "--frames", str(a.frames),
             "--seed", str(500000 + MODALITIES[m]), "--out", data])
        rows = []
        for label, args in methods:
            out = os.path.join(a.work, f"{m}_{args[1]}_{args[-3] if args[1] == 'neural' else args[-1]}.json")
            extra = ["--checkpoint", os.path.join(a.checkpoints, m), "--device", "flex"] if args[1] == "neural" else []
            # One worker thread: every time below is one core's.
            wall = run([a.lfit, "-q", "--threads", "1", "fit", "--data", data, "--energy", energy, "--out", out, *args, *extra])
            d = json.load(open(out))
            fr = d["frames"]
            n = len(fr)
            row = {"method": label, "frames": n, "v2v_mm": sum(f["v2v_mm"] for f in fr) / n,
                   "mpjpe_mm": sum(f["mpjpe_mm"] for f in fr) / n, "energy": sum(f["energy"] for f in fr) / n,
                   "time_ms": 1000 * sum(f["time_s"] for f in fr) / n,
                   "evaluations": sum(f["evaluations"] for f in fr) / n,
                   "iterations": sum(f["iterations"] for f in fr) / n, "command_wall_s": wall}
            if "v2v_mm_per_iteration" in fr[0]:
                k = len(fr[0]["v2v_mm_per_iteration"])
                row["v2v_per_iteration"] = [sum(f["v2v_mm_per_iteration"][i] for f in fr) / n for i in range(k)]
                row["mpjpe_per_iteration"] = [sum(f["mpjpe_mm_per_iteration"][i] for f in fr) / n for i in range(k)]
            rows.append(row)
            print(m, label, f"V2V {row['v2v_mm']:.1f} mm, {row['time_ms']:.2f} ms/frame", flush=True)
        report[m] = rows
        lines.append(f"\n### {m} ({rows[0]['frames']} held-out frames, local scenario, noise and occlusion on)\n")
        lines.append("| method | V2V (mm) | MPJPE (mm) | final energy | time / frame (ms) | evaluations | iterations |")
        lines.append("|---|---|---|---|---|---|---|")
        for r in rows:
            lines.append(f"| {r['method']} | {r['v2v_mm']:.1f} | {r['mpjpe_mm']:.1f} | {r['energy']:.3f} | {r['time_ms']:.2f} | {r['evaluations']:.0f} | {r['iterations']:.0f} |")
        lines.append("\nError after each neural iteration (papers/002 Fig. 4 as numbers; θ0 first):\n")
        lines.append("| start | " + " | ".join(f"n={i}" for i in range(len(rows[0]["v2v_per_iteration"]))) + " |")
        lines.append("|---|" + "---|" * len(rows[0]["v2v_per_iteration"]))
        for r in rows[:2]:
            lines.append(f"| {r['method']} V2V | " + " | ".join(f"{v:.1f}" for v in r["v2v_per_iteration"]) + " |")
            lines.append(f"| {r['method']} MPJPE | " + " | ".join(f"{v:.1f}" for v in r["mpjpe_per_iteration"]) + " |")
        best = min(r["v2v_mm"] for r in rows[2:])
        cma = next(r for r in rows if r["method"].startswith("CMA"))
        lb = next(r for r in rows if r["method"].startswith("L-BFGS"))
        lm = next(r for r in rows if r["method"].startswith("Levenberg"))
        for r in rows[:2]:
            lines.append(f"\n- {r['method']}: V2V {r['v2v_mm'] / best:.2f}× the best baseline's; "
                         f"{cma['time_ms'] / r['time_ms']:.0f}× faster than CMA-ES@4000, {lb['time_ms'] / r['time_ms']:.1f}× faster than L-BFGS per frame.")
        for r in rows[:2]:
            wins = []
            wins.append(("the neural fitter" if r["v2v_mm"] < lm["v2v_mm"] else "LM") + f" on V2V ({r['v2v_mm']:.1f} vs {lm['v2v_mm']:.1f} mm)")
            wins.append(("the neural fitter" if r["energy"] < lm["energy"] else "LM") + f" on final energy ({r['energy']:.3f} vs {lm['energy']:.3f})")
            wins.append(("the neural fitter" if r["time_ms"] < lm["time_ms"] else "LM") + f" on time per frame ({r['time_ms']:.2f} vs {lm['time_ms']:.2f} ms)")
            lines.append(f"\n- {r['method']} against Levenberg–Marquardt: " + "; ".join(w.replace(" on ", " wins on ", 1) for w in wins) + ".")
    with open(os.path.join(a.out, "neural_vs_baselines.json"), "w") as f:
        json.dump(report, f, indent=1)
    with open(os.path.join(a.out, "neural_vs_baselines.md"), "w") as f:
        f.write("# Neural fitter vs classical fitters (issues 4 and 14)\n\nGenerated by `python3 docs/results/neural_vs_baselines.py --lfit $CARGO_TARGET_DIR/release/lfit`"
                " with the checkpoints in `checkpoints/`. Every method minimises the same energy (gradient variant, printed in each fit JSON),"
                " from the same start poses, on one core (`--threads 1`); the neural fitter runs one frame per network pass (batch 1) on flex.\n" + "\n".join(lines) + "\n")

if __name__ == "__main__":
    main()
