//! `handcap._core`: handcap's modelling core as a CPython extension. The Python package
//! (`handcap/`) wraps it in a scikit-learn estimator; this module only converts arrays and
//! errors and releases the GIL around the work.
//!
//! Arrays come in as float64 (the Python side converts; any layout, read-only accepted) and go
//! out as new C-ordered arrays. Errors of the data or the parameters raise `ValueError` with
//! the core's words (the same the command line prints); file errors raise `OSError`.

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};

use numpy::ndarray::{Array1, Array2, Array3, ArrayView1, ArrayView2};
use numpy::{IntoPyArray, PyArray1, PyArray2, PyArray3, PyReadonlyArray1, PyReadonlyArray2};
use pyo3::exceptions::{PyOSError, PyRuntimeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyTuple;

use handcap_core::data::{self, Columns, Dataset};
use handcap_core::model::file::{ModelFile, ModelFileError};
use handcap_core::model::history::{HistoryChoice, Series};
use handcap_core::model::inverse::{self, InverseOptions};
use handcap_core::model::msvr::{self, Loss, MsvrParams, MIN_FIT_ROWS};
use handcap_core::model::{Differentiable, Predict, StoredModel};
use handcap_core::provenance::Provenance;
use handcap_core::select::family::{Family, FamilyChoice};
use handcap_core::select::folds::FoldsBy;
use handcap_core::select::tune::{BasisChoice, Pinned};
use handcap_core::select::{self, Plan, Selection, Table};

/// A core message in Python's words: its parameters are named `field=value` already, but
/// Python spells the booleans True and False.
fn value_error(e: impl std::fmt::Display) -> PyErr {
    let message = e.to_string();
    PyValueError::new_err(
        message
            .replace("=true", "=True")
            .replace("=false", "=False"),
    )
}

/// Set when Python asks the work running to stop (Ctrl-C): the search ends, and nothing
/// starts after it.
static STOP: AtomicBool = AtomicBool::new(false);

/// Runs `work` on a thread of its own without the GIL, while this thread checks Python's
/// signals: Ctrl-C stops the work ([`STOP`] and the core's stop) and raises
/// `KeyboardInterrupt` once it has ended. A panic in the work (a defect: the core validates
/// what it is given) raises `RuntimeError` with its message instead of `PanicException`,
/// which `except Exception` does not catch.
fn detached<T: Send>(
    py: Python<'_>,
    work: impl FnOnce() -> Result<T, String> + Send,
) -> PyResult<T> {
    STOP.store(false, Ordering::SeqCst);
    // Set, and the waiting thread woken, when the work ends: it returns at once, not at its
    // next check of the signals.
    let finished = (std::sync::Mutex::new(false), std::sync::Condvar::new());
    let (outcome, interrupted) = std::thread::scope(|scope| {
        let worker = scope.spawn(|| {
            let outcome = std::panic::catch_unwind(std::panic::AssertUnwindSafe(work));
            *finished.0.lock().expect("the flag") = true;
            finished.1.notify_all();
            outcome
        });
        let mut interrupted = None;
        loop {
            let done = py.detach(|| {
                let flag = finished.0.lock().expect("the flag");
                let tick = std::time::Duration::from_millis(20);
                *finished
                    .1
                    .wait_timeout_while(flag, tick, |done| !*done)
                    .expect("the flag")
                    .0
            });
            if done {
                break;
            }
            if interrupted.is_none() {
                if let Err(e) = py.check_signals() {
                    STOP.store(true, Ordering::SeqCst);
                    handcap_core::control::request_stop();
                    interrupted = Some(e);
                }
            }
        }
        (
            worker.join().expect("the work's panic is caught"),
            interrupted,
        )
    });
    if let Some(e) = interrupted {
        return Err(e);
    }
    match outcome {
        Ok(result) => result.map_err(value_error),
        Err(panic) => {
            let what = panic
                .downcast_ref::<String>()
                .map(String::as_str)
                .or_else(|| panic.downcast_ref::<&str>().copied())
                .unwrap_or("no message");
            Err(PyRuntimeError::new_err(format!(
                "handcap failed inside ({what}); please report it with the data that caused it"
            )))
        }
    }
}

/// Kernel evaluations (rows × centres) a prediction runs on the calling thread: about a
/// millisecond at most, where a thread of its own costs tens of microseconds.
const INLINE_WORK: usize = 100_000;

/// `Err` when Python asked to stop ([`STOP`]): work after a stopped search does not start.
fn not_stopped() -> Result<(), String> {
    if STOP.load(Ordering::SeqCst) {
        Err("interrupted".into())
    } else {
        Ok(())
    }
}

fn file_error(e: ModelFileError) -> PyErr {
    match e {
        ModelFileError::Invalid { .. }
        | ModelFileError::Version { .. }
        | ModelFileError::Family { .. } => value_error(e),
        _ => PyOSError::new_err(e.to_string()),
    }
}

/// `x` as a float64 array of `ndim` dimensions (any numeric dtype, layout or writeability).
fn float_array<'py>(x: &Bound<'py, PyAny>, ndim: usize, what: &str) -> PyResult<Bound<'py, PyAny>> {
    let py = x.py();
    let numpy = py.import("numpy")?;
    let float64 = numpy.getattr("float64")?;
    let a = numpy.call_method1("asarray", (x, float64)).map_err(|e| {
        value_error(format!(
            "{what}: {e}; give numbers (number text labels first)"
        ))
    })?;
    let found: usize = a.getattr("ndim")?.extract()?;
    if found != ndim {
        return Err(value_error(format!(
            "{what} must be a {ndim}-D array; got {found} dimensions"
        )));
    }
    Ok(a)
}

