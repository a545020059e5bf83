"""Evaluations-to-1e-8 of pycma (PyPI `cma`) on the functions of `lfit optimize`, for comparison
with lfit's CMA-ES: d = 10, domain [-5, 5]^d, start 0, sigma0 = 1 (nevergrad's setting, lfit's
`--preset nevergrad`), optimum at (1, ..., 1) with value 0. Median over 11 seeds.

    python docs/results/pycma_reference.py
"""
import json
import statistics
import sys

import cma
import numpy as np


def sphere(x):
    return float(np.sum((x - 1.0) ** 2))


def ellipsoid(x):
    d = len(x)
    w = 10.0 ** (6.0 * np.arange(d) / (d - 1))
    return float(np.sum(w * (x - 1.0) ** 2))


def rosenbrock(x):
    return float(np.sum(100.0 * (x[1:] - x[:-1] ** 2) ** 2 + (1.0 - x[:-1]) ** 2))


def evals_to_target(f, d, seed, target=1e-8, budget=100000):
    es = cma.CMAEvolutionStrategy(np.zeros(d), 1.0, {
        "bounds": [-5, 5], "seed": seed + 1, "verbose": -9, "maxfevals": budget,
        "ftarget": target, "tolfun": 0, "tolfunhist": 0, "tolx": 0, "tolstagnation": 10**9,
    })
    evals = 0
    while not es.stop():
        xs = es.ask()
        values = [f(np.asarray(x)) for x in xs]
        for v in values:
            evals += 1
            if v < target:
                return evals
        es.tell(xs, values)
    return None


def main():
    d = int(sys.argv[1]) if len(sys.argv) > 1 else 10
    out = {"cma_version": cma.__version__, "d": d, "seeds": 11, "median_evals_to_1e-8": {}}
    for name, f in [("sphere", sphere), ("ellipsoid", ellipsoid), ("rosenbrock", rosenbrock)]:
        runs = [evals_to_target(f, d, s) for s in range(11)]
        ok = [r for r in runs if r is not None]
        out["median_evals_to_1e-8"][name] = {"median": statistics.median(ok) if ok else None, "successes": len(ok), "runs": runs}
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
