"""Evaluations-to-1e-8 of lfit's CMA-ES (`lfit optimize`) on sphere / ellipsoid / Rosenbrock at
d = 10, median over 11 seeds, next to pycma's figures from `pycma_reference.py` (run it first; it
writes pycma_reference.json). Same setting for both: [-5, 5]^d, start 0, sigma0 = 1.

    python docs/results/pycma_reference.py > docs/results/pycma_reference.json
    python docs/results/cma_vs_pycma.py target/release/lfit
"""
import json
import pathlib
import statistics
import subprocess
import sys

here = pathlib.Path(__file__).parent
lfit = sys.argv[1] if len(sys.argv) > 1 else "lfit"
pycma = json.loads((here / "pycma_reference.json").read_text())


def evals_to_target(function, seed, budget=30000, target=1e-8):
    out = subprocess.run([lfit, "optimize", "--function", function, "--dim", "10", "--method", "cma",
                          "--budget", str(budget), "--seed", str(seed), "--json"],
                         check=True, capture_output=True, text=True).stdout
    for evals, value in json.loads(out)["trace"]:
        if value < target:
            return evals
    return None


rows = []
for function in ["sphere", "ellipsoid", "rosenbrock"]:
    runs = [evals_to_target(function, s) for s in range(11)]
    ok = [r for r in runs if r is not None]
    ref = pycma["median_evals_to_1e-8"][function]
    rows.append((function, statistics.median(ok) if ok else None, len(ok), ref["median"], ref["successes"]))
print(f"| function (d=10) | lfit CMA-ES median evals to 1e-8 | successes | pycma {pycma['cma_version']} | successes |")
print("|---|---|---|---|---|")
for f, a, na, b, nb in rows:
    print(f"| {f} | {a} | {na}/11 | {b} | {nb}/11 |")
