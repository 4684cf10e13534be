//! Multi-output support vector regression (MSVR), the paper's model (eqs. 8-12).
//!
//! f(x) = Σᵢ K(x, xᵢ) βᵢ + b with the RBF kernel K(x, x') = exp(−‖x − x'‖² / (2σ²)) on inputs
//! min-max scaled to [0, 1] per column (training min and max, stored in the model), outputs used
//! as they are, so ε is in output units (mm for the micro-hand). Trained by [`irwls`].
//!
//! ```
//! use handcap_core::data::{Columns, Dataset};
//! use handcap_core::model::{msvr::MsvrParams, Predict};
//!
//! let x: Vec<f64> = (0..20).map(|i| i as f64).collect();
//! let y: Vec<f64> = x.iter().map(|v| (v / 4.0).sin()).collect();
//! let data = Dataset {
//!     source: "inline".into(),
//!     inputs: Columns::new(vec!["p".into()], x),
//!     outputs: Columns::new(vec!["z".into()], y),
//!     weights: None,
//! };
//! let model = MsvrParams::new(100.0, 0.001, 0.2).check()?.fit(&data)?;
//! assert!(model.fit.converged);
//! let mut out = [0.0];
//! model.predict_row(&[8.0], &mut out);
//! assert!((out[0] - 2f64.sin()).abs() < 0.01);
//! # Ok::<(), Box<dyn std::error::Error>>(())
//! ```

pub mod basis;
pub mod hyper;
pub mod irwls;
pub mod kernel;
mod params;
pub mod reduced;
pub mod tube;

use faer::{Mat, MatRef};
use serde::{Deserialize, Serialize};

use crate::data::{Columns, DataError};
use crate::model::{Differentiable, Predict};
pub use hyper::{Hyper, InvalidParam, PAPER_TABLE2};
use irwls::{NotPositiveDefinite, StopReason};
pub use params::{MsvrParams, ValidMsvrParams};
pub use tube::{Loss, RowWeights, ROBUST_ZONE};

/// Default relative tolerance on the objective's decrease.
pub const DEFAULT_TOL: f64 = 1e-8;
/// Default iteration cap (fits take 10-40 iterations).
pub const DEFAULT_MAX_ITER: usize = 500;
/// Fewest rows a fit accepts.
pub const MIN_FIT_ROWS: usize = 3;

