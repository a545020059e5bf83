"""Type stubs of the native module ``lfit._lfit`` (re-exported by ``lfit``)."""

import os
from typing import Any, Callable, Dict, List, Optional, Sequence, Tuple, Union

import numpy as np
import numpy.typing as npt

_Path = Union[str, "os.PathLike[str]"]
_Array = npt.ArrayLike
_F64 = npt.NDArray[np.float64]
_ModelArg = Union["Model", _Path]
_DataArg = Union["Dataset", _Path]

HAS_NEURAL: bool
"""Whether this build has the neural fitter (``method="neural"``, ``"neural+lm"``)."""

SHIPPED_MODELS: List[str]
"""Names of the models shipped in the package (``Model.load(name)``)."""

class LfitError(ValueError):
    """Bad input or a failed command: the one-line message the ``lfit`` CLI prints."""

class Model:
    """A body model: mesh, skeleton, skinning weights, blend shapes, markers."""

    @staticmethod
    def load(source: _Path) -> "Model":
        """A template directory or SMPL-layout ``.npz`` file, a shipped model by name
        (``makehuman-cmu_mb``, ``makehuman-face``) or a procedural body (``default``,
        ``morphable``, ``tall``, ...)."""
    @property
    def id(self) -> str: ...
    @property
    def dim(self) -> int:
        """Length of a full parameter vector, ``3 + 3J + B + E``."""
    @property
    def pose_dim(self) -> int:
        """``3 + 3J``: translation, then an axis-angle rotation per joint."""
    @property
    def shape_dim(self) -> int: ...
    @property
    def expression_dim(self) -> int: ...
    @property
    def layout(self) -> Dict[str, Any]:
        """``{"dim", "names", "blocks": {"translation": (start, end), "rotations": ..., "shape": ..., "expression": ...}}``."""
    @property
    def joint_names(self) -> List[str]: ...
    @property
    def parents(self) -> List[int]:
        """Parent index of every joint, -1 for the root."""
    @property
    def marker_names(self) -> List[str]: ...
    @property
    def faces(self) -> npt.NDArray[np.int64]:
        """``(F, 3)`` vertex indices."""
    @property
    def vertices(self) -> _F64:
        """Rest vertices ``(V, 3)``, metres."""
    def info(self) -> Dict[str, Any]:
        """Everything ``lfit model info`` prints."""
    def pose(
        self,
        params: _Array,
        shape: Optional[_Array] = None,
        expression: Optional[_Array] = None,
        skinning: str = "lbs",
    ) -> Tuple[_F64, _F64]:
        """Posed ``(vertices, joints)``: ``(V, 3), (J, 3)`` for ``params`` ``(P,)``, or
        ``(N, V, 3), (N, J, 3)`` for ``(N, P)``; P is ``dim`` or ``pose_dim`` (then ``shape``
        and ``expression`` may be given, zero-padded)."""
    def shape_for_height(self, height: float) -> _F64:
        """The β ``(B,)`` of least norm whose rest mesh is ``height`` metres tall, sole to
        crown: the shape prior's most likely body of that stature (``lfit fit --known-shape
        height:M``)."""
    def rest_height(self, shape: Optional[_Array] = None) -> float:
        """The rest mesh's height in metres at ``shape`` ``(≤B,)`` (default the mean shape)."""

class Dataset:
    """Frames of observations with start poses and, when synthetic, the ground truth."""

    @staticmethod
    def load(path: _Path) -> "Dataset": ...
    def save(self, path: _Path) -> None:
        """Writes the ``.npz`` file atomically."""
    def __len__(self) -> int: ...
    @property
    def modality(self) -> str: ...
    @property
    def scenario(self) -> str: ...
    @property
    def model_id(self) -> str: ...
    @property
    def fps(self) -> float: ...
    @property
    def path(self) -> Optional["os.PathLike[str]"]:
        """The file it was read from or written to (a ``pathlib.Path``), or None."""
    @property
    def has_ground_truth(self) -> bool: ...
    @property
    def summary(self) -> Optional[Dict[str, Any]]: ...
    @property
    def start_params(self) -> _F64:
        """``(N, P)`` start parameters."""
    @property
    def gt_params(self) -> _F64:
        """``(N, P)`` ground truth, ``(0, P)`` without."""
    @property
    def observations(self) -> _F64:
        """Sparse modalities ``(N, D)``; scan ``(N, V, 3)``."""
    @property
    def visibility(self) -> npt.NDArray[np.bool_]: ...
    @property
    def reference_joints(self) -> Optional[_F64]: ...
    @property
    def reference_visible(self) -> Optional[Any]: ...
    @property
    def sensor(self) -> Dict[str, Any]: ...
    @property
    def meta(self) -> Dict[str, Any]: ...

