#!/usr/bin/env python3
"""Run an lfit neural fitter exported with `lfit export-onnx` in ONNX Runtime (Python).

The exported directory holds three graphs (see docs/onnx.md):

  init.onnx     obs [B, 2R]                                  -> theta0 [B, 57], h0.l [B, H]
  propose.onnx  core_in [B, R+114+2R], h.l                   -> delta [B, 57], h_next.l
  step.onnx     step_in [B, 2R], delta, grad [B, 57],
                lambda_h.l (, gamma_h.l)                     -> update [B, 57], lambda, gamma,
                                                                lambda_h_next.l (, gamma_h_next.l)

One fitting iteration n (papers/002 Alg. 1) in your engine is:

  1. evaluate your energy at theta: residual R(theta) and gradient g(theta);
  2. delta = propose(normalise([R, g, theta, D]));  multiply delta and g by your DOF mask;
  3. evaluate R(theta + delta);
  4. update = step(normalise([R(theta), R(theta + delta)]), delta, g);
  5. theta = clamp(theta + update, lower, upper).

The normalisation statistics, the clip value, N, the modality and the DOF layout are in the
models' metadata. This script runs the first iteration for one frame whose raw features are
given in a JSON file and prints the network outputs as JSON:

  python3 docs/onnx_step.py --onnx out/onnx --sample sample.json

sample.json: {"observation": [2R], "residual": [R], "gradient": [57], "pose": [57],
              "residual_tried": [R]  (R at pose + delta, step 3 above),
              "free": [57] (optional, 1 free / 0 frozen)}
"""

import argparse
import json
import os
import sys

import numpy as np
import onnxruntime as ort


class LfitOnnx:
    """The exported graphs of one checkpoint, with the metadata they carry."""

    def __init__(self, directory):
        options = ort.SessionOptions()
        providers = ["CPUExecutionProvider"]
        self.init = ort.InferenceSession(os.path.join(directory, "init.onnx"), options, providers=providers)
        meta = self.init.get_modelmeta().custom_metadata_map
        if meta.get("lfit.format") != "lfit-onnx":
            sys.exit(f"{directory}/init.onnx: not an lfit ONNX export")
        if meta.get("lfit.version") != "1":
            sys.exit(f"{directory}/init.onnx: lfit ONNX version {meta.get('lfit.version')} is not supported (this script reads 1)")
        self.config = json.loads(meta["lfit.checkpoint"])["network"]
        self.stats = {k: (np.asarray(v["mean"], np.float32), np.asarray(v["std"], np.float32)) for k, v in json.loads(meta["lfit.feature_stats"]).items()}
        self.clip = np.float32(meta["lfit.feature_clip"])
        self.iterations = int(meta["lfit.iterations"])
        self.dof_mask = json.loads(meta["lfit.dof_mask"])
        sets = int(meta["lfit.weight_sets"])
        name = lambda role, s: f"{role}.{s}.onnx" if sets > 1 else f"{role}.onnx"
        self.propose_sessions = [ort.InferenceSession(os.path.join(directory, name("propose", s)), options, providers=providers) for s in range(sets)]
        has_step = self.config["update"] != "delta-only"
        self.step_sessions = [ort.InferenceSession(os.path.join(directory, name("step", s)), options, providers=providers) for s in range(sets)] if has_step else []
        self.gru_layers = self.config["layers"] if self.config["core"] == "gru" else 0
        self.hidden = self.config["hidden"]

    def normalise(self, name, x):
        """clip((x - mean) / std), non-finite entries to 0 (as lfit does, in float32)."""
        mean, std = self.stats[name]
        z = (np.asarray(x, np.float32) - mean) / std
        z = np.where(np.isfinite(z), z, np.float32(0.0))
        return np.clip(z, -self.clip, self.clip).astype(np.float32)

    def initial(self, observation):
        """theta0 = Phi(D) and the recurrent states of every network."""
        obs = self.normalise("observation", observation)
        outputs = self.init.run(None, {"obs": obs})
        names = [o.name for o in self.init.get_outputs()]
        values = dict(zip(names, outputs))
        batch = obs.shape[0]
        zeros = lambda: [np.zeros((batch, self.hidden), np.float32) for _ in range(self.gru_layers)]
        state = {
            "core": [values[f"h0.{l}"] for l in range(self.gru_layers)],
            "lambda": zeros() if self.step_sessions else [],
            "gamma": zeros() if any(i.name.startswith("gamma_h.") for s in self.step_sessions for i in s.get_inputs()) else [],
        }
        return values["theta0"], state, obs

    def _set(self, n):
        return min(n, len(self.propose_sessions) - 1) if self.config["per_step_weights"] else 0

    def propose(self, n, residual, gradient, pose, obs_normalised, state):
        """delta of iteration n; updates state['core']."""
        core_in = np.concatenate([self.normalise("residual", residual), self.normalise("gradient", gradient), self.normalise("pose", pose), obs_normalised], axis=1)
        session = self.propose_sessions[self._set(n)]
        feeds = {"core_in": core_in, **{f"h.{l}": h for l, h in enumerate(state["core"])}}
        values = dict(zip([o.name for o in session.get_outputs()], session.run(None, feeds)))
        state["core"] = [values[f"h_next.{l}"] for l in range(len(state["core"]))]
        return values["delta"]

    def step(self, n, residual, residual_tried, delta, gradient, state):
        """update, lambda, gamma of iteration n; updates the lambda/gamma states."""
        if not self.step_sessions:
            return delta, None, None
        step_in = np.concatenate([self.normalise("residual", residual), self.normalise("residual", residual_tried)], axis=1)
        session = self.step_sessions[self._set(n)]
        feeds = {"step_in": step_in, "delta": delta.astype(np.float32), "grad": np.asarray(gradient, np.float32)}
        feeds.update({f"lambda_h.{l}": h for l, h in enumerate(state["lambda"])})
        feeds.update({f"gamma_h.{l}": h for l, h in enumerate(state["gamma"])})
        values = dict(zip([o.name for o in session.get_outputs()], session.run(None, feeds)))
        state["lambda"] = [values[f"lambda_h_next.{l}"] for l in range(len(state["lambda"]))]
        state["gamma"] = [values[f"gamma_h_next.{l}"] for l in range(len(state["gamma"]))]
        return values["update"], values["lambda"], values["gamma"]


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--onnx", required=True, help="directory written by lfit export-onnx")
    parser.add_argument("--sample", required=True, help="JSON with one frame's raw features")
    args = parser.parse_args()
    fitter = LfitOnnx(args.onnx)
    with open(args.sample) as f:
        sample = json.load(f)
    row = lambda k: np.asarray([sample[k]], np.float64)
    free = np.asarray([sample.get("free", [1.0] * 57)], np.float32)

    theta0, state, obs = fitter.initial(row("observation"))
    delta = fitter.propose(0, row("residual"), row("gradient"), row("pose"), obs, state) * free
    gradient = row("gradient").astype(np.float32) * free
    update, lam, gamma = fitter.step(0, row("residual"), row("residual_tried"), delta, gradient, state)
    result = {
        "modality": fitter.config["modality"],
        "iterations": fitter.iterations,
        "theta0": theta0[0].tolist(),
        "delta": delta[0].tolist(),
        "lambda": None if lam is None else lam[0].tolist(),
        "gamma": None if gamma is None else gamma[0].tolist(),
        "update": update[0].tolist(),
        "pose_next": (np.asarray(sample["pose"], np.float32) + update[0]).tolist(),
    }
    json.dump(result, sys.stdout)
    print()


if __name__ == "__main__":
    main()