/// Errors of checking parameters and fitting.
#[derive(Debug, thiserror::Error)]
pub enum MsvrError {
    #[error(transparent)]
    InvalidParam(#[from] InvalidParam),
    #[error(transparent)]
    Data(#[from] DataError),
    #[error(transparent)]
    Solver(#[from] NotPositiveDefinite),
    #[error("the fit was stopped (Ctrl-C, a termination signal, or KeyboardInterrupt) before it converged")]
    Interrupted,
    #[error("the fit with C = {c}, ε = {epsilon}, σ = {sigma} gave non-finite numbers; choose other parameters or rescale the data")]
    NonFinite { c: f64, epsilon: f64, sigma: f64 },
    #[error("{rows} rows with the {basis} basis need about {need_gb:.1} GB, and {available_gb:.1} GB are available; use a reduced basis of fewer centres (basis=auto or basis=M)")]
    TooLarge {
        rows: usize,
        basis: Basis,
        need_gb: f64,
        available_gb: f64,
    },
}

/// Bytes a fit on `rows` rows holds at once. Exact: the n × n kernel, the IRWLS system and
/// its Cholesky factor, and room for a second fit running beside it (cross-validation), about
/// six n × n matrices of f64. Reduced: the features (stored up to [`STORED_FEATURE_BYTES`]), the
/// centres' kernel and factors (a few m × m), and the targets, predictions and residuals of
/// every row (a few n × 8).
pub fn fit_bytes(rows: usize, basis: Basis) -> f64 {
    let n = rows as f64;
    match basis {
        Basis::Exact => 6.0 * 8.0 * n * n,
        Basis::Reduced { centres, .. } => {
            let m = centres.min(rows) as f64;
            (8.0 * n * m).min(STORED_FEATURE_BYTES as f64) + 8.0 * 6.0 * m * m + 8.0 * 48.0 * n
        }
    }
}

/// Refuses a fit that would not fit in memory: [`fit_bytes`] against the memory the system
/// says is available (`MemAvailable` of `/proc/meminfo`; no limit where it cannot be read).
///
/// # Errors
/// [`MsvrError::TooLarge`].
pub fn check_memory(rows: usize, basis: Basis) -> Result<(), MsvrError> {
    let Some(available) = available_bytes() else {
        return Ok(());
    };
    let need = fit_bytes(rows, basis);
    if need > available {
        return Err(MsvrError::TooLarge {
            rows,
            basis,
            need_gb: need / 1e9,
            available_gb: available / 1e9,
        });
    }
    Ok(())
}

/// The memory the system says is available, in bytes (`None` where it cannot be read).
pub fn available_bytes() -> Option<f64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = text.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024.0)
}

/// What either solver leaves: the kernel's centres (scaled inputs) with their coefficients.
struct Expansion {
    centres: Vec<Vec<f64>>,
    coefficients: Vec<Vec<f64>>,
    bias: Vec<f64>,
    objective: f64,
    iterations: usize,
    stop: StopReason,
    basis: Option<BasisFit>,
}

impl Expansion {
    /// Whether its objective, bias and coefficients are all finite numbers.
    fn is_finite(&self) -> bool {
        self.objective.is_finite()
            && self.bias.iter().all(|b| b.is_finite())
            && self.coefficients.iter().flatten().all(|b| b.is_finite())
    }
}

/// Features of a reduced fit are stored when they take at most this many bytes, else computed
/// block by block at every pass.
pub const STORED_FEATURE_BYTES: usize = 1 << 30;

/// The expansion a fit uses.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Basis {
    /// A kernel at every training row: the n × n kernel (the paper's MSVR).
    #[default]
    Exact,
    /// A kernel at up to `centres` centres picked by k-means++ with `seed` ([`basis`]), fitted by
    /// [`reduced`]: O(n m²) time, O(m²) memory.
    Reduced { centres: usize, seed: u64 },
}

impl std::fmt::Display for Basis {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Basis::Exact => f.write_str("exact"),
            Basis::Reduced { centres, .. } => write!(f, "{centres} centres"),
        }
    }
}

/// What a reduced fit did with its basis.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct BasisFit {
    /// Centres asked for.
    pub requested: usize,
    /// Centres k-means++ found (fewer when the rows have fewer distinct points).
    pub chosen: usize,
    /// Centres kept by the pivoted Cholesky at this σ (the model's terms).
    pub kept: usize,
    /// Training rows outside the tube at the optimum.
    pub outside_tube: usize,
}

/// How the fit went.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FitDiagnostics {
    pub rows: usize,
    pub iterations: usize,
    /// F at the returned point.
    pub objective: f64,
    pub support_vectors: usize,
    pub converged: bool,
    pub stop: StopReason,
    /// The reduced basis's figures (absent for an exact fit).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub basis: Option<BasisFit>,
    /// The rows' weights in the loss, when they were given.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub weights: Option<Weighing>,
}

/// The span and sum of the rows' weights a model was fitted with.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Weighing {
    pub min: f64,
    pub max: f64,
    pub total: f64,
}

impl Weighing {
    pub fn of(weights: &[f64]) -> Weighing {
        Weighing {
            min: weights.iter().copied().fold(f64::INFINITY, f64::min),
            max: weights.iter().copied().fold(f64::NEG_INFINITY, f64::max),
            total: weights.iter().sum(),
        }
    }
}

impl std::fmt::Display for Weighing {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let number = crate::data::format_number;
        write!(
            f,
            "weighted {} to {}, {:.1} in all",
            number(self.min),
            number(self.max),
            self.total
        )
    }
}

/// Per-column min-max scaling to [0, 1], with the training minimum and maximum.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MinMaxScaler {
    pub min: Vec<f64>,
    pub max: Vec<f64>,
}

impl MinMaxScaler {
    /// The scaler of the given columns (each must not be constant).
    pub fn fit(x: &Columns) -> Self {
        let (mut min, mut max) = (
            vec![f64::INFINITY; x.width()],
            vec![f64::NEG_INFINITY; x.width()],
        );
        for row in x.iter_rows() {
            for (j, &v) in row.iter().enumerate() {
                min[j] = min[j].min(v);
                max[j] = max[j].max(v);
            }
        }
        MinMaxScaler { min, max }
    }

