//! Between Python and the library: errors as `lfit.LfitError` (a `ValueError`) carrying the
//! CLI's one-line message, numpy arrays in (checked for dtype, shape and finite values before
//! any work) and out, JSON values as Python objects.

use numpy::{PyArray1, PyArrayDyn, PyArrayMethods, PyUntypedArrayMethods};
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyList};
use serde_json::Value;

pyo3::create_exception!(
    lfit,
    LfitError,
    PyValueError,
    "Bad input or a failed command: the one-line message the `lfit` CLI prints."
);

/// A library error as `LfitError` with the CLI's one line.
pub fn err(e: anyhow::Error) -> PyErr {
    LfitError::new_err(lfit::api::error_line(&e))
}

/// An `LfitError` with `message`.
pub fn bad(message: impl Into<String>) -> PyErr {
    LfitError::new_err(message.into())
}

/// `Result<T, anyhow::Error>` → `PyResult<T>`.
pub trait OrPy<T> {
    fn py_err(self) -> PyResult<T>;
}

impl<T> OrPy<T> for anyhow::Result<T> {
    fn py_err(self) -> PyResult<T> {
        self.map_err(err)
    }
}

/// A real-valued array read from Python: its shape and its values (row-major, float64).
pub struct Floats {
    pub shape: Vec<usize>,
    pub data: Vec<f64>,
}

impl Floats {
    /// Checks that every value is finite; the error names `what` and the first bad index.
    pub fn finite(self, what: &str) -> PyResult<Self> {
        if let Some(i) = self.data.iter().position(|v| !v.is_finite()) {
            let index = unravel(i, &self.shape);
            return Err(bad(format!(
                "{what}{index} is not a finite number ({})",
                self.data[i]
            )));
        }
        Ok(self)
    }

    /// Rows of a 1-D (one row) or 2-D array of `width` columns, and whether it was 1-D.
    pub fn rows(&self, width: usize, what: &str) -> PyResult<(Vec<&[f64]>, bool)> {
        match self.shape.as_slice() {
            [n] if *n == width => Ok((vec![&self.data[..]], true)),
            [_, n] if *n == width && width > 0 => Ok((self.data.chunks(width).collect(), false)),
            [_, 0] if width == 0 => Ok((Vec::new(), false)),
            _ => Err(bad(format!(
                "{what} has shape {}, expected ({width},) or (N, {width})",
                shape_text(&self.shape)
            ))),
        }
    }
}

fn unravel(mut i: usize, shape: &[usize]) -> String {
    if shape.len() <= 1 {
        return format!("[{i}]");
    }
    let mut index = vec![0; shape.len()];
    for (k, &n) in shape.iter().enumerate().rev() {
        let n = n.max(1);
        index[k] = i % n;
        i /= n;
    }
    format!(
        "[{}]",
        index
            .iter()
            .map(usize::to_string)
            .collect::<Vec<_>>()
            .join(", ")
    )
}

/// `(a, b)` as numpy prints a shape.
pub fn shape_text(shape: &[usize]) -> String {
    match shape {
        [n] => format!("({n},)"),
        _ => format!(
            "({})",
            shape
                .iter()
                .map(usize::to_string)
                .collect::<Vec<_>>()
                .join(", ")
        ),
    }
}

/// Reads a real-valued array (float or integer numpy array, or nested sequences of numbers).
/// Booleans, complex numbers, strings and objects are refused with a one-line `LfitError`
/// naming `what` and the dtype.
pub fn floats(obj: &Bound<'_, PyAny>, what: &str) -> PyResult<Floats> {
    // Fast path: a float64 ndarray, no conversion.
    if let Ok(a) = obj.cast::<PyArrayDyn<f64>>() {
        let a = a.readonly();
        let shape = a.shape().to_vec();
        let data = match a.as_slice() {
            Ok(s) => s.to_vec(),
            Err(_) => a.as_array().iter().copied().collect(),
        };
        return Ok(Floats { shape, data });
    }
    let py = obj.py();
    let np = py.import("numpy")?;
    let arr = np.call_method1("asarray", (obj,)).map_err(|e| {
        bad(format!(
            "{what} is not an array of numbers ({})",
            e.value(py)
        ))
    })?;
    let dtype = arr.getattr("dtype")?;
    let kind: String = dtype.getattr("kind")?.extract()?;
    if !matches!(kind.as_str(), "f" | "i" | "u") {
        return Err(bad(format!(
            "{what} has dtype {}, expected real numbers (float64, or another float or integer type)",
            dtype.str()?
        )));
    }
    let arr = arr.call_method1("astype", ("float64",))?;
    let arr = arr
        .cast_into::<PyArrayDyn<f64>>()
        .map_err(|e| bad(format!("{what}: {e}")))?;
    let a = arr.readonly();
    let shape = a.shape().to_vec();
    let data = match a.as_slice() {
        Ok(s) => s.to_vec(),
        Err(_) => a.as_array().iter().copied().collect(),
    };
    Ok(Floats { shape, data })
}

