//! The virtual micro-hand: muscle pressures (kPa) → tip position in the hand frame (mm).
//!
//! A deterministic stand-in for the real finger, used to generate data with exact ground truth.
//! It is a *variable-curvature elastic rod* driven by muscle forces, deliberately different from
//! the paper's previous model (which turns muscle lengths into one constant-curvature arc through
//! the plane of three cylinder tops): here the curvature varies along the finger, the two bending
//! directions have different stiffness, and the section stiffens with pressure, so a
//! constant-curvature model cannot match it exactly.
//!
//! # Geometry
//!
//! The finger is `length_mm` = 50 mm long; the last `cap_mm` = 3 mm are the muscles' rigid end
//! cap carrying the marker. Muscle centres in the cross-section are the design's
//! ([`crate::hand::MUSCLE_XY_MM`], hand frame x, y, mm): muscle 1 at (−1.25, −0.4), muscle 3 at
//! (+1.25, −0.4), muscle 2 at (0, +0.8): muscles 1 and 3 lie side by side, muscle 2 sits across
//! the gap. Their centroid is the origin of the section, which is also its elastic centre (the
//! silicone is moulded symmetrically around them).
//!
//! # Equations
//!
//! 1. Hysteresis (optional): each pressure passes a play operator of width h (kPa),
//!    p̃ = min(max(p̃_prev, p − h/2), p + h/2); with h = 0, p̃ = p.
//! 2. McKibben force with a dead band and saturation, per muscle (N):
//!    g(p̃) = F_max · (1 − exp(−r(p̃) / p_sat)), where the driving pressure r is 0 up to the dead
//!    band p_db = 20 kPa (the braid is slack and the rubber pre-stretched below it), rises
//!    quadratically over the onset width w = 30 kPa as the braid takes up the slack,
//!    r = (p̃ − p_db)² / (2w), and linearly after it, r = p̃ − p_db − w/2 (r is C¹);
//!    p_sat = 110 kPa sets the saturation as the braid nears its locking angle.
//! 3. Coupling through the silicone: a muscle drags its neighbours along in proportion to the
//!    force difference, f = (I − Λ) g with Λ the weighted graph Laplacian of the three muscles,
//!    weight c_adj = 0.15 between muscles 1 and 3 (bonded side by side) and c_gap = 0.05 across
//!    the gap to muscle 2. Equal forces are left unchanged.
//! 4. Stiffness along the arc s from the base (mm), growing with the mean activation
//!    ā = Σ f_i / (3 F_max) (pressurised muscles stiffen the section) and near the clamped root:
//!    S(s) = (1 + k_p · ā) · (1 + k_root · exp(−s / s_root)), k_p = 0.35, k_root = 1.0, s_root = 4 mm.
//! 5. Curvature (1/mm) towards +x and +y and axial strain:
//!    κ_x(s) = Σ f_i x_i / (EI_x S(s)), κ_y(s) = Σ f_i y_i / (EI_y S(s)),
//!    ε(s) = −Σ f_i / (EA S(s)), with EI_x = 90 N·mm², EI_y = 60 N·mm² (the thin direction is
//!    softer), EA = 110 N.
//! 6. The centre line is integrated from the base, (0, 0, L) in the hand frame with tangent
//!    (0, 0, −1), in `segments` steps of reference length ds: each step turns the tangent and the
//!    section axes about t × (κ_x d₁ + κ_y d₂) by |κ| ds (no twist) and advances by
//!    (1 + ε) ds along the mid-step tangent. The rigid cap follows the last tangent.
//! 7. A payload of m = `tip_load_g` on the tip (0 unless a fault hangs one there): the finger
//!    hangs from its base, gravity along −z, so the tip bears F = (0, 0, −m g). At s its moment
//!    M = (p_tip − p(s)) × F bends the section, κ_x += −M·d₂ / (EI_x S), κ_y += M·d₁ / (EI_y S),
//!    and its pull along the tangent stretches it, ε += F·t / (EA S). The shape the moment
//!    needs is the shape it makes: [`LOAD_PASSES`] passes, each on the line of the one before
//!    (a payload of grams moves the tip by hundredths of a millimetre a gram, so they settle
//!    at once).
//!
//! With these constants the tip travels up to about 10 mm sideways and 3 mm along z over
//! 0-250 kPa, the order of the paper's Figures 9-14. Pressures outside 0-300 kPa (the safety
//! regulator's limit) are an error.

