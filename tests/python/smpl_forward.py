"""SMPL's forward model in numpy, written independently of lfit, for tests/makehuman_cli.rs.

Usage: smpl_forward.py MODEL.npz PARAMS.json OUT.npy

PARAMS.json: {"poses": [[t(3), r_0(3), ..., r_{J-1}(3)], ...], "shapes": [[β], ...]}. Rotations
are axis-angle relative to the parent in the world-aligned rest frame (SMPL's convention):
T(β) = v_template + S β, joints = J_regressor T(β), G_j = G_parent [R_j | c_j − c_parent],
v = Σ_j w_vj G_j (T_v − c_j) + t. Writes the posed vertices as a (N, V, 3) float64 array.
"""
import json
import sys

import numpy as np


def rodrigues(r):
    theta = np.linalg.norm(r)
    if theta < 1e-12:
        return np.eye(3)
    k = r / theta
    kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(theta) * kx + (1 - np.cos(theta)) * kx @ kx


def main():
    model = np.load(sys.argv[1])
    params = json.load(open(sys.argv[2]))
    v_template = model["v_template"]
    shapedirs = model["shapedirs"]
    weights = model["weights"]
    reg = model["J_regressor"]
    parents = model["kintree_table"][0].astype(np.int64)
    n_joints = weights.shape[1]
    out = []
    for pose, beta in zip(params["poses"], params["shapes"]):
        pose = np.asarray(pose, dtype=np.float64)
        beta = np.asarray(beta, dtype=np.float64)
        t = v_template + shapedirs[:, :, : len(beta)] @ beta
        joints = reg @ t
        rot = [rodrigues(pose[3 + 3 * j : 6 + 3 * j]) for j in range(n_joints)]
        g_rot, g_t = [], []
        for j in range(n_joints):
            p = parents[j]
            if p < 0 or p >= n_joints:
                g_rot.append(rot[j])
                g_t.append(joints[j])
            else:
                g_rot.append(g_rot[p] @ rot[j])
                g_t.append(g_t[p] + g_rot[p] @ (joints[j] - joints[p]))
        posed = np.zeros_like(t)
        for j in range(n_joints):
            w = weights[:, j]
            nz = w != 0
            if nz.any():
                local = (t[nz] - joints[j]) @ g_rot[j].T + g_t[j]
                posed[nz] += w[nz, None] * local
        out.append(posed + pose[:3])
    np.save(sys.argv[3], np.asarray(out))


if __name__ == "__main__":
    main()
