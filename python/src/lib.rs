//! The Python package `lfit` (`import lfit`): body models, energies, fitters and datasets of the
//! lfit library as numpy arrays. A thin layer: every function calls the library's own entry
//! point (`lfit::api`) and only converts arguments and results; bad input is an
//! `lfit.LfitError` (a `ValueError`) with the one-line message the CLI prints.

mod convert;
mod dataset;
mod energy;
mod fit;
mod model;

use pyo3::prelude::*;

#[pymodule]
fn _lfit(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("LfitError", m.py().get_type::<convert::LfitError>())?;
    m.add("HAS_NEURAL", lfit::api::HAS_NEURAL)?;
    m.add("SHIPPED_MODELS", model::SHIPPED.to_vec())?;
    m.add_class::<model::Model>()?;
    m.add_class::<dataset::Dataset>()?;
    m.add_class::<dataset::Motion>()?;
    m.add_class::<energy::Energy>()?;
    m.add_class::<fit::FitResult>()?;
    m.add_function(wrap_pyfunction!(dataset::load_dataset, m)?)?;
    m.add_function(wrap_pyfunction!(dataset::synth, m)?)?;
    m.add_function(wrap_pyfunction!(dataset::import_c3d, m)?)?;
    m.add_function(wrap_pyfunction!(dataset::import_trc, m)?)?;
    m.add_function(wrap_pyfunction!(dataset::import_keypoints, m)?)?;
    m.add_function(wrap_pyfunction!(dataset::read_cameras, m)?)?;
    m.add_function(wrap_pyfunction!(dataset::import_bvh, m)?)?;
    m.add_function(wrap_pyfunction!(dataset::motion_prior, m)?)?;
    m.add_function(wrap_pyfunction!(fit::fit, m)?)?;
    m.add_function(wrap_pyfunction!(fit::calibrate, m)?)?;
    Ok(())
}