use nalgebra::{Rotation3, Vector3};
use serde::Serialize;

use crate::hand::{self, MAX_PRESSURE_KPA};

/// Errors of driving the plant.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum PlantError {
    #[error("pressure P{muscle} = {value} kPa is outside 0-{MAX_PRESSURE_KPA} kPa")]
    PressureOutOfRange { muscle: usize, value: f64 },
}

/// Constants of the virtual micro-hand (see the module docs for their roles and units).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct PlantParams {
    pub length_mm: f64,
    pub cap_mm: f64,
    /// Muscle centres (x, y) in the hand frame, muscles 1, 2, 3.
    pub muscle_xy_mm: [[f64; 2]; 3],
    pub max_force_n: f64,
    pub dead_band_kpa: f64,
    pub onset_kpa: f64,
    pub saturation_kpa: f64,
    pub coupling_adjacent: f64,
    pub coupling_gap: f64,
    pub pressure_stiffening: f64,
    pub root_stiffening: f64,
    pub root_length_mm: f64,
    pub bend_stiffness_x_nmm2: f64,
    pub bend_stiffness_y_nmm2: f64,
    pub axial_stiffness_n: f64,
    /// Width of the play operator (kPa); 0 disables hysteresis.
    pub hysteresis_kpa: f64,
    /// Integration steps along the muscle part of the finger.
    pub segments: usize,
    /// A payload on the tip (g), equation 7.
    pub tip_load_g: f64,
}

/// The passes of the centre line under a payload (equation 7).
pub const LOAD_PASSES: usize = 4;

/// Gravity (m/s²).
const GRAVITY: f64 = 9.81;

impl Default for PlantParams {
    fn default() -> Self {
        PlantParams {
            length_mm: hand::LENGTH_MM,
            cap_mm: 3.0,
            muscle_xy_mm: hand::MUSCLE_XY_MM,
            max_force_n: 1.2,
            dead_band_kpa: 20.0,
            onset_kpa: 30.0,
            saturation_kpa: 110.0,
            coupling_adjacent: 0.15,
            coupling_gap: 0.05,
            pressure_stiffening: 0.35,
            root_stiffening: 1.0,
            root_length_mm: 4.0,
            bend_stiffness_x_nmm2: 90.0,
            bend_stiffness_y_nmm2: 60.0,
            axial_stiffness_n: 110.0,
            hysteresis_kpa: 0.0,
            segments: 200,
            tip_load_g: 0.0,
        }
    }
}

/// The three muscle pressures (kPa), muscles 1, 2, 3.
pub type Pressures = [f64; 3];

/// The virtual finger.
#[derive(Clone, Debug)]
pub struct Plant {
    params: PlantParams,
}

impl Plant {
    pub fn new(params: PlantParams) -> Self {
        Plant { params }
    }

    pub fn params(&self) -> &PlantParams {
        &self.params
    }

    /// The settled tip for pressures held from rest, without hysteresis memory.
    ///
    /// # Errors
    /// [`PlantError::PressureOutOfRange`] for a pressure outside 0-300 kPa or not finite.
    pub fn tip(&self, p: Pressures) -> Result<[f64; 3], PlantError> {
        check_pressures(p)?;
        Ok(self.tip_from_effective(p))
    }

    /// Settled tips for a sequence of pressure steps applied in order from rest; with hysteresis
    /// the response to each step depends on the ones before it.
    ///
    /// # Errors
    /// As [`Plant::tip`], for the first bad step.
    pub fn run(&self, steps: &[Pressures]) -> Result<Vec<[f64; 3]>, PlantError> {
        let mut state = [0.0f64; 3];
        steps
            .iter()
            .map(|&p| {
                check_pressures(p)?;
                play(&mut state, p, self.params.hysteresis_kpa);
                Ok(self.tip_from_effective(state))
            })
            .collect()
    }

    /// The centre line from the base to the tip (hand frame, mm), `segments + 2` points.
    ///
    /// # Errors
    /// As [`Plant::tip`].
    pub fn centre_line(&self, p: Pressures) -> Result<Vec<[f64; 3]>, PlantError> {
        check_pressures(p)?;
        Ok(self.integrate(p).0)
    }