class Motion:
    """A motion in one model's parameter layout (``lfit motion import``)."""

    @property
    def params(self) -> _F64:
        """``(T, P)``."""
    @property
    def fps(self) -> float: ...
    @property
    def source(self) -> str: ...
    @property
    def summary(self) -> Dict[str, Any]: ...
    def save(self, path: _Path) -> None: ...
    def __len__(self) -> int: ...

class Energy:
    """One frame's energy over the free entries of its scenario (points ``x`` of length ``dim``)."""

    def __init__(
        self,
        model: Optional[_ModelArg] = None,
        data: Optional[_DataArg] = None,
        frame: int = 0,
        *,
        observations: Optional[_Array] = None,
        visible: Optional[_Array] = None,
        sensor: Optional[Union[str, Dict[str, Any]]] = None,
        scenario: str = "global",
        start: Optional[_Array] = None,
        config: Optional[Union[Dict[str, Any], _Path]] = None,
        height_prior: Optional[Union[float, str, Tuple[float, float]]] = None,
    ) -> None: ...
    @property
    def dim(self) -> int: ...
    @property
    def x0(self) -> _F64: ...
    @property
    def lower(self) -> _F64: ...
    @property
    def upper(self) -> _F64: ...
    @property
    def free(self) -> List[int]: ...
    @property
    def names(self) -> List[str]: ...
    @property
    def modality(self) -> str: ...
    @property
    def config(self) -> Dict[str, Any]: ...
    @property
    def residual_count(self) -> Optional[int]: ...
    @property
    def evaluations(self) -> int: ...
    def full(self, x: _Array) -> _F64:
        """The full parameter vector of ``x``."""
    def value(self, x: _Array) -> Any:
        """float for ``(dim,)``; ``(N,)`` array for ``(N, dim)``."""
    def value_and_grad(self, x: _Array) -> Tuple[float, _F64]: ...
    def terms(self, x: _Array) -> Dict[str, float]: ...
    def residuals(self, x: _Array) -> _F64:
        """``(M,)``; the energy is their sum of squares."""
    def jacobian(self, x: _Array) -> _F64:
        """``(M, dim)``."""
    def residuals_and_jacobian(self, x: _Array) -> Tuple[_F64, _F64]: ...
    def _rust_seconds_per_residuals_and_jacobian(self, x: _Array, repeats: int) -> float: ...

class FitResult:
    """One row per fitted frame."""

    @property
    def frames(self) -> npt.NDArray[np.int64]: ...
    @property
    def params(self) -> _F64:
        """``(N, P)``: pose, β, ψ."""
    @property
    def poses(self) -> _F64: ...
    @property
    def shapes(self) -> _F64: ...
    @property
    def expressions(self) -> _F64: ...
    @property
    def energies(self) -> _F64: ...
    @property
    def start_energies(self) -> _F64: ...
    @property
    def times(self) -> _F64: ...
    @property
    def evaluations(self) -> _F64: ...
    @property
    def v2v_mm(self) -> _F64: ...
    @property
    def mpjpe_mm(self) -> _F64: ...
    @property
    def pa_mpjpe_mm(self) -> _F64: ...
    @property
    def reference_mpjpe_mm(self) -> _F64: ...
    @property
    def reference_pa_mpjpe_mm(self) -> _F64: ...
    @property
    def observation_error(self) -> _F64: ...
    @property
    def observation_unit(self) -> Optional[str]: ...
    @property
    def method(self) -> str: ...
    @property
    def summary(self) -> Dict[str, Any]: ...
    def document(self) -> Dict[str, Any]:
        """The result document ``lfit fit --out`` writes."""
    def save(self, path: _Path) -> None: ...
    def __len__(self) -> int: ...

def load_dataset(path: _Path) -> Dataset: ...
def synth(
    modality: str,
    model: Optional[_ModelArg] = None,
    *,
    scenario: str = "local",
    frames: int = 100,
    seed: int = 0,
    source: str = "motion",
    noise: float = 1.0,
    noise_spread: float = 0.0,
    fps: float = 30.0,
    library_motions: Optional[Sequence[str]] = None,
    motions: Optional[Sequence[_Path]] = None,
    with_library: bool = False,
    mirror: bool = False,
    heading: bool = False,
    jitter_deg: float = 0.0,
    uniform_share: float = 0.0,
    marker_slip_mm: float = 0.0,
    keypoint_bias_mm: float = 0.0,
    keypoint_detector: Optional[int] = None,
    cameras: Optional[int] = None,
    camera_file: Optional[_Path] = None,
    out: Optional[_Path] = None,
) -> Dataset:
    """``lfit synth``: same settings and seed, same data; written to ``out`` too when given.
    Ctrl-C stops it (``KeyboardInterrupt``, nothing written)."""