/// Reads a boolean array (bool dtype, or 0/1 integers) with its shape.
pub fn bools(obj: &Bound<'_, PyAny>, what: &str) -> PyResult<(Vec<usize>, Vec<bool>)> {
    let py = obj.py();
    let np = py.import("numpy")?;
    let arr = np
        .call_method1("asarray", (obj,))
        .map_err(|e| bad(format!("{what} is not an array ({})", e.value(py))))?;
    let dtype = arr.getattr("dtype")?;
    let kind: String = dtype.getattr("kind")?.extract()?;
    if kind != "b" {
        let f = floats(&arr, what)?;
        if let Some(i) = f.data.iter().position(|&v| v != 0.0 && v != 1.0) {
            return Err(bad(format!(
                "{what}{} is {}, expected booleans (or 0/1)",
                unravel(i, &f.shape),
                f.data[i]
            )));
        }
        return Ok((f.shape, f.data.iter().map(|&v| v == 1.0).collect()));
    }
    let arr = arr.call_method1("astype", ("float64",))?;
    let f = floats(&arr, what)?;
    Ok((f.shape, f.data.iter().map(|&v| v != 0.0).collect()))
}

/// A 1-D float64 array.
pub fn array1<'py>(py: Python<'py>, v: Vec<f64>) -> Bound<'py, PyArray1<f64>> {
    PyArray1::from_vec(py, v)
}

/// A float64 array of `shape` from row-major `v` (`v.len()` must be the product of `shape`).
pub fn array_nd<'py>(py: Python<'py>, v: Vec<f64>, shape: &[usize]) -> PyResult<Bound<'py, PyAny>> {
    Ok(PyArray1::from_vec(py, v)
        .reshape(shape.to_vec())?
        .into_any())
}

/// A JSON value as Python objects (dicts, lists, floats, ints, strings, None).
pub fn json_to_py<'py>(py: Python<'py>, v: &Value) -> PyResult<Bound<'py, PyAny>> {
    Ok(match v {
        Value::Null => py.None().into_bound(py),
        Value::Bool(b) => (*b).into_pyobject(py)?.to_owned().into_any(),
        Value::Number(n) => match (n.as_i64(), n.as_u64(), n.as_f64()) {
            (Some(i), _, _) => i.into_pyobject(py)?.into_any(),
            (None, Some(u), _) => u.into_pyobject(py)?.into_any(),
            (_, _, f) => f.unwrap_or(f64::NAN).into_pyobject(py)?.into_any(),
        },
        Value::String(s) => s.into_pyobject(py)?.into_any(),
        Value::Array(items) => {
            let list = PyList::empty(py);
            for item in items {
                list.append(json_to_py(py, item)?)?;
            }
            list.into_any()
        }
        Value::Object(map) => {
            let dict = PyDict::new(py);
            for (k, item) in map {
                dict.set_item(k, json_to_py(py, item)?)?;
            }
            dict.into_any()
        }
    })
}

/// A Python object (dict, list, number, string) as JSON, through `json.dumps`; `what` names it
/// in the error.
pub fn py_to_json(obj: &Bound<'_, PyAny>, what: &str) -> PyResult<Value> {
    let py = obj.py();
    let text: String = py
        .import("json")?
        .call_method1("dumps", (obj,))
        .map_err(|e| bad(format!("{what} is not JSON data ({})", e.value(py))))?
        .extract()?;
    serde_json::from_str(&text).map_err(|e| bad(format!("{what}: {e}")))
}

/// Runs `work` with the GIL released; `work` gets a check that raises a pending Ctrl-C
/// (`KeyboardInterrupt`) as an error, to call between units of work.
pub fn without_gil<T: Send>(
    py: Python<'_>,
    work: impl FnOnce(&dyn Fn() -> anyhow::Result<()>) -> anyhow::Result<T> + Send,
) -> PyResult<T> {
    let interrupted: std::sync::Mutex<Option<PyErr>> = std::sync::Mutex::new(None);
    let check = || -> anyhow::Result<()> {
        let signal = Python::attach(|py| py.check_signals());
        match signal {
            Ok(()) => Ok(()),
            Err(e) => {
                if let Ok(mut slot) = interrupted.lock() {
                    *slot = Some(e);
                }
                anyhow::bail!("interrupted")
            }
        }
    };
    let result = py.detach(|| work(&check));
    let pending = interrupted.into_inner().ok().flatten();
    match (result, pending) {
        (_, Some(e)) => Err(e),
        (Ok(v), None) => Ok(v),
        (Err(e), None) => Err(err(e)),
    }
}

/// Runs `work` on a worker thread while this thread, which holds the GIL only between 20 ms
/// sleeps, watches for Ctrl-C. On one it sets the flag `work` gets (work checks it between units
/// of work and stops), waits for it and raises `KeyboardInterrupt`. For work that runs on rayon's
/// threads: Python runs signal handlers only on its main thread, so a check from a worker would
/// never see the interrupt.
pub fn cancellable<T: Send>(
    py: Python<'_>,
    work: impl FnOnce(&std::sync::atomic::AtomicBool) -> anyhow::Result<T> + Send,
) -> PyResult<T> {
    use std::sync::atomic::{AtomicBool, Ordering};
    let cancel = AtomicBool::new(false);
    let mut interrupted = None;
    let joined = std::thread::scope(|scope| {
        let handle = scope.spawn(|| work(&cancel));
        while !handle.is_finished() {
            py.detach(|| std::thread::sleep(std::time::Duration::from_millis(20)));
            if let Err(e) = py.check_signals() {
                interrupted = Some(e);
                cancel.store(true, Ordering::Relaxed);
                break;
            }
        }
        py.detach(|| handle.join())
    });
    match (joined, interrupted) {
        (_, Some(e)) => Err(e),
        (Ok(Ok(v)), None) => Ok(v),
        (Ok(Err(e)), None) => Err(err(e)),
        (Err(_), None) => Err(bad("internal error: the worker thread panicked")),
    }
}
