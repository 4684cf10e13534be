//! The previous physics model of the micro-hand: pressures → muscle lengths → one constant-
//! curvature bend (Kawamura et al., Actuators 2019, 8, 32; the 2020 paper's §2.2, eqs. 1-7).
//!
//! handcap keeps it as the baseline MSVR is measured against. The 2019 paper's constants are not
//! available here, so the model comes in two variants ([`Variant`]): *default*, with the
//! documented physical constants below, and *calibrated*, whose five uncertain constants are
//! fitted to training data by nonlinear least squares ([`calibrate`]).
//!
//! # Equations
//!
//! 1. Muscle lengths (McKibben static model of Chou & Hannaford, 1996, against an elastic load).
//!    A muscle of bore D₀ and rest braid angle α₀ pulls with
//!    F = (π D₀²/4) p (a (1 − κ)² − b), a = 3 / tan² α₀, b = 1 / sin² α₀,
//!    at contraction ratio κ, where p = max(P − P_th, 0) is the pressure above the threshold
//!    P_th that inflates the inner tube. The silicone resists with K κ (K, N, the load's stiffness
//!    per unit contraction), and the balance F = K κ is a quadratic in s = 1 − κ whose root
//!    s = 2 (f b + K) / (K + √(K² + 4 f a (f b + K))), f = (π D₀²/4) p,
//!    is the stable form (s = 1 at p = 0; 0 ≤ κ < 1 − √(b/a) for α₀ below the neutral angle
//!    54.7°). Then Lᵢ = L₀ (1 − κᵢ), each muscle on its own pressure.
//! 2. The finger is cut into n pieces; a piece is three cylinders at the muscle centres
//!    (xᵢ, yᵢ) (scaled by the effective lever arms s_x, s_y), of lengths Lᵢ/n, symmetric about
//!    the piece's mid-plane, so the tops are Hᵢ = (s_x xᵢ, s_y yᵢ, Lᵢ / 2n) and the top plane is
//!    tilted by half the piece's bend. Its normal is (a, b, c) = H₂H₁ × H₂H₃ (c > 0 for the
//!    hand's muscle order).
//! 3. θ = 2n √(2 (1 − c/√(a² + b² + c²))) (eq. 1): twice the chord between the unit normal and
//!    the axis, per piece, times n. It is evaluated as 2n √(2 (a² + b²) / (N (N + c))),
//!    N = √(a² + b² + c²), which is the same number without the cancellation of 1 − c/N.
//! 4. γ from eq. 2, which is exactly atan2(b, a) (and 0 where a = b = 0, i.e. no bend).
//! 5. R = (L₁ + L₂ + L₃) / 3θ (eq. 3), λ = θ/2 (eq. 7), and the tip (eqs. 4-6):
//!    x = 2R sin²λ cos γ, y = 2R sin²λ sin γ, z = L₀ − 2R sin λ cos λ.
//!    With L̄ the mean length these are x = L̄ (1 − cos θ)/θ · cos γ and z = L₀ − L̄ sin θ / θ,
//!    which is how they are evaluated: finite and continuous as θ → 0 (a straight finger, R = ∞).
//!
//! # Constants and where they come from
//!
//! | constant | default | calibrated | source |
//! |---|---|---|---|
//! | L₀, finger length | 50 mm | no | the paper (§1) |
//! | (xᵢ, yᵢ), muscle centres | [`crate::hand::MUSCLE_XY_MM`] | no | the cross-section (Fig. 1) |
//! | D₀, muscle bore | 1.0 mm | no | thin McKibben muscles of ~1.5 mm outer diameter fit a 2.6 mm thick finger |
//! | n, pieces | 10 | no | eq. 1; θ is within 0.1 % of its n → ∞ limit for bends up to ~1 rad |
//! | α₀, rest braid angle | 25° | yes | typical of braided sleeves (20-30°) |
//! | K, load stiffness | 55 N | yes | the finger's bending resistance seen by one muscle, EI / d²: EI ≈ 75 N·mm² (silicone with braided muscles) over d² ≈ 1.36 mm², the muscles' mean squared distance from the centre |
//! | P_th, threshold pressure | 0 kPa | yes | the ideal McKibben muscle has none |
//! | s_x, s_y, lever-arm scales | 1, 1 | yes | the drawing's geometry |
//!
//! The lever-arm scales let the calibration give the two bending directions different effective
//! stiffness, which the model otherwise cannot express. Calibration starts from the defaults and
//! from two other braid angles and keeps the best fit; the defaults are never tuned to the data.

