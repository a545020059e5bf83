"""lfit.Model: loading, layout, and the forward pass against `lfit template pose` (the CLI) and
against an independent numpy implementation of SMPL's forward model (tests/python/smpl_forward.py,
shared with tests/makehuman_cli.rs)."""

import json
import sys

import numpy as np
import pytest

import lfit
from conftest import ROOT, one_line

sys.path.insert(0, str(ROOT / "tests" / "python"))
from smpl_forward import forward as numpy_forward  # noqa: E402

SMPL_PARENTS = [-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 20, 21]


def random_smpl_file(path, seed=3, v=300, b=6):
    """A random model in the SMPL layout: 24 joints in SMPL's tree, ≤ 4 influences per vertex,
    a dense joint regressor, shape blend shapes and pose correctives."""
    rng = np.random.default_rng(seed)
    j = 24
    verts = rng.uniform([-0.4, 0.0, -0.15], [0.4, 1.8, 0.15], size=(v, 3))
    faces = rng.integers(0, v, size=(2 * v, 3))
    faces = faces[(faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])]
    weights = np.zeros((v, j))
    for i in range(v):
        k = rng.integers(1, 5)
        js = rng.choice(j, size=k, replace=False)
        w = rng.uniform(0.1, 1.0, size=k)
        weights[i, js] = w / w.sum()
    reg = np.zeros((j, v))
    for a in range(j):
        idx = rng.choice(v, size=5, replace=False)
        w = rng.uniform(0.1, 1.0, size=5)
        reg[a, idx] = w / w.sum()
    kintree = np.array([[2**32 - 1 if p < 0 else p for p in SMPL_PARENTS], list(range(j))], dtype=np.uint32)
    np.savez(
        path,
        v_template=verts,
        f=faces.astype(np.int32),
        weights=weights,
        kintree_table=kintree,
        J_regressor=reg,
        shapedirs=rng.normal(scale=0.01, size=(v, 3, b)),
        posedirs=rng.normal(scale=0.005, size=(v, 3, 9 * (j - 1))),
    )
    return path


def random_params(model, n, seed):
    rng = np.random.default_rng(seed)
    p = np.zeros((n, model.dim))
    p[:, :3] = rng.normal(scale=0.3, size=(n, 3))
    p[:, 3 : model.pose_dim] = rng.normal(scale=0.4, size=(n, model.pose_dim - 3))
    p[:, model.pose_dim :] = rng.normal(size=(n, model.dim - model.pose_dim))
    return p


def obj_vertices(path):
    """The vertices of an OBJ file lfit wrote: f32 values in shortest round-trip text, read back
    as the same f32 values."""
    rows = [line.split()[1:4] for line in open(path) if line.startswith("v ")]
    return np.array(rows, dtype=np.float32).astype(np.float64)


@pytest.fixture(scope="module")
def models(tmp_path_factory):
    smpl = random_smpl_file(tmp_path_factory.mktemp("smpl") / "smpl.npz")
    return {"makehuman": ROOT / "models" / "makehuman-cmu_mb.npz", "smpl": smpl}


@pytest.mark.parametrize("name", ["makehuman", "smpl"])
def test_pose_matches_the_cli_and_an_independent_numpy_forward_pass(models, name, cli, tmp_path):
    path = models[name]
    model = lfit.Model.load(path)
    params = random_params(model, 3, seed=11)
    vertices, joints = model.pose(params)
    assert vertices.shape == (3, model.vertices.shape[0], 3) and joints.shape == (3, len(model.joint_names), 3)
    # One vector gives the batch's first row.
    v0, j0 = model.pose(params[0])
    np.testing.assert_array_equal(v0, vertices[0])
    np.testing.assert_array_equal(j0, joints[0])
    # `lfit template pose` on the same parameters (shortest round-trip text of the same floats).
    pd = model.pose_dim
    pose_json = tmp_path / "p.json"
    pose_json.write_text(json.dumps({"poses": params[:, :pd].tolist(), "shapes": params[:, pd:].tolist()}))
    cli("template", "pose", "--model", path, "--pose", pose_json, "--out", tmp_path / "o.obj")
    worst_cli = max(
        np.abs(obj_vertices(tmp_path / f"o_{i:04}.obj") - vertices[i]).max() for i in range(len(params))
    )
    assert worst_cli <= 1e-9, worst_cli
    # The independent forward pass (f64 throughout; lfit returns the f32 skinning output).
    npz = dict(np.load(path))
    worst_v, worst_j = 0.0, 0.0
    for i in range(len(params)):
        v_ref, j_ref = numpy_forward(npz, params[i])
        worst_v = max(worst_v, np.abs(v_ref - vertices[i]).max())
        worst_j = max(worst_j, np.abs(j_ref - joints[i]).max())
    print(f"{name}: vs CLI {worst_cli:.2e} m, vs numpy vertices {worst_v:.2e} m, joints {worst_j:.2e} m")
    assert worst_v <= 1e-6, worst_v
    assert worst_j <= 1e-6, worst_j