fn array2<'py>(x: &Bound<'py, PyAny>, what: &str) -> PyResult<PyReadonlyArray2<'py, f64>> {
    float_array(x, 2, what)?.extract()
}

fn array1<'py>(x: &Bound<'py, PyAny>, what: &str) -> PyResult<PyReadonlyArray1<'py, f64>> {
    float_array(x, 1, what)?.extract()
}

/// `x` has one column per name, or a `ValueError` says what the model takes.
fn check_width(x: ArrayView2<f64>, names: &[String]) -> PyResult<()> {
    if x.ncols() == names.len() {
        return Ok(());
    }
    Err(value_error(format!(
        "X has {} features, but the model takes {} ({})",
        x.ncols(),
        names.len(),
        names.join(",")
    )))
}

/// Every value of `x` (one column per name) finite, or a `ValueError` names the first that is
/// not (a NaN row was predicted and blamed on the model's coefficients, an infinite one given
/// the bias as a tip).
fn check_finite(x: ArrayView2<f64>, names: &[String]) -> PyResult<()> {
    match x.indexed_iter().find(|(_, v)| !v.is_finite()) {
        None => Ok(()),
        Some(((row, j), v)) => Err(value_error(format!(
            "X row {row}, column {j} ({}): {v} is not a finite number; remove or repair the row",
            names[j]
        ))),
    }
}

/// Every value of `values` (the `what` argument) finite, or a `ValueError` names the first
/// that is not.
fn check_finite_1d(values: &[f64], what: &str) -> PyResult<()> {
    match values.iter().position(|v| !v.is_finite()) {
        None => Ok(()),
        Some(row) => Err(value_error(format!(
            "{what} row {row}: {} is not a finite number; give each row's",
            values[row]
        ))),
    }
}

fn columns(names: &[String], x: ArrayView2<f64>) -> Columns {
    Columns::new(names.to_vec(), x.iter().copied().collect())
}

fn array(c: &Columns) -> Array2<f64> {
    Array2::from_shape_vec((c.rows(), c.width()), c.values.clone()).expect("rows × width")
}

/// What `fit` is asked for, owned so the work can run without the GIL.
struct FitRequest {
    table: Table,
    plan: Plan,
}

