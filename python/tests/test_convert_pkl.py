"""``python -m lfit.convert_pkl``: an SMPL-family pickle whose arrays are chumpy objects (SMPL,
MANO, FLAME) converts without chumpy installed to the npz lfit loads — the same model as the
arrays saved directly; bad input is a one-line error and writes nothing."""

import pickle
import subprocess
import sys
import textwrap

import os

import numpy as np

import lfit
from conftest import require

# SMPL's kinematic tree (24 joints: lfit names them as SMPL's when J = 24).
PARENTS = [-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 20, 21]


def smpl_like(seed=3, v=60, betas=10):
    rng = np.random.default_rng(seed)
    j = len(PARENTS)
    weights = rng.random((v, j)) ** 4
    weights /= weights.sum(1, keepdims=True)
    regressor = rng.random((j, v)) * (rng.random((j, v)) < 0.1)
    regressor[:, 0] += 1e-3
    regressor /= regressor.sum(1, keepdims=True)
    kintree = np.array([[2**32 - 1 if p < 0 else p for p in PARENTS], list(range(j))], dtype=np.int64)
    faces = np.array([[k, (k + 1) % v, (k + 2) % v] for k in range(0, v - 2, 2)], dtype=np.uint32)
    return {
        "v_template": rng.uniform(-0.9, 0.9, (v, 3)),
        "f": faces,
        "weights": weights,
        "kintree_table": kintree,
        "J_regressor": regressor,
        "shapedirs": rng.uniform(-0.02, 0.02, (v, 3, betas)),
        "posedirs": rng.uniform(-0.01, 0.01, (v, 3, 9 * (j - 1))),
    }


def run(*args, path=None):
    """`python ARGS`, with `path` first on PYTHONPATH (scipy's, from the environment, after it)."""
    env = dict(os.environ)
    if path is not None:
        env["PYTHONPATH"] = os.pathsep.join(p for p in (str(path), env.get("PYTHONPATH", "")) if p)
    return subprocess.run([sys.executable, *map(str, args)], capture_output=True, text=True, env=env)


def test_a_chumpy_pickle_converts_to_the_model_of_its_arrays(tmp_path):
    try:
        import scipy.sparse  # noqa: F401  (SMPL's J_regressor is one)
    except ImportError as e:
        require(f"scipy is not importable ({e}); scripts/fetch-scipy.sh installs it (LFIT_SCIPY_PYTHONPATH)")
    arrays = smpl_like()
    # A stand-in for chumpy (its Ch pickles its value as state "x"), importable only while the
    # pickle is written: the conversion runs where no chumpy exists.
    stub = tmp_path / "stub" / "chumpy"
    stub.mkdir(parents=True)
    (stub / "__init__.py").write_text("")
    (stub / "ch.py").write_text("class Ch(object):\n    def __init__(self, x):\n        self.x = x\n")
    np.savez(tmp_path / "arrays.npz", **arrays)
    pkl = tmp_path / "model.pkl"
    writer = textwrap.dedent(f"""
        import pickle, numpy as np, scipy.sparse
        from chumpy.ch import Ch
        a = dict(np.load({str(tmp_path / 'arrays.npz')!r}))
        a["shapedirs"] = Ch(a["shapedirs"])
        a["J_regressor"] = scipy.sparse.csc_matrix(a["J_regressor"])
        a["bs_style"] = "lbs"
        a["J"] = Ch(np.zeros((24, 3)))
        pickle.dump(a, open({str(pkl)!r}, "wb"), protocol=2)
    """)
    w = run("-c", writer, path=tmp_path / "stub")
    assert w.returncode == 0, w.stderr
    # Plain pickle cannot read it without chumpy: what the converter is for.
    p = run("-c", f"import pickle; pickle.load(open({str(pkl)!r}, 'rb'), encoding='latin1')")
    assert p.returncode != 0 and "chumpy" in p.stderr
    out = tmp_path / "smpl.npz"
    c = run("-m", "lfit.convert_pkl", pkl, out)
    assert c.returncode == 0, c.stderr
    assert "wrote" in c.stdout
    with np.load(out) as got:
        assert sorted(got.files) == sorted(arrays)
        for k, v in arrays.items():
            np.testing.assert_array_equal(got[k], v, err_msg=k)
    direct = tmp_path / "direct.npz"
    np.savez(direct, **arrays)
    a, b = lfit.Model.load(str(out)), lfit.Model.load(str(direct))
    np.testing.assert_array_equal(a.vertices, b.vertices)
    theta = np.random.default_rng(1).uniform(-0.3, 0.3, a.dim)
    for x, y in zip(a.pose(theta), b.pose(theta)):
        np.testing.assert_array_equal(x, y)


def test_bad_pickles_are_one_line_errors_and_write_nothing(tmp_path):
    out = tmp_path / "never.npz"
    cases = []
    listed = tmp_path / "list.pkl"
    listed.write_bytes(pickle.dumps([1, 2, 3]))
    cases.append((listed, "not a pickled model"))
    partial = tmp_path / "partial.pkl"
    partial.write_bytes(pickle.dumps({"v_template": np.zeros((3, 3))}))
    cases.append((partial, "not an SMPL-family model file"))
    cases.append((tmp_path / "missing.pkl", "No such file"))
    junk = tmp_path / "junk.pkl"
    junk.write_bytes(b"not a pickle")
    cases.append((junk, "error:"))
    for path, needle in cases:
        c = run("-m", "lfit.convert_pkl", path, out)
        assert c.returncode == 1, (path, c.stderr)
        lines = c.stderr.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("error:") and needle in lines[0], c.stderr
        assert not out.exists()
    u = run("-m", "lfit.convert_pkl", listed)
    assert u.returncode == 2 and "usage" in u.stderr