def import_c3d(
    path: _Path,
    model: Optional[_ModelArg] = None,
    *,
    label_map: Optional[_Path] = None,
    up: str = "y",
    scenario: str = "sequence",
    out: Optional[_Path] = None,
) -> Dataset:
    """``lfit data import --c3d``."""

def import_trc(
    path: _Path,
    model: Optional[_ModelArg] = None,
    *,
    label_map: Optional[_Path] = None,
    up: str = "y",
    scenario: str = "sequence",
    out: Optional[_Path] = None,
) -> Dataset:
    """``lfit data import --trc``."""

def import_keypoints(
    paths: Sequence[_Path],
    layout: str,
    camera: _Path,
    model: Optional[_ModelArg] = None,
    *,
    camera_names: Optional[Sequence[str]] = None,
    camera_units: Optional[str] = None,
    keypoint_scale: Optional[str] = None,
    keypoint_map: Optional[_Path] = None,
    min_confidence: float = 0.1,
    fps: float = 30.0,
    scenario: str = "sequence",
    up: str = "y",
    reference: Optional[Sequence[_Path]] = None,
    reference_person: Optional[int] = None,
    reference_layout: Optional[str] = None,
    reference_map: Optional[_Path] = None,
    out: Optional[_Path] = None,
) -> Dataset:
    """``lfit data import --keypoints``."""

def read_cameras(
    camera: _Path,
    *,
    camera_names: Optional[Sequence[str]] = None,
    camera_units: Optional[str] = None,
    up: str = "y",
    pinhole: bool = False,
    out: Optional[_Path] = None,
) -> Dict[str, Any]:
    """``lfit data cameras``: the summary (each camera's place); writes lfit's JSON to ``out``."""

def import_bvh(
    path: _Path,
    model: Optional[_ModelArg] = None,
    *,
    map: Optional[_Path] = None,
    units: str = "auto",
    up: str = "y",
    root: str = "floor",
    stride: int = 1,
    rest_pose: Optional[_Path] = None,
    out: Optional[_Path] = None,
) -> Motion:
    """``lfit motion import --bvh``."""

def motion_prior(
    motions: Sequence[Union[_Path, Motion]],
    model: Optional[_ModelArg] = None,
    *,
    data: Optional[Sequence[_Path]] = None,
    stride: int = 1,
    epsilon_deg: float = 3.0,
    weight: Optional[float] = None,
    modality: str = "markers",
    components: int = 1,
    seed: int = 0,
    held_out: Optional[Sequence[_Path]] = None,
    energy: Optional[_Path] = None,
    out: Optional[_Path] = None,
) -> Tuple[Dict[str, Any], Dict[str, Any]]:
    """``lfit motion prior``: ``(energy, summary)``, the energy configuration carrying a pose prior
    fitted to ``motions`` (files or ``Motion``s) for ``fit(energy=...)``, and the summary; written
    to ``out`` too when given. ``weight`` defaults to ``modality``'s (markers 0.01, keypoints2d
    0.001; required otherwise); ``components`` above 1 fits SMPLify's mixture by EM."""

def calibrate(
    model: Optional[_ModelArg],
    data: _DataArg,
    *,
    poses: Optional[_Path] = None,
    prior_mm: Optional[float] = None,
    out: Optional[_Path] = None,
) -> Dict[str, Any]:
    """``lfit calibrate``: the markers' or keypoints' offsets at known poses (the dataset's ground
    truth, or ``poses``: a fit result), as the document ``fit(..., offsets=)`` reads; written to
    ``out`` too when given."""

def fit(
    model: Optional[_ModelArg],
    data: _DataArg,
    method: str = "lm",
    budget: int = 100,
    *,
    checkpoint: Optional[_Path] = None,
    known_shape: Optional[Union[str, _Array]] = None,
    height_prior: Optional[Union[float, str, Tuple[float, float]]] = None,
    frames: Optional[Union[str, Sequence[int]]] = None,
    seed: int = 0,
    strategy: str = "holistic",
    preset: Optional[str] = None,
    step_scale: Optional[float] = None,
    cma_diagonal: bool = False,
    cma_elitist: bool = False,
    cma_popsize: Optional[int] = None,
    energy: Optional[Union[Dict[str, Any], _Path]] = None,
    batch: int = 1,
    neural_start: str = "phi",
    neural_pick: str = "last",
    sequence_shape: str = "per-frame",
    marker_placement: str = "model",
    offsets: Optional[_Path] = None,
    dofs: Optional[str] = None,
    device: str = "flex",
    runtime: str = "burn",
    ort_threads: Optional[int] = None,
    progress: Optional[Callable[[int, int], None]] = None,
) -> FitResult:
    """``lfit fit``: the same fitters, settings and results, as arrays."""