/// The selection `handcap model` makes on a file ([`select::select`]), on arrays.
fn fit_request(r: FitRequest) -> Result<ModelFile, String> {
    let selected =
        select::select(&r.table, None, &r.plan, &(), &STOP).map_err(|e| rows(e.to_string()))?;
    not_stopped()?;
    let provenance = Provenance::new(
        vec!["handcap.MSVRRegressor.fit".into()],
        r.plan.selection.seed(),
    );
    Ok(selected.into_file(provenance).0)
}

/// A core message about rows from memory: "python line N: …" (the table's lines are the rows
/// counted from 1) as "row N-1: …", and "python: …" without its prefix.
fn rows(message: String) -> String {
    if let Some(rest) = message.strip_prefix("python line ") {
        let (line, tail) = rest.split_once(':').unwrap_or((rest, ""));
        if let Ok(line) = line.parse::<u64>() {
            return format!("row {}:{tail}", line.saturating_sub(1));
        }
    }
    message
        .strip_prefix("python: ")
        .map_or(message.clone(), str::to_string)
}

/// Fits MSVR to `x` (n × d) and `y` (n × q) as `handcap model` does: hyper-parameters left
/// `None` are chosen by the search; `groups` (one label per row) keeps runs whole in the
/// folds, `time` (seconds, increasing within each group) lets the model see its inputs'
/// history (`history`: auto, none, ema:τ1,τ2…, lags:k); `intervals` calibrates the conformal
/// intervals when the search made no held-out predictions (k more fits). Returns the model.
#[pyfunction]
#[pyo3(signature = (x, y, *, input_names, output_names, model="msvr", c=None, epsilon=None,
    sigma=None, loss="robust", basis="auto", budget=None, folds=5, groups=None, time=None, weights=None, history="auto",
    seed=2020, tol=msvr::DEFAULT_TOL, max_iter=msvr::DEFAULT_MAX_ITER, intervals=false))]
#[allow(clippy::too_many_arguments)]
fn fit(
    py: Python<'_>,
    x: &Bound<'_, PyAny>,
    y: &Bound<'_, PyAny>,
    input_names: Vec<String>,
    output_names: Vec<String>,
    model: &str,
    c: Option<f64>,
    epsilon: Option<f64>,
    sigma: Option<f64>,
    loss: &str,
    basis: &str,
    budget: Option<usize>,
    folds: usize,
    groups: Option<&Bound<'_, PyAny>>,
    time: Option<&Bound<'_, PyAny>>,
    weights: Option<&Bound<'_, PyAny>>,
    history: &str,
    seed: u64,
    tol: f64,
    max_iter: usize,
    intervals: bool,
) -> PyResult<Model> {
    let (x, y) = (array2(x, "X")?, array2(y, "y")?);
    let groups = groups.map(|g| array1(g, "groups")).transpose()?;
    let time = time.map(|t| array1(t, "time")).transpose()?;
    let weights = weights.map(|w| array1(w, "sample_weight")).transpose()?;
    let (x, y) = (x.as_array(), y.as_array());
    if x.nrows() != y.nrows() {
        return Err(value_error(format!(
            "X has {} rows but y has {}",
            x.nrows(),
            y.nrows()
        )));
    }
    if input_names.len() != x.ncols() || output_names.len() != y.ncols() {
        return Err(value_error("one name per column of X and of y"));
    }
    let family: FamilyChoice = model
        .parse()
        .map_err(|e: String| value_error(format!("model {e}")))?;
    let loss = match loss {
        "robust" => Loss::Robust,
        "quadratic" => Loss::Quadratic,
        other => {
            return Err(value_error(format!(
                "loss `{other}`: give \"robust\" or \"quadratic\""
            )))
        }
    };
    let basis: BasisChoice = basis
        .parse()
        .map_err(|e: String| value_error(format!("basis `{basis}`: {e}")))?;
    let history: HistoryChoice = history
        .parse()
        .map_err(|e: String| value_error(format!("history `{history}`: {e}")))?;
    let per_row = |values: Option<PyReadonlyArray1<f64>>, what: &str| {
        let values = values.map(|v| v.as_array().to_vec());
        match values {
            Some(v) if v.len() != x.nrows() => Err(value_error(format!(
                "{what} has {} values; give one per row of X ({})",
                v.len(),
                x.nrows()
            ))),
            v => Ok(v),
        }
    };
    let groups = per_row(groups, "groups")?;
    let time = per_row(time, "time")?;
    let weights = per_row(weights, "sample_weight")?;
    if let Some(w) = &weights {
        if let Some(row) = data::refused_weight(w) {
            return Err(value_error(format!(
                "row {row}: sample_weight {}; give every row a finite weight above 0",
                w[row]
            )));
        }
    }
    let series = time.map(|time| Series {
        time,
        group: groups.clone(),
    });
    let table = Table {
        data: Dataset {
            source: PathBuf::from("python"),
            inputs: columns(&input_names, x),
            outputs: columns(&output_names, y),
            weights,
        },
        series,
        lines: (1..=x.nrows() as u64).collect(),
        context: None,
        fold_columns: groups
            .clone()
            .map(|g| vec![("groups".to_string(), g)])
            .unwrap_or_default(),
    };
    let folds_by = match groups {
        Some(_) => FoldsBy::Column("groups".into()),
        None => FoldsBy::Auto,
    };
    let pinned = Pinned {
        c,
        epsilon,
        sigma,
        loss: None,
    };
    let searched = family.searches(&pinned);
    let selection = if searched {
        Selection::aco_r(seed, budget, folds, folds_by)
    } else {
        Selection::Fixed { folds, folds_by }
    };
    let params = MsvrParams::new(
        c.unwrap_or(1.0),
        epsilon.unwrap_or(0.1),
        sigma.unwrap_or(1.0),
    )
    .loss(loss)
    .tol(tol)
    .max_iter(max_iter);
    let with_time = table.series.is_some();
    let request = FitRequest {
        plan: Plan {
            family,
            params,
            selection,
            pinned,
            basis,
            history,
            time: with_time.then(|| "time".to_string()),
            group: (with_time && table.fold_columns.len() == 1).then(|| "groups".to_string()),
            max_rows: None,
            intervals,
        },
        table,
    };
    let file = detached(py, || fit_request(request))?;
    Ok(Model { file })
}