use std::f64::consts::PI;

use levenberg_marquardt::{LeastSquaresProblem, LevenbergMarquardt};
use nalgebra::{storage::Owned, DVector, Dyn, OMatrix, Vector5, U5};
use serde::{Deserialize, Serialize};

use crate::data::{names, Dataset, HAND_INPUTS, HAND_OUTPUTS};
use crate::hand;
use crate::model::Predict;

/// The braid angle at which a McKibben muscle produces no force: atan √2 (degrees).
pub const NEUTRAL_BRAID_ANGLE_DEG: f64 = 54.735_610_317_245_35;

/// Errors of building or calibrating the previous model.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum PreviousError {
    #[error("previous model: {0}")]
    Invalid(String),
    #[error("the previous model describes the micro-hand: it needs inputs {} and outputs {}, got inputs ({inputs}) and outputs ({outputs})", HAND_INPUTS.join(","), HAND_OUTPUTS.join(","))]
    NotTheHand { inputs: String, outputs: String },
    #[error("previous model calibration failed: {0}")]
    Calibration(String),
}

/// The model's constants (see the module docs for their roles and sources).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PreviousParams {
    pub length_mm: f64,
    pub muscle_xy_mm: [[f64; 2]; 3],
    pub bore_mm: f64,
    pub pieces: usize,
    pub braid_angle_deg: f64,
    pub load_n: f64,
    pub threshold_kpa: f64,
    pub arm_x: f64,
    pub arm_y: f64,
}

impl Default for PreviousParams {
    fn default() -> Self {
        PreviousParams {
            length_mm: hand::LENGTH_MM,
            muscle_xy_mm: hand::MUSCLE_XY_MM,
            bore_mm: 1.0,
            pieces: 10,
            braid_angle_deg: 25.0,
            load_n: 55.0,
            threshold_kpa: 0.0,
            arm_x: 1.0,
            arm_y: 1.0,
        }
    }
}

impl PreviousParams {
    /// Checks ranges and that the muscle order gives an outward normal (c > 0).
    ///
    /// # Errors
    /// [`PreviousError::Invalid`] naming the constant.
    pub fn check(&self) -> Result<(), PreviousError> {
        let positive = [
            ("length_mm", self.length_mm),
            ("bore_mm", self.bore_mm),
            ("load_n", self.load_n),
            ("arm_x", self.arm_x),
            ("arm_y", self.arm_y),
        ];
        for (name, v) in positive {
            if !(v.is_finite() && v > 0.0) {
                return Err(PreviousError::Invalid(format!(
                    "{name} must be a positive number, got {v}"
                )));
            }
        }
        if !(self.braid_angle_deg > 0.0 && self.braid_angle_deg < NEUTRAL_BRAID_ANGLE_DEG) {
            return Err(PreviousError::Invalid(format!(
                "braid_angle_deg must lie in (0, {NEUTRAL_BRAID_ANGLE_DEG:.2}) (the neutral angle), got {}",
                self.braid_angle_deg
            )));
        }
        if !self.threshold_kpa.is_finite() || self.pieces == 0 {
            return Err(PreviousError::Invalid(
                "threshold_kpa must be finite and pieces at least 1".into(),
            ));
        }
        let [h1, h2, h3] = self.piece_tops([0.0; 3]);
        if cross(sub(h1, h2), sub(h3, h2))[2] <= 0.0 {
            return Err(PreviousError::Invalid(
                "muscle centres must run 1 → 2 → 3 counter-clockwise seen from the tip (as in the hand's cross-section)".into(),
            ));
        }
        Ok(())
    }

