"""Minimise lfit's energy for one frame with nevergrad, through `lfit objective-server`.

The server speaks JSON lines: {"describe": true} -> {"dim", "lower", "upper", "start", "names"},
{"x": [...]} -> {"energy", "terms"}. It evaluates exactly the energy `lfit fit` minimises, so the
result is comparable with `lfit fit --method cma --budget 2000 --frames 0` on the same dataset.

    pip install nevergrad
    lfit synth --modality markers --scenario local --frames 1 --seed 0 --out /tmp/m.npz
    python docs/nevergrad_objective_server.py /tmp/m.npz 0 2000
"""
import json
import subprocess
import sys

import nevergrad as ng
import numpy as np


class LfitObjective:
    def __init__(self, data, frame, lfit="lfit"):
        self.proc = subprocess.Popen(
            [lfit, "objective-server", "--data", data, "--frame", str(frame)],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, bufsize=1)
        self.info = self.ask({"describe": True})

    def ask(self, request):
        self.proc.stdin.write(json.dumps(request) + "\n")
        answer = json.loads(self.proc.stdout.readline())
        if "error" in answer:
            raise RuntimeError(answer["error"])
        return answer

    def __call__(self, x):
        return self.ask({"x": [float(v) for v in x]})["energy"]

    def close(self):
        self.proc.stdin.close()
        self.proc.wait()


def main():
    data, frame, budget = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
    objective = LfitObjective(data, frame)
    info = objective.info
    lower, upper = np.array(info["lower"]), np.array(info["upper"])
    param = ng.p.Array(init=np.array(info["start"])).set_bounds(lower, upper)
    # papers/000 §4.1: initial mutation 0.1 m for the translation, 3° for rotations.
    steps = np.array([0.1 if n.startswith("t_") else np.radians(3.0) for n in info["names"]])
    param.set_mutation(sigma=steps)
    optimizer = ng.optimizers.CMA(parametrization=param, budget=budget)
    recommendation = optimizer.minimize(objective)
    best = objective.ask({"x": recommendation.value.tolist()})
    print(json.dumps({"method": "nevergrad CMA", "budget": budget, "energy": best["energy"], "terms": best["terms"]}))
    objective.close()


if __name__ == "__main__":
    main()