/// A fitted model: from `fit`, or a model file any `handcap model` run wrote.
#[pyclass(module = "handcap._core", frozen)]
struct Model {
    file: ModelFile,
}

impl Model {
    fn msvr(&self) -> &msvr::Msvr {
        match &self.file.model {
            StoredModel::Msvr(m) => m,
        }
    }

    /// The inputs a caller gives: the present inputs (a history model's features are built).
    fn given_inputs(&self) -> Vec<String> {
        self.file.steady_state().inputs().to_vec()
    }
}

#[pymethods]
impl Model {
    /// Reads a model file written by `handcap model` or `Model.save`.
    #[staticmethod]
    fn load(path: PathBuf) -> PyResult<Model> {
        Ok(Model {
            file: ModelFile::load(&path).map_err(file_error)?,
        })
    }

    /// The model from the JSON text of a model file.
    #[staticmethod]
    fn from_json(text: &str) -> PyResult<Model> {
        let file: ModelFile = serde_json::from_str(text).map_err(value_error)?;
        file.validate()
            .map_err(|e| value_error(format!("not a handcap model ({e})")))?;
        Ok(Model { file })
    }

    /// The model file's JSON text.
    fn to_json(&self) -> String {
        serde_json::to_string_pretty(&self.file).expect("a model serialises")
    }

    /// Writes the model file (atomically); `handcap predict` and `inverse` read it.
    fn save(&self, path: PathBuf) -> PyResult<()> {
        self.file.save(&path).map_err(file_error)
    }

    fn __reduce__<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyTuple>> {
        let rebuild = py
            .import("handcap._core")?
            .getattr("Model")?
            .getattr("from_json")?;
        (rebuild, (self.to_json(),)).into_pyobject(py)
    }