    /// Contraction ratio κ of one muscle at pressure `p_kpa` (equation 1 of the module docs).
    pub fn contraction(&self, p_kpa: f64) -> f64 {
        let alpha = self.braid_angle_deg.to_radians();
        let a = 3.0 / alpha.tan().powi(2);
        let b = 1.0 / alpha.sin().powi(2);
        let drive_kpa = (p_kpa - self.threshold_kpa.max(0.0)).max(0.0);
        // kPa · mm² = 1e-3 N.
        let f = PI * self.bore_mm * self.bore_mm / 4.0 * drive_kpa * 1e-3;
        let k = self.load_n;
        let s = 2.0 * (f * b + k) / (k + (k * k + 4.0 * f * a * (f * b + k)).sqrt());
        1.0 - s
    }

    /// Muscle lengths L1-L3 (mm).
    pub fn muscle_lengths(&self, p: [f64; 3]) -> [f64; 3] {
        p.map(|pi| self.length_mm * (1.0 - self.contraction(pi)))
    }

    /// The tops H1-H3 of one piece's cylinders.
    fn piece_tops(&self, lengths: [f64; 3]) -> [[f64; 3]; 3] {
        let half = 2.0 * self.pieces as f64;
        std::array::from_fn(|i| {
            let [x, y] = self.muscle_xy_mm[i];
            [self.arm_x * x, self.arm_y * y, lengths[i] / half]
        })
    }

    /// Bending angle θ and direction γ (rad) for muscle lengths (eqs. 1-2).
    pub fn bend(&self, lengths: [f64; 3]) -> Bend {
        let [h1, h2, h3] = self.piece_tops(lengths);
        let [a, b, c] = cross(sub(h1, h2), sub(h3, h2));
        let lateral = a * a + b * b;
        let norm = (lateral + c * c).sqrt();
        let chord = (2.0 * lateral / (norm * (norm + c))).sqrt();
        Bend {
            theta: 2.0 * self.pieces as f64 * chord,
            gamma: b.atan2(a),
            normal: [a, b, c],
        }
    }

    /// The tip in the hand frame (mm) for pressures (kPa).
    pub fn tip(&self, p: [f64; 3]) -> [f64; 3] {
        self.tip_from_lengths(self.muscle_lengths(p))
    }

    /// The tip in the hand frame (mm) for muscle lengths (mm), eqs. 1-7.
    pub fn tip_from_lengths(&self, lengths: [f64; 3]) -> [f64; 3] {
        let Bend { theta, gamma, .. } = self.bend(lengths);
        let mean = lengths.iter().sum::<f64>() / 3.0;
        // (1 − cos θ)/θ and sin θ/θ, with their limits at θ = 0.
        let (versine, sinc) = if theta < 1e-8 {
            (theta / 2.0, 1.0 - theta * theta / 6.0)
        } else {
            (
                2.0 * (theta / 2.0).sin().powi(2) / theta,
                theta.sin() / theta,
            )
        };
        [
            mean * versine * gamma.cos(),
            mean * versine * gamma.sin(),
            self.length_mm - mean * sinc,
        ]
    }
}

/// The bend of the finger's axis.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Bend {
    /// Bending angle (rad), eq. 1.
    pub theta: f64,
    /// Bending direction from +x towards +y (rad), eq. 2.
    pub gamma: f64,
    /// The piece's top-plane normal (a, b, c) = H2H1 × H2H3.
    pub normal: [f64; 3],
}

/// Which constants a model uses.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Variant {
    Default,
    Calibrated,
}

/// The previous model with its constants, behind the [`Predict`] contract.
#[derive(Clone, Debug)]
pub struct PreviousModel {
    pub params: PreviousParams,
    pub variant: Variant,
    inputs: Vec<String>,
    outputs: Vec<String>,
}

