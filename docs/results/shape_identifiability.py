"""How well joint centres determine a body's shape coefficients (docs/results/captured-motion.md,
round 6).

Keypoints2d observes the joint centres only (the joint regressor times the shaped rest mesh), so a
shape direction that barely moves them cannot be recovered from keypoints, however long the
sequence. This prints the singular values of d(joint centres)/d(beta) (mm per unit of beta, summed
over the joints, centred so that a whole-body shift does not count), and, for one subject's beta,
the RMS error left when the k best-observed directions are recovered exactly and the rest are left
at the prior's mean (0).

    python3 docs/results/shape_identifiability.py models/makehuman-cmu_mb.npz [DATASET.npz]

DATASET (an `lfit synth` file) gives the subject's beta (its first frame's `gt_shape`); without it
only the singular values are printed. Needs numpy.
"""

import sys

import numpy as np


def main() -> None:
    if len(sys.argv) not in (2, 3):
        sys.exit("usage: shape_identifiability.py MODEL.npz [DATASET.npz]")
    model = np.load(sys.argv[1])
    shapedirs, regressor = model["shapedirs"], model["J_regressor"]
    # d(joint centre j, axis c)/d(beta b), metres; centred over the joints.
    joints = np.einsum("jv,vcb->jcb", regressor, shapedirs)
    joints -= joints.mean(axis=0, keepdims=True)
    jacobian = joints.reshape(-1, shapedirs.shape[2])
    _, sigma, vt = np.linalg.svd(jacobian, full_matrices=False)
    print("singular values, mm per unit beta:", " ".join(f"{1000 * s:.1f}" for s in sigma))
    if len(sys.argv) == 3:
        beta = np.load(sys.argv[2])["gt_shape"][0]
        coefficients = vt @ beta
        n = len(beta)
        print(f"subject's beta RMS (the error of the prior's mean): {np.sqrt(np.mean(beta**2)):.3f}")
        for k in range(n + 1):
            left = np.sqrt(np.sum(coefficients[k:] ** 2) / n)
            print(f"best {k:2d} directions recovered exactly: beta RMS error {left:.3f}")


if __name__ == "__main__":
    main()