    /// Predicts `x` (rows × inputs). A model with input history needs each row's `time` (and
    /// `groups` when it was fitted with groups), rows in time order within each group.
    #[pyo3(signature = (x, time=None, groups=None))]
    fn predict<'py>(
        &self,
        py: Python<'py>,
        x: &Bound<'py, PyAny>,
        time: Option<&Bound<'py, PyAny>>,
        groups: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Bound<'py, PyArray2<f64>>> {
        let (given, series) = self.given(x, time, groups)?;
        let rows = given.rows();
        let predictor = self.file.model.predictor();
        let features = self.features(given, &series).map_err(value_error)?;
        // Said as `handcap predict` says it on stderr.
        if let Some(warning) = predictor.range_warning(&features) {
            let message = std::ffi::CString::new(warning).expect("no NUL in a message");
            let category = py.get_type::<pyo3::exceptions::PyUserWarning>();
            PyErr::warn(py, category.as_any(), &message, 1)?;
        }
        let work = || predictor.predict(&features).map_err(|e| e.to_string());
        // A few rows (a controller's step) take microseconds: run here, without the thread
        // that lets Ctrl-C through a long prediction.
        let predicted = if rows * self.msvr().support_vector_count() <= INLINE_WORK {
            work().map_err(value_error)?
        } else {
            detached(py, work)?
        };
        Ok(array(&predicted).into_pyarray(py))
    }

    /// The conformal interval's radius at `level` around the prediction at each row of `x`
    /// (`time` and `groups` as [`Model::predict`] takes them): wider where the row's inputs
    /// are farther from the training rows than the held-out rows were.
    #[pyo3(signature = (x, level, time=None, groups=None))]
    fn interval_radii<'py>(
        &self,
        py: Python<'py>,
        x: &Bound<'py, PyAny>,
        level: f64,
        time: Option<&Bound<'py, PyAny>>,
        groups: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Bound<'py, PyArray1<f64>>> {
        let (given, series) = self.given(x, time, groups)?;
        let features = self.features(given, &series).map_err(value_error)?;
        let radii = self
            .file
            .interval_radii(level, &features)
            .map_err(value_error)?;
        Ok(radii.radii.into_pyarray(py))
    }

    /// ∂outputs/∂inputs at each row of `x` (rows × inputs): `(rows, outputs, inputs)`. A
    /// history model's is its steady state's (every filter settled at the row's inputs), the
    /// map the inverse and a feed-forward controller use; exact, from the kernel's derivative.
    fn jacobian<'py>(
        &self,
        py: Python<'py>,
        x: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyArray3<f64>>> {
        let steady = self.file.steady_state();
        let (d, q) = (steady.inputs().len(), steady.outputs().len());
        let x = array2(x, "X")?;
        let x = x.as_array();
        check_width(x, steady.inputs())?;
        check_finite(x, steady.inputs())?;
        let n = x.nrows();
        let values: Vec<f64> = x.iter().copied().collect();
        let work = || Ok(steady.jacobians(&values));
        let jac = if n * self.msvr().support_vector_count() <= INLINE_WORK {
            work().map_err(|e: String| value_error(e))?
        } else {
            detached(py, work)?
        };
        Ok(Array3::from_shape_vec((n, q, d), jac)
            .expect("n × q × d")
            .into_pyarray(py))
    }

    /// The inputs that put the model's outputs at each row of `targets`, within the training
    /// range and 0-`max_kpa` (250 when not given) for `_kpa` inputs (as `handcap inverse`); a
    /// history model plans on its steady state. Returns (inputs, achieved, error, reached).
    #[pyo3(signature = (targets, max_kpa=None, reach=0.01))]
    #[allow(clippy::type_complexity)]
    fn inverse<'py>(
        &self,
        py: Python<'py>,
        targets: &Bound<'py, PyAny>,
        max_kpa: Option<f64>,
        reach: f64,
    ) -> PyResult<(
        Bound<'py, PyArray2<f64>>,
        Bound<'py, PyArray2<f64>>,
        Bound<'py, PyArray1<f64>>,
        Bound<'py, PyArray1<bool>>,
    )> {
        let steady = self.file.steady_state();
        // A cap given for a model with no pressure to cap was ignored, unsaid.
        if max_kpa.is_some() && !steady.inputs().iter().any(|n| n.ends_with("_kpa")) {
            return Err(value_error(format!(
                "max_kpa caps the inputs named *_kpa (pressures); this model's inputs are {}, held within their training range: leave max_kpa out",
                steady.inputs().join(", ")
            )));
        }
        let max_kpa = max_kpa.unwrap_or(handcap_core::hand::DEFAULT_MAX_KPA);
        if !(max_kpa > 0.0 && max_kpa <= handcap_core::hand::MAX_PRESSURE_KPA) {
            return Err(value_error(format!(
                "max_kpa {max_kpa} must lie in (0, {}]: the regulator caps the supply",
                handcap_core::hand::MAX_PRESSURE_KPA
            )));
        }
        if reach.is_nan() || reach <= 0.0 {
            return Err(value_error("reach must be positive"));
        }
        let q = steady.outputs().len();
        let targets = array2(targets, "targets")?;
        let targets = targets.as_array();
        if targets.ncols() != q {
            return Err(value_error(format!(
                "targets have {} columns, but the model predicts {q} ({})",
                targets.ncols(),
                steady.outputs().join(",")
            )));
        }
        let rows: Vec<Vec<f64>> = targets.rows().into_iter().map(|r| r.to_vec()).collect();
        if let Some(k) = rows.iter().position(|r| r.iter().any(|v| !v.is_finite())) {
            return Err(value_error(format!(
                "targets row {k}: {:?} is not a position (NaN or infinite); give finite numbers",
                rows[k]
            )));
        }
        let solutions = detached(py, || {
            let cap = |name: &str| name.ends_with("_kpa").then_some((0.0, max_kpa));
            let options = InverseOptions {
                reach,
                ..InverseOptions::within_training_range(&steady, cap)
            };
            rows.iter()
                .map(|t| inverse::solve(&steady, t, &options))
                .collect::<Result<Vec<_>, _>>()
                .map_err(|e| e.to_string())
        })?;
        let d = steady.inputs().len();
        let n = solutions.len();
        let inputs = Array2::from_shape_vec(
            (n, d),
            solutions.iter().flat_map(|s| s.inputs.clone()).collect(),
        )
        .expect("n × d");
        let achieved = Array2::from_shape_vec(
            (n, q),
            solutions.iter().flat_map(|s| s.achieved.clone()).collect(),
        )
        .expect("n × q");
        let error: Array1<f64> = solutions.iter().map(|s| s.error).collect();
        let reached: Array1<bool> = solutions.iter().map(|s| s.reached).collect();
        Ok((
            inputs.into_pyarray(py),
            achieved.into_pyarray(py),
            error.into_pyarray(py),
            reached.into_pyarray(py),
        ))
    }

    /// The input columns a caller gives, in order.
    #[getter]
    fn inputs(&self) -> Vec<String> {
        self.given_inputs()
    }

    /// The columns the kernel sees (with input history: the inputs and their features).
    #[getter]
    fn feature_names(&self) -> Vec<String> {
        self.file.model.predictor().inputs().to_vec()
    }

    #[getter]
    fn outputs(&self) -> Vec<String> {
        self.file.model.predictor().outputs().to_vec()
    }

    /// The family the model is: "msvr" or "krr" (kernel ridge: MSVR with ε = 0 and the
    /// squared loss).
    #[getter]
    fn family(&self) -> String {
        self.file.family().to_string()
    }

    /// (C, ε, σ) of the fit.
    #[getter]
    fn hyper(&self) -> (f64, f64, f64) {
        let p = self.msvr().params;
        (p.c, p.epsilon, p.sigma)
    }

    /// The kernel's centres in scaled inputs (support vectors; a reduced basis's centres).
    #[getter]
    fn support_vectors<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        per_centre(
            py,
            self.msvr().support_vectors(),
            self.msvr().support_vector_count(),
        )
    }

    /// The centres' coefficients β (n_sv × q).
    #[getter]
    fn dual_coef<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray2<f64>> {
        per_centre(
            py,
            self.msvr().coefficients(),
            self.msvr().support_vector_count(),
        )
    }

    #[getter]
    fn intercept<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        ArrayView1::from(&self.msvr().bias[..])
            .to_owned()
            .into_pyarray(py)
    }

    /// The search's summary, the basis decision and the history decision as JSON (`None`
    /// where there was none).
    #[getter]
    fn search(&self) -> Option<String> {
        self.file
            .search
            .as_ref()
            .map(|s| serde_json::to_string(s).expect("serialises"))
    }

    /// Iterations of the final fit's solver.
    #[getter]
    fn iterations(&self) -> usize {
        self.file.model.diagnostics().iterations
    }

    #[getter]
    fn basis(&self) -> String {
        self.msvr().params.basis.to_string()
    }

    #[getter]
    fn history(&self) -> Option<String> {
        self.file
            .history
            .as_ref()
            .map(|h| serde_json::to_string(h).expect("serialises"))
    }

    /// The conformal prediction interval's radius at `level` (output units): the truth lies
    /// within it of the prediction that share of the time, over inputs like the held-out ones.
    /// Raises ValueError for a level outside (0, 1), too few held-out rows for it, or a model
    /// fitted without held-out rows (every hyper-parameter given).
    fn interval_radius(&self, level: f64) -> PyResult<f64> {
        self.file.interval_radius(level).map_err(value_error)
    }
}