impl PreviousModel {
    /// # Errors
    /// [`PreviousError::Invalid`] for constants out of range.
    pub fn new(params: PreviousParams, variant: Variant) -> Result<Self, PreviousError> {
        params.check()?;
        Ok(PreviousModel {
            params,
            variant,
            inputs: names(&HAND_INPUTS),
            outputs: names(&HAND_OUTPUTS),
        })
    }

    /// The model with the documented default constants.
    pub fn with_defaults() -> Self {
        PreviousModel::new(PreviousParams::default(), Variant::Default)
            .expect("default constants are valid")
    }

    /// The name reports use: `previous-default` or `previous-calibrated`.
    pub fn name(&self) -> &'static str {
        match self.variant {
            Variant::Default => "previous-default",
            Variant::Calibrated => "previous-calibrated",
        }
    }
}

impl Predict for PreviousModel {
    fn inputs(&self) -> &[String] {
        &self.inputs
    }
    fn outputs(&self) -> &[String] {
        &self.outputs
    }
    fn predict_row(&self, x: &[f64], out: &mut [f64]) {
        out.copy_from_slice(&self.params.tip([x[0], x[1], x[2]]));
    }
}

/// How a calibration went.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Calibration {
    pub rows: usize,
    /// Root mean square of the residuals over rows and coordinates (mm).
    pub rms_mm: f64,
    /// Residual evaluations of the best start.
    pub evaluations: usize,
    /// The solver's reason for stopping, for the best start.
    pub termination: String,
    pub converged: bool,
    /// Braid angles the starts began from (degrees); the other constants start at the defaults.
    pub start_braid_angles_deg: Vec<f64>,
}

/// Braid angles (degrees) the calibration starts from, besides the given start's.
const EXTRA_START_ANGLES_DEG: [f64; 2] = [15.0, 40.0];

/// Fits α₀, K, P_th, s_x and s_y to `data` (the hand's columns) by Levenberg-Marquardt on the
/// tip residuals (x, y, z in mm), from `start` and from two other braid angles; keeps the best.
///
/// The fit runs on unconstrained coordinates (logit of α₀ over the neutral angle, logarithms of
/// K, s_x, s_y; P_th as it is, read as max(P_th, 0)) with a central-difference Jacobian.
///
/// # Errors
/// [`PreviousError::NotTheHand`] for other columns, [`PreviousError::Calibration`] when no
/// start ends in finite constants.
pub fn calibrate(
    data: &Dataset,
    start: &PreviousParams,
) -> Result<(PreviousModel, Calibration), PreviousError> {
    if data.inputs.names != HAND_INPUTS || data.outputs.names != HAND_OUTPUTS {
        return Err(PreviousError::NotTheHand {
            inputs: data.inputs.names_list(),
            outputs: data.outputs.names_list(),
        });
    }
    start.check()?;
    let angles: Vec<f64> = std::iter::once(start.braid_angle_deg)
        .chain(EXTRA_START_ANGLES_DEG)
        .collect();
    let mut best: Option<(PreviousParams, f64, usize, String, bool)> = None;
    for &angle in &angles {
        let from = PreviousParams {
            braid_angle_deg: angle,
            ..start.clone()
        };
        let problem = TipResiduals {
            data,
            base: start.clone(),
            u: encode(&from),
        };
        let (problem, report) = LevenbergMarquardt::new()
            .with_patience(200)
            .minimize(problem);
        let fitted = decode(&problem.base, &problem.u);
        if fitted.check().is_err() {
            continue;
        }
        let Some(residuals) = problem.residuals() else {
            continue;
        };
        let sse = residuals.norm_squared();
        if sse.is_finite() && best.as_ref().is_none_or(|b| sse < b.1) {
            best = Some((
                fitted,
                sse,
                report.number_of_evaluations,
                format!("{:?}", report.termination),
                report.termination.was_successful(),
            ));
        }
    }
    let (params, sse, evaluations, termination, converged) =
        best.ok_or_else(|| PreviousError::Calibration("no start reached finite constants".into()))?;
    let calibration = Calibration {
        rows: data.rows(),
        rms_mm: (sse / (3 * data.rows()) as f64).sqrt(),
        evaluations,
        termination,
        converged,
        start_braid_angles_deg: angles,
    };
    Ok((
        PreviousModel::new(params, Variant::Calibrated)?,
        calibration,
    ))
}