    pub fn scale(&self, j: usize, v: f64) -> f64 {
        (v - self.min[j]) / (self.max[j] - self.min[j])
    }

    pub fn transform(&self, x: &Columns) -> Columns {
        let w = x.width();
        let values = x
            .values
            .iter()
            .enumerate()
            .map(|(k, &v)| self.scale(k % w, v))
            .collect();
        Columns::new(x.names.clone(), values)
    }
}

/// A fitted MSVR.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(try_from = "MsvrRepr", into = "MsvrRepr")]
pub struct Msvr {
    pub inputs: Vec<String>,
    pub outputs: Vec<String>,
    pub params: MsvrParams,
    pub scaler: MinMaxScaler,
    /// Support vectors in scaled input units, one row each (`n_sv × d`, row-major).
    support_vectors: Vec<f64>,
    /// Coefficients β of the support vectors (`n_sv × q`, row-major).
    coefficients: Vec<f64>,
    pub bias: Vec<f64>,
    pub fit: FitDiagnostics,
}

impl Msvr {
    /// Builds the model from its file form, without checks (see `TryFrom` for those).
    fn from_repr(r: MsvrRepr) -> Self {
        Msvr {
            inputs: r.inputs,
            outputs: r.outputs,
            params: r.params,
            scaler: r.scaler,
            support_vectors: r.support_vectors.concat(),
            coefficients: r.coefficients.concat(),
            bias: r.bias,
            fit: r.fit,
        }
    }

    pub fn support_vector_count(&self) -> usize {
        self.coefficients.len() / self.outputs.len()
    }

    /// The kernel's centres in scaled input units (`support_vector_count() × d`, row-major).
    pub fn support_vectors(&self) -> &[f64] {
        &self.support_vectors
    }

    /// The centres' coefficients β (`support_vector_count() × q`, row-major).
    pub fn coefficients(&self) -> &[f64] {
        &self.coefficients
    }
}

impl Differentiable for Msvr {
    /// ∂f/∂xⱼ = Σᵢ βᵢ k(sᵢ, s) (sᵢⱼ − sⱼ) / (σ² (maxⱼ − minⱼ)), s the scaled inputs.
    fn predict_with_jacobian(&self, x: &[f64], out: &mut [f64], jacobian: &mut [f64]) {
        let (d, q) = (self.inputs.len(), self.outputs.len());
        assert_eq!(jacobian.len(), q * d, "a q × d Jacobian");
        let sigma2 = self.params.sigma * self.params.sigma;
        let s: Vec<f64> = (0..d).map(|j| self.scaler.scale(j, x[j])).collect();
        out.copy_from_slice(&self.bias);
        jacobian.fill(0.0);
        let mut diff = vec![0.0; d];
        for (sv, beta) in self
            .support_vectors
            .chunks_exact(d)
            .zip(self.coefficients.chunks_exact(q))
        {
            let mut d2 = 0.0;
            for j in 0..d {
                diff[j] = sv[j] - s[j];
                d2 += diff[j] * diff[j];
            }
            let k = (-d2 / (2.0 * sigma2)).exp();
            for (o, b) in beta.iter().enumerate() {
                out[o] += k * b;
                for j in 0..d {
                    jacobian[o * d + j] += k * b * diff[j];
                }
            }
        }
        for o in 0..q {
            for j in 0..d {
                jacobian[o * d + j] /= sigma2 * (self.scaler.max[j] - self.scaler.min[j]);
            }
        }
    }
}

impl Predict for Msvr {
    fn inputs(&self) -> &[String] {
        &self.inputs
    }

    fn outputs(&self) -> &[String] {
        &self.outputs
    }

    fn training_range(&self) -> Option<(&[f64], &[f64])> {
        Some((&self.scaler.min, &self.scaler.max))
    }