def test_pose_only_params_take_shape_separately(makehuman):
    p = random_params(makehuman, 2, seed=5)
    pd = makehuman.pose_dim
    full_v, _ = makehuman.pose(p)
    split_v, _ = makehuman.pose(p[:, :pd], shape=p[:, pd:])
    np.testing.assert_array_equal(full_v, split_v)
    # Shorter shape vectors are zero-padded, as `lfit template pose` pads them.
    short_v, _ = makehuman.pose(p[0, :pd], shape=p[0, pd : pd + 3])
    padded = p[0].copy()
    padded[pd + 3 :] = 0.0
    np.testing.assert_array_equal(short_v, makehuman.pose(padded)[0])


def test_layout_faces_markers(makehuman):
    layout = makehuman.layout
    assert layout["dim"] == makehuman.dim == makehuman.pose_dim + makehuman.shape_dim
    assert layout["blocks"]["translation"] == (0, 3)
    assert layout["blocks"]["shape"] == (makehuman.pose_dim, makehuman.dim)
    assert len(layout["names"]) == makehuman.dim and layout["names"][0] == "t_x"
    assert makehuman.faces.shape == (26756, 3) and makehuman.faces.dtype == np.int64
    assert makehuman.vertices.shape == (13380, 3)
    assert len(makehuman.marker_names) == 39 and "LFHD" in makehuman.marker_names
    assert makehuman.parents[0] == -1 and len(makehuman.parents) == len(makehuman.joint_names) == 31
    assert makehuman.info()["id"] == makehuman.id


def test_models_by_name():
    by_name = lfit.Model.load("makehuman-cmu_mb")
    by_path = lfit.Model.load(ROOT / "models" / "makehuman-cmu_mb.npz")
    assert by_name.id == by_path.id
    np.testing.assert_array_equal(by_name.vertices, by_path.vertices)
    assert lfit.Model.load("makehuman-face").expression_dim > 0
    assert lfit.Model.load("default").dim == 57
    assert lfit.Model.load("morphable").shape_dim == 8


@pytest.mark.parametrize(
    "params, needle",
    [
        (np.zeros(10), "params has shape (10,), expected (96,) or (N, 96)"),
        (np.zeros((2, 3, 96)), "params has shape (2, 3, 96)"),
        (np.array(["a"] * 96), "params has dtype <U1, expected real numbers"),
        (np.full(96, np.nan), "params[0] is not a finite number (NaN)"),
        (np.zeros(96, dtype=complex), "params has dtype complex128"),
    ],
)
def test_bad_params_are_one_line_value_errors(makehuman, params, needle):
    with pytest.raises(ValueError) as e:
        makehuman.pose(params)
    assert needle in one_line(e), str(e.value)
    assert isinstance(e.value, lfit.LfitError)


def test_bad_shape_and_skinning(makehuman):
    pd = makehuman.pose_dim
    with pytest.raises(lfit.LfitError, match="shape has 17 numbers, but the model 'makehuman-cmu_mb' has only 16"):
        makehuman.pose(np.zeros(pd), shape=np.zeros(17))
    with pytest.raises(lfit.LfitError, match="shape given twice"):
        makehuman.pose(np.zeros(makehuman.dim), shape=np.zeros(3))
    with pytest.raises(lfit.LfitError, match="unknown skinning 'xyz'"):
        makehuman.pose(np.zeros(pd), skinning="xyz")


def test_missing_model_file_is_the_cli_line(cli, tmp_path):
    missing = tmp_path / "missing.npz"
    with pytest.raises(lfit.LfitError) as e:
        lfit.Model.load(missing)
    p = cli("model", "info", "--model", missing, check=False)
    assert p.returncode != 0
    assert p.stderr.strip() == f"error: {one_line(e)}"
    with pytest.raises(lfit.LfitError, match="model 'smpl-x': no such file, and not a model name"):
        lfit.Model.load("smpl-x")