/// The calibrated constants in unconstrained coordinates.
fn encode(p: &PreviousParams) -> Vector5<f64> {
    let r = p.braid_angle_deg / NEUTRAL_BRAID_ANGLE_DEG;
    Vector5::new(
        (r / (1.0 - r)).ln(),
        p.load_n.ln(),
        p.threshold_kpa,
        p.arm_x.ln(),
        p.arm_y.ln(),
    )
}

fn decode(base: &PreviousParams, u: &Vector5<f64>) -> PreviousParams {
    PreviousParams {
        braid_angle_deg: NEUTRAL_BRAID_ANGLE_DEG / (1.0 + (-u[0]).exp()),
        load_n: u[1].exp(),
        threshold_kpa: u[2].max(0.0),
        arm_x: u[3].exp(),
        arm_y: u[4].exp(),
        ..base.clone()
    }
}

/// The least-squares problem: tip residuals of every row, stacked (x, y, z).
struct TipResiduals<'a> {
    data: &'a Dataset,
    base: PreviousParams,
    u: Vector5<f64>,
}

impl TipResiduals<'_> {
    fn residuals_at(&self, u: &Vector5<f64>) -> DVector<f64> {
        let p = decode(&self.base, u);
        let mut r = DVector::zeros(3 * self.data.rows());
        for (i, (x, y)) in self
            .data
            .inputs
            .iter_rows()
            .zip(self.data.outputs.iter_rows())
            .enumerate()
        {
            let tip = p.tip([x[0], x[1], x[2]]);
            for j in 0..3 {
                r[3 * i + j] = tip[j] - y[j];
            }
        }
        r
    }
}

impl LeastSquaresProblem<f64, Dyn, U5> for TipResiduals<'_> {
    type ResidualStorage = Owned<f64, Dyn>;
    type JacobianStorage = Owned<f64, Dyn, U5>;
    type ParameterStorage = Owned<f64, U5>;

    fn set_params(&mut self, u: &Vector5<f64>) {
        self.u = *u;
    }

    fn params(&self) -> Vector5<f64> {
        self.u
    }

    fn residuals(&self) -> Option<DVector<f64>> {
        let r = self.residuals_at(&self.u);
        r.iter().all(|v| v.is_finite()).then_some(r)
    }

    fn jacobian(&self) -> Option<OMatrix<f64, Dyn, U5>> {
        let mut jac = OMatrix::<f64, Dyn, U5>::zeros(3 * self.data.rows());
        for k in 0..5 {
            let h = 1e-6 * self.u[k].abs().max(1.0);
            let mut up = self.u;
            let mut down = self.u;
            up[k] += h;
            down[k] -= h;
            let column = (self.residuals_at(&up) - self.residuals_at(&down)) / (2.0 * h);
            jac.set_column(k, &column);
        }
        jac.iter().all(|v| v.is_finite()).then_some(jac)
    }
}

fn sub(p: [f64; 3], q: [f64; 3]) -> [f64; 3] {
    [p[0] - q[0], p[1] - q[1], p[2] - q[2]]
}

fn cross(u: [f64; 3], v: [f64; 3]) -> [f64; 3] {
    [
        u[1] * v[2] - u[2] * v[1],
        u[2] * v[0] - u[0] * v[2],
        u[0] * v[1] - u[1] * v[0],
    ]
}

#[cfg(test)]
mod tests;