impl Model {
    /// The inputs of `x` as the model's columns, with each row's time and group when the
    /// model sees its inputs' history.
    fn given(
        &self,
        x: &Bound<'_, PyAny>,
        time: Option<&Bound<'_, PyAny>>,
        groups: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<(Columns, Option<Series>)> {
        let names = self.given_inputs();
        let x = array2(x, "X")?;
        let time = time.map(|t| array1(t, "time")).transpose()?;
        let groups = groups.map(|g| array1(g, "groups")).transpose()?;
        let x = x.as_array();
        check_width(x, &names)?;
        check_finite(x, &names)?;
        let given = columns(&names, x);
        let series = match (self.file.history(), time) {
            (None, _) => None,
            (Some(h), None) => {
                return Err(value_error(format!(
                    "the model sees its inputs' history: give time= (its `{}` column){}",
                    h.time,
                    h.group
                        .as_ref()
                        .map_or_else(String::new, |g| format!(" and groups= (its `{g}`)"))
                )))
            }
            (Some(h), Some(t)) => {
                if h.group.is_some() && groups.is_none() {
                    return Err(value_error(format!(
                        "the model's history restarts in each `{}`: give groups=",
                        h.group.as_deref().unwrap_or_default()
                    )));
                }
                let series = Series {
                    time: t.as_array().to_vec(),
                    group: groups.map(|g| g.as_array().to_vec()),
                };
                check_finite_1d(&series.time, "time")?;
                if let Some(group) = &series.group {
                    check_finite_1d(group, "groups")?;
                }
                Some(series)
            }
        };
        Ok((given, series))
    }

    /// The model's own inputs of `given`: its history's features built along `series`.
    fn features(&self, given: Columns, series: &Option<Series>) -> Result<Columns, String> {
        match (self.file.history(), series) {
            (Some(h), Some(s)) => h.features(&given, s).map_err(|e| e.to_string()),
            _ => Ok(given),
        }
    }
}

/// A row-major block of one row per centre as an array.
fn per_centre<'py>(py: Python<'py>, values: &[f64], centres: usize) -> Bound<'py, PyArray2<f64>> {
    let width = values.len() / centres.max(1);
    ArrayView2::from_shape((centres, width), values)
        .expect("one row per centre")
        .to_owned()
        .into_pyarray(py)
}

#[pymodule]
fn _core(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add_function(wrap_pyfunction!(fit, m)?)?;
    m.add_class::<Model>()?;
    m.add("MIN_FIT_ROWS", MIN_FIT_ROWS)?;
    // Each family's name and the axes of (C, ε, σ) its search moves (the others it holds).
    let families: Vec<(&str, Vec<&str>)> = Family::ALL
        .iter()
        .map(|f| (f.name(), f.axes().to_vec()))
        .collect();
    m.add("FAMILIES", families)?;
    Ok(())
}