    fn predict_row(&self, x: &[f64], out: &mut [f64]) {
        let (d, q) = (self.inputs.len(), self.outputs.len());
        let gamma = 1.0 / (2.0 * self.params.sigma * self.params.sigma);
        out.copy_from_slice(&self.bias);
        for (sv, beta) in self
            .support_vectors
            .chunks_exact(d)
            .zip(self.coefficients.chunks_exact(q))
        {
            let d2: f64 = (0..d)
                .map(|j| {
                    let diff = self.scaler.scale(j, x[j]) - sv[j];
                    diff * diff
                })
                .sum();
            let k = (-gamma * d2).exp();
            for (o, b) in out.iter_mut().zip(beta) {
                *o += k * b;
            }
        }
    }
}

/// The model file's form of [`Msvr`]: support vectors and coefficients as nested rows, checked
/// for consistency when read.
#[derive(Serialize, Deserialize)]
struct MsvrRepr {
    inputs: Vec<String>,
    outputs: Vec<String>,
    params: MsvrParams,
    scaler: MinMaxScaler,
    support_vectors: Vec<Vec<f64>>,
    coefficients: Vec<Vec<f64>>,
    bias: Vec<f64>,
    fit: FitDiagnostics,
}

impl From<Msvr> for MsvrRepr {
    fn from(m: Msvr) -> Self {
        let (d, q) = (m.inputs.len(), m.outputs.len());
        MsvrRepr {
            support_vectors: m
                .support_vectors
                .chunks_exact(d)
                .map(<[f64]>::to_vec)
                .collect(),
            coefficients: m
                .coefficients
                .chunks_exact(q)
                .map(<[f64]>::to_vec)
                .collect(),
            inputs: m.inputs,
            outputs: m.outputs,
            params: m.params,
            scaler: m.scaler,
            bias: m.bias,
            fit: m.fit,
        }
    }
}

/// The largest magnitude of a number in a model file: far beyond any fit's, and far enough
/// below `f64::MAX` that sums over millions of support vectors stay finite.
pub const LARGEST_NUMBER: f64 = 1e100;

impl TryFrom<MsvrRepr> for Msvr {
    type Error = String;

    fn try_from(r: MsvrRepr) -> Result<Self, String> {
        let (d, q) = (r.inputs.len(), r.outputs.len());
        if d == 0 || q == 0 {
            return Err("the model needs at least one input and one output".into());
        }
        r.params.check().map_err(|e| format!("params: {e}"))?;
        let widths = [
            ("scaler.min", r.scaler.min.len(), d),
            ("scaler.max", r.scaler.max.len(), d),
            ("bias", r.bias.len(), q),
        ];
        for (name, found, expected) in widths {
            if found != expected {
                return Err(format!("{name} has {found} values, expected {expected}"));
            }
        }
        if r.support_vectors.len() != r.coefficients.len() {
            return Err(format!(
                "{} support vectors but {} coefficient rows",
                r.support_vectors.len(),
                r.coefficients.len()
            ));
        }
        for (i, (sv, beta)) in r.support_vectors.iter().zip(&r.coefficients).enumerate() {
            if sv.len() != d || beta.len() != q {
                return Err(format!(
                    "support vector {i} has {} values and {} coefficients, expected {d} and {q}",
                    sv.len(),
                    beta.len()
                ));
            }
        }
        let all = r.scaler.min.iter().chain(&r.scaler.max).chain(&r.bias);
        if !all
            .chain(r.support_vectors.iter().flatten())
            .chain(r.coefficients.iter().flatten())
            .all(|v| v.abs() <= LARGEST_NUMBER)
        {
            return Err(format!(
                "a number is not finite or beyond ±{LARGEST_NUMBER:e}, which no fit gives"
            ));
        }
        if r.scaler
            .min
            .iter()
            .zip(&r.scaler.max)
            .any(|(lo, hi)| lo >= hi)
        {
            return Err("scaler.min must be below scaler.max in every column".into());
        }
        Ok(Msvr::from_repr(r))
    }
}

/// A faer matrix of a block of columns.
pub fn to_mat(c: &Columns) -> Mat<f64> {
    Mat::from_fn(c.rows(), c.width(), |i, j| c.row(i)[j])
}

/// The block of columns `names` of a faer matrix ([`to_mat`]'s inverse).
pub fn to_columns(names: Vec<String>, m: MatRef<f64>) -> Columns {
    let values = (0..m.nrows())
        .flat_map(|i| (0..m.ncols()).map(move |j| m[(i, j)]))
        .collect();
    Columns::new(names, values)
}
