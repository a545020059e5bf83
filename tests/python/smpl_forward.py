"""SMPL's forward model in numpy, written independently of lfit, for tests/makehuman_cli.rs and
the Python package's tests (python/tests/test_model.py imports `forward`).

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


def forward(npz, params):
    """SMPL's forward model (SMPL, Loper et al. 2015, eq. 1-4) from the arrays of a model file:
    T = v_template + S β + E ψ + P (R(θ) - I); joints = J_regressor (v_template + S β + E ψ);
    G_j = G_parent [R_j | c_j - c_parent]; v = Σ_j w_vj G_j (T_v - c_j) + t."""
    v_template = npz["v_template"]
    weights = npz["weights"]
    reg = npz["J_regressor"]
    parents = npz["kintree_table"][0].astype(np.int64)
    nj = weights.shape[1]
    shapedirs = npz["shapedirs"] if "shapedirs" in npz else np.zeros(v_template.shape + (0,))
    n_expr = int(npz["num_expression"]) if "num_expression" in npz else 0
    nb = shapedirs.shape[2] - n_expr
    pose = params[: 3 + 3 * nj]
    coeffs = params[3 + 3 * nj :]
    beta = np.zeros(shapedirs.shape[2])
    beta[: len(coeffs)] = coeffs[: shapedirs.shape[2]]
    assert nb >= 0
    shaped = v_template + shapedirs @ beta
    joints = reg @ shaped
    rots = [rodrigues(pose[3 + 3 * j : 6 + 3 * j]) for j in range(nj)]
    t = shaped
    if "posedirs" in npz:
        feature = np.concatenate([(rots[j] - np.eye(3)).ravel() for j in range(1, nj)])
        t = shaped + npz["posedirs"] @ feature
    g_rot, g_t = [], []
    for j in range(nj):
        p = parents[j]
        if p < 0 or p >= nj:
            g_rot.append(rots[j])
            g_t.append(joints[j])
        else:
            g_rot.append(g_rot[p] @ rots[j])
            g_t.append(g_t[p] + g_rot[p] @ (joints[j] - joints[p]))
    posed = np.zeros_like(t)
    for j in range(nj):
        w = weights[:, j]
        nz = w != 0
        if nz.any():
            posed[nz] += w[nz, None] * ((t[nz] - joints[j]) @ g_rot[j].T + g_t[j])
    return posed + pose[:3], np.asarray(g_t) + pose[:3]


def main():
    model = np.load(sys.argv[1])
    params = json.load(open(sys.argv[2]))
    out = [
        forward(model, np.concatenate([np.asarray(p, np.float64), np.asarray(b, np.float64)]))[0]
        for p, b in zip(params["poses"], params["shapes"])
    ]
    np.save(sys.argv[3], np.asarray(out))


if __name__ == "__main__":
    main()