    fn tip_from_effective(&self, p: Pressures) -> [f64; 3] {
        self.integrate(p).1
    }

    /// Muscle forces after the dead band, saturation and coupling (N), equations 2-3.
    pub fn muscle_forces(&self, p: Pressures) -> [f64; 3] {
        let q = &self.params;
        let g = p.map(|pi| {
            let over = (pi - q.dead_band_kpa).max(0.0);
            let driving = if over < q.onset_kpa {
                over * over / (2.0 * q.onset_kpa)
            } else {
                over - q.onset_kpa / 2.0
            };
            q.max_force_n * (1.0 - (-driving / q.saturation_kpa).exp())
        });
        // Laplacian weights: (1,3) adjacent, (1,2) and (2,3) across the gap.
        let w = |i: usize, j: usize| {
            if i + j == 2 {
                q.coupling_adjacent
            } else {
                q.coupling_gap
            }
        };
        std::array::from_fn(|i| {
            g[i] - (0..3)
                .filter(|&j| j != i)
                .map(|j| w(i, j) * (g[i] - g[j]))
                .sum::<f64>()
        })
    }

    /// Integrates the centre line (equations 4-7); returns the points and the tip.
    fn integrate(&self, p: Pressures) -> (Vec<[f64; 3]>, [f64; 3]) {
        let mut shape = self.pass(p, None);
        if self.params.tip_load_g != 0.0 {
            for _ in 0..LOAD_PASSES {
                shape = self.pass(p, Some(&shape.0));
            }
        }
        shape
    }

    /// One integration of the centre line; under a payload, its moments taken on `loaded`
    /// (the line of the pass before).
    fn pass(&self, p: Pressures, loaded: Option<&[[f64; 3]]>) -> (Vec<[f64; 3]>, [f64; 3]) {
        let q = &self.params;
        // The payload's force (N) and the moment arm's end, the tip (mm).
        let load = loaded.map(|line| {
            let tip = Vector3::from(line[line.len() - 1]);
            (
                Vector3::new(0.0, 0.0, -q.tip_load_g * 1e-3 * GRAVITY),
                tip,
                line,
            )
        });
        let f = self.muscle_forces(p);
        let activation = f.iter().sum::<f64>() / (3.0 * q.max_force_n);
        let moment_x: f64 = (0..3).map(|i| f[i] * q.muscle_xy_mm[i][0]).sum();
        let moment_y: f64 = (0..3).map(|i| f[i] * q.muscle_xy_mm[i][1]).sum();
        let axial: f64 = f.iter().sum();

        let muscle_len = q.length_mm - q.cap_mm;
        let ds = muscle_len / q.segments as f64;
        let mut pos = Vector3::new(0.0, 0.0, q.length_mm);
        let mut t = Vector3::new(0.0, 0.0, -1.0);
        let mut d1 = Vector3::x();
        let mut d2 = Vector3::y();
        let mut line = Vec::with_capacity(q.segments + 2);
        line.push(pos.into());
        for k in 0..q.segments {
            let s = (k as f64 + 0.5) * ds;
            let stiffness = (1.0 + q.pressure_stiffening * activation)
                * (1.0 + q.root_stiffening * (-s / q.root_length_mm).exp());
            let mut kx = moment_x / (q.bend_stiffness_x_nmm2 * stiffness);
            let mut ky = moment_y / (q.bend_stiffness_y_nmm2 * stiffness);
            let mut strain = -axial / (q.axial_stiffness_n * stiffness);
            if let Some((force, tip, line)) = load {
                let here = (Vector3::from(line[k]) + Vector3::from(line[k + 1])) / 2.0;
                let m = (tip - here).cross(&force);
                kx -= m.dot(&d2) / (q.bend_stiffness_x_nmm2 * stiffness);
                ky += m.dot(&d1) / (q.bend_stiffness_y_nmm2 * stiffness);
                strain += force.dot(&t) / (q.axial_stiffness_n * stiffness);
            }
            let turn = t.cross(&(d1 * kx + d2 * ky)) * ds;
            let half = Rotation3::from_scaled_axis(turn * 0.5);
            let full = Rotation3::from_scaled_axis(turn);
            pos += half * t * ((1.0 + strain) * ds);
            t = full * t;
            d1 = full * d1;
            d2 = full * d2;
            line.push(pos.into());
        }
        pos += t * q.cap_mm;
        line.push(pos.into());
        (line, [pos.x, pos.y, pos.z])
    }
}

