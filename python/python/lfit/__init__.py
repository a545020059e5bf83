"""lfit: learned fitting of skinned 3D body models, from Python.

Body models, per-frame energies (value, gradient, residuals, Jacobian), the fitters of ``lfit
fit`` and the dataset tools of ``lfit synth`` / ``lfit data import`` / ``lfit motion import``,
with numpy arrays in and out. Every function calls the Rust library's own code; bad input raises
:class:`LfitError` (a ``ValueError``) with the one-line message the ``lfit`` command prints.

>>> import lfit
>>> body = lfit.Model.load("makehuman-cmu_mb")
>>> data = lfit.synth("markers", body, frames=10, seed=1)
>>> result = lfit.fit(body, data, method="lm", budget=100)
>>> result.v2v_mm.mean()  # doctest: +SKIP
"""

from ._lfit import (
    HAS_NEURAL,
    SHIPPED_MODELS,
    Dataset,
    Energy,
    FitResult,
    LfitError,
    Model,
    Motion,
    calibrate,
    fit,
    import_bvh,
    import_c3d,
    import_trc,
    import_keypoints,
    load_dataset,
    motion_prior,
    read_cameras,
    synth,
)

__all__ = [
    "HAS_NEURAL",
    "SHIPPED_MODELS",
    "Dataset",
    "Energy",
    "FitResult",
    "LfitError",
    "Model",
    "Motion",
    "calibrate",
    "fit",
    "import_bvh",
    "import_c3d",
    "import_trc",
    "import_keypoints",
    "load_dataset",
    "motion_prior",
    "read_cameras",
    "synth",
]
