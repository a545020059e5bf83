"""Fits frames of an lfit dataset with scipy.optimize.least_squares on lfit's own residuals.

Each frame is served by `lfit objective-server` (JSON lines): `describe` gives the free entries,
their box and the start; `{"x": ..., "residuals": true, "jacobian": true}` gives the residuals
(energy = sum of squares) and their exact Jacobian. scipy runs method "trf" with that Jacobian
from the served start inside the served box, at its default tolerances.

Usage: scipy_least_squares.py LFIT DATASET FRAMES OUT.json [SERVER_ARG ...]
(FRAMES: comma-separated indices; SERVER_ARGs go to every `lfit objective-server`, e.g.
`--template models/makehuman-face.npz --energy configs/face-energy.json`)
Writes {"frames": [{"frame", "energy", "nfev", "njev", "status"}, ...]}.
"""

import json
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from scipy.optimize import least_squares


class Server:
    def __init__(self, lfit, data, frame, extra):
        self.proc = subprocess.Popen(
            [lfit, "objective-server", "--data", data, "--frame", str(frame), *extra],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
        )
        self.cache = None

    def ask(self, request):
        self.proc.stdin.write(json.dumps(request) + "\n")
        self.proc.stdin.flush()
        answer = json.loads(self.proc.stdout.readline())
        if "error" in answer:
            raise RuntimeError(answer["error"])
        return answer

    def at(self, x, jacobian):
        """Residuals, Jacobian (None unless asked) and energy at x; one request per point
        (the Jacobian is asked for only where scipy wants it)."""
        key = x.tobytes()
        if self.cache is None or self.cache[0] != key or (jacobian and self.cache[2] is None):
            a = self.ask({"x": x.tolist(), "residuals": True, "jacobian": jacobian})
            jac = np.asarray(a["jacobian"]) if jacobian else None
            self.cache = (key, np.asarray(a["residuals"]), jac, a["energy"])
        return self.cache

    def close(self):
        self.proc.stdin.close()
        self.proc.wait()


def fit(lfit, data, frame, extra):
    server = Server(lfit, data, frame, extra)
    try:
        d = server.ask({"describe": True})
        lower, upper = np.asarray(d["lower"]), np.asarray(d["upper"])
        x0 = np.clip(np.asarray(d["start"]), lower, upper)
        res = least_squares(
            lambda x: server.at(x, False)[1],
            x0,
            jac=lambda x: server.at(x, True)[2],
            bounds=(lower, upper),
            method="trf",
        )
        energy = server.at(np.asarray(res.x, dtype=float), False)[3]
        return {"frame": frame, "energy": energy, "nfev": int(res.nfev), "njev": int(res.njev or 0), "status": int(res.status)}
    finally:
        server.close()


def main():
    lfit, data, frames, out = sys.argv[1:5]
    extra = sys.argv[5:]
    frames = [int(f) for f in frames.split(",")]
    with ThreadPoolExecutor(max_workers=4) as pool:
        results = list(pool.map(lambda f: fit(lfit, data, f, extra), frames))
    with open(out + ".part", "w") as fh:
        json.dump({"frames": results}, fh)
    import os

    os.replace(out + ".part", out)


if __name__ == "__main__":
    main()