impl Default for Plant {
    fn default() -> Self {
        Plant::new(PlantParams::default())
    }
}

/// The play operator of width `width_kpa` (equation 1), one step: `state` follows `p` only
/// where `p` leaves the band of half the width around it. Stays in 0-300 kPa when `p` does.
pub fn play(state: &mut Pressures, p: Pressures, width_kpa: f64) {
    let half = width_kpa / 2.0;
    for (s, &pi) in state.iter_mut().zip(&p) {
        *s = (*s).max(pi - half).min(pi + half);
    }
}

fn check_pressures(p: Pressures) -> Result<(), PlantError> {
    for (i, &v) in p.iter().enumerate() {
        if !(0.0..=MAX_PRESSURE_KPA).contains(&v) {
            return Err(PlantError::PressureOutOfRange {
                muscle: i + 1,
                value: v,
            });
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn norm_xy(t: [f64; 3]) -> f64 {
        t[0].hypot(t[1])
    }

    #[test]
    fn zero_pressure_is_the_origin() {
        let tip = Plant::default().tip([0.0; 3]).unwrap();
        for (axis, v) in ["x", "y", "z"].iter().zip(tip) {
            assert!(v.abs() < 1e-9, "{axis} = {v} mm at zero pressure");
        }
    }

    #[test]
    fn pressures_inside_the_dead_band_do_not_move_the_tip() {
        let tip = Plant::default().tip([15.0, 19.0, 5.0]).unwrap();
        assert!(norm_xy(tip) < 1e-9 && tip[2].abs() < 1e-9, "{tip:?}");
    }

    #[test]
    fn equal_pressures_contract_without_lateral_motion() {
        let plant = Plant::default();
        let mut last_z = 0.0;
        for p in [50.0, 100.0, 150.0, 250.0] {
            let tip = plant.tip([p; 3]).unwrap();
            assert!(
                norm_xy(tip) < 1e-12,
                "lateral {} mm at {p} kPa",
                norm_xy(tip)
            );
            assert!(
                tip[2] > last_z,
                "z {} mm at {p} kPa not above {last_z}",
                tip[2]
            );
            last_z = tip[2];
        }
    }

    #[test]
    fn muscle_three_alone_bends_towards_plus_x() {
        let tip = Plant::default().tip([0.0, 0.0, 250.0]).unwrap();
        assert!(
            tip[0] > 5.0,
            "x = {} mm, expected a bend of several mm",
            tip[0]
        );
        // Mostly towards +x, and away from muscle 2 (−y): muscles 1 and 3 sit below the centroid.
        assert!(
            tip[0] > tip[1].abs() && tip[1] < 0.0,
            "x = {}, y = {}",
            tip[0],
            tip[1]
        );
        assert!(tip[2] > 0.0, "the finger shortens: z = {}", tip[2]);
    }

    #[test]
    fn muscle_two_alone_bends_towards_plus_y_and_muscle_one_towards_minus_x() {
        let plant = Plant::default();
        let two = plant.tip([0.0, 200.0, 0.0]).unwrap();
        assert!(two[1] > 3.0 && two[0].abs() < 1e-9, "{two:?}");
        let one = plant.tip([200.0, 0.0, 0.0]).unwrap();
        let three = plant.tip([0.0, 0.0, 200.0]).unwrap();
        assert!(
            (one[0] + three[0]).abs() < 1e-9,
            "mirror: {one:?} {three:?}"
        );
        assert!((one[1] - three[1]).abs() < 1e-9 && (one[2] - three[2]).abs() < 1e-9);
    }

    #[test]
    fn response_is_monotone_and_saturating() {
        let plant = Plant::default();
        let xs: Vec<f64> = (0..=25)
            .map(|k| plant.tip([0.0, 0.0, 10.0 * k as f64]).unwrap()[0])
            .collect();
        let steps: Vec<f64> = xs.windows(2).map(|w| w[1] - w[0]).collect();
        assert!(steps.iter().all(|&d| d >= 0.0), "not monotone: {steps:?}");
        // Past the dead band the gain per 10 kPa falls: saturation.
        let early = steps[3]; // 30 → 40 kPa
        let late = steps[24]; // 240 → 250 kPa
        assert!(
            late < 0.6 * early,
            "gain {early} mm early vs {late} mm late"
        );
        assert!(
            xs[25] < 20.0,
            "tip travel {} mm is beyond the finger's range",
            xs[25]
        );
    }

    #[test]
    fn pressures_outside_the_regulator_range_are_rejected() {
        let plant = Plant::default();
        for bad in [-1.0, 300.5, f64::NAN, f64::INFINITY] {
            let err = plant.tip([0.0, bad, 0.0]).unwrap_err();
            assert!(matches!(
                err,
                PlantError::PressureOutOfRange { muscle: 2, .. }
            ));
        }
        assert!(plant.tip([300.0, 0.0, 0.0]).is_ok());
    }

    /// A payload pulls a bent finger back towards hanging straight (the moment of its weight
    /// about each section), by an amount proportional to its weight; at rest it only
    /// stretches the finger; none changes nothing.
    #[test]
    fn a_payload_pulls_the_bent_finger_towards_hanging_straight_in_proportion_to_its_weight() {
        let loaded = |g: f64| {
            Plant::new(PlantParams {
                tip_load_g: g,
                ..PlantParams::default()
            })
        };
        let p = [150.0, 0.0, 0.0];
        let free = Plant::default().tip(p).unwrap();
        assert_eq!(loaded(0.0).tip(p).unwrap(), free);
        let shift = |g: f64| {
            let tip = loaded(g).tip(p).unwrap();
            Vector3::from(tip) - Vector3::from(free)
        };
        // 0.2 g, the monitor's payload, and twice that.
        let (one, two) = (shift(0.2), shift(0.4));
        let side = Vector3::new(free[0], free[1], 0.0).normalize();
        // Back towards the axis, not sideways.
        assert!(one.dot(&side) < -0.01, "{one:?} against {side:?}");
        assert!(one.dot(&side).abs() > 3.0 * (one - side * one.dot(&side)).xy().norm());
        assert!(
            (two.norm() / one.norm() - 2.0).abs() < 0.1,
            "{one:?} {two:?}"
        );
        // The moment's bend of a clamped beam, M L² / (2 EI) with M = F · the tip's offset,
        // bounds it from above: the root's and the pressure's stiffening make the finger
        // stiffer than its softer EI alone.
        let force = 0.2e-3 * GRAVITY;
        let bend = free[0].hypot(free[1]);
        let reach = force * bend * 47.0 * 47.0 / (2.0 * 60.0);
        eprintln!("0.2 g: {:.4} mm back of {reach:.4}", one.dot(&side).abs());
        assert!(one.dot(&side).abs() < reach, "{one:?}: {reach}");
        // At rest the weight only stretches it, by F L / EA.
        let rest = Vector3::from(loaded(0.2).tip([0.0; 3]).unwrap())
            - Vector3::from(Plant::default().tip([0.0; 3]).unwrap());
        assert!(rest.xy().norm() < 1e-9 && rest.z < 0.0, "{rest:?}");
        assert!(rest.z.abs() < 47.0 * force / 110.0, "{rest:?}");
    }

    #[test]
    fn hysteresis_makes_the_response_depend_on_the_path() {
        let plant = Plant::new(PlantParams {
            hysteresis_kpa: 30.0,
            ..PlantParams::default()
        });
        let up = plant.run(&[[0.0, 0.0, 100.0]]).unwrap()[0];
        let down = plant.run(&[[0.0, 0.0, 200.0], [0.0, 0.0, 100.0]]).unwrap()[1];
        assert!(
            down[0] > up[0] + 0.1,
            "loading {up:?} vs unloading {down:?}"
        );
        let none = Plant::default().run(&[[0.0, 0.0, 200.0], [0.0, 0.0, 100.0]]);
        assert_eq!(
            none.unwrap()[1],
            Plant::default().tip([0.0, 0.0, 100.0]).unwrap()
        );
    }
}
