//! Faults injected in a virtual session at given times (`synth --fault KIND@T=AMOUNT`), and
//! the [`Timeline`] that says what the finger and the cameras are at each instant.
//!
//! - `camera@T=DEG`: the right (second) camera tilts by DEG degrees about its own x axis at T
//!   (a bump). Its beads leave their epipolar lines by about f·tan(DEG), so the reprojection residual
//!   says so, and the tip moves.
//! - `pan@T=DEG`: the right camera turns by DEG degrees about its own y axis at T. Its beads
//!   move along the epipolar lines of a side-by-side pair: the tip shifts in depth with little
//!   residual to tell. The still scene behind the finger moves in its picture all the same
//!   (as after a tilt: the renderer's wall is seen through the turned camera), which
//!   [`crate::triangulate::scene`] measures. One camera fault per session: the first of the
//!   two.
//! - `stiffness@T=SHARE`: from T the finger's bending and axial stiffness are 1 + SHARE times
//!   what they were (−0.1: 10 % softer).
//! - `leak@T=SHARE`: muscle 1 loses up to SHARE of its pressure, linearly over the minute after
//!   T (a slow leak: what the regulator is told is not what the muscle holds).
//! - `payload@T=GRAMS`: from T the tip carries GRAMS (the plant's equation 7: the finger
//!   hangs from its base; 0.2 g pulls a finger bent 10 mm about 0.17 mm back towards hanging
//!   straight).

use std::str::FromStr;

use nalgebra::{Rotation3, Vector3};
use serde::Serialize;

use super::camera::{Camera, Rig};
use super::dynamics::Motion;
use super::plant::{Plant, PlantError, PlantParams, Pressures};

/// What goes wrong, and when.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Fault {
    pub kind: FaultKind,
    pub at_s: f64,
    pub amount: f64,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum FaultKind {
    Camera,
    Pan,
    Stiffness,
    Leak,
    Payload,
}

impl FromStr for Fault {
    type Err = String;

    fn from_str(s: &str) -> Result<Fault, String> {
        let usage = || {
            format!("{s:?} is not a fault: give KIND@T=AMOUNT, KIND one of camera, pan, stiffness, leak, payload (e.g. stiffness@40=-0.1)")
        };
        let (kind, rest) = s.split_once('@').ok_or_else(usage)?;
        let (at, amount) = rest.split_once('=').ok_or_else(usage)?;
        let kind = match kind {
            "camera" => FaultKind::Camera,
            "pan" => FaultKind::Pan,
            "stiffness" => FaultKind::Stiffness,
            "leak" => FaultKind::Leak,
            "payload" => FaultKind::Payload,
            _ => return Err(usage()),
        };
        let number = |v: &str| v.trim().parse::<f64>().ok().filter(|v| v.is_finite());
        let (Some(at_s), Some(amount)) = (number(at), number(amount)) else {
            return Err(usage());
        };
        let fine = match kind {
            FaultKind::Camera | FaultKind::Pan => amount.abs() <= 10.0,
            FaultKind::Stiffness => amount > -0.9 && amount <= 10.0,
            FaultKind::Leak => (0.0..=1.0).contains(&amount),
            FaultKind::Payload => (0.0..=20.0).contains(&amount),
        };
        if at_s < 0.0 || !fine {
            return Err(format!("{s}: the time must be ≥ 0 s and the amount within a camera's ±10°, a stiffness share above −0.9, a leak's share within 0-1, a payload's 0-20 g"));
        }
        Ok(Fault { kind, at_s, amount })
    }
}

/// The finger and the cameras as the faults make them at each instant.
pub struct Timeline {
    before: Plant,
    /// The finger from each change on (a stiffness fault, a payload), in time order, each
    /// with those before it.
    after: Vec<(f64, Plant)>,
    leak: Option<(f64, f64)>,
    /// The second (a pair's right) camera from the camera fault on.
    knocked: Option<(f64, Camera)>,
}

impl Timeline {
    /// The finger of `params` and the cameras of `rig`, changed by `faults` (the first of each
    /// kind).
    pub fn new(params: &PlantParams, rig: &Rig, faults: &[Fault]) -> Timeline {
        let of = |kind| faults.iter().find(|f| f.kind == kind);
        let mut changes: Vec<&Fault> = [FaultKind::Stiffness, FaultKind::Payload]
            .into_iter()
            .filter_map(of)
            .collect();
        changes.sort_by(|a, b| a.at_s.total_cmp(&b.at_s));
        let mut finger = params.clone();
        let after = changes
            .into_iter()
            .map(|f| {
                if f.kind == FaultKind::Payload {
                    finger.tip_load_g = f.amount;
                } else {
                    let scale = 1.0 + f.amount;
                    finger.bend_stiffness_x_nmm2 *= scale;
                    finger.bend_stiffness_y_nmm2 *= scale;
                    finger.axial_stiffness_n *= scale;
                }
                (f.at_s, Plant::new(finger.clone()))
            })
            .collect();
        Timeline {
            before: Plant::new(params.clone()),
            after,
            leak: of(FaultKind::Leak).map(|f| (f.at_s, f.amount)),
            knocked: (faults.iter())
                .filter(|f| matches!(f.kind, FaultKind::Camera | FaultKind::Pan))
                .min_by(|a, b| a.at_s.total_cmp(&b.at_s))
                .map(|f| {
                    let axis = match f.kind {
                        FaultKind::Pan => Vector3::y_axis(),
                        _ => Vector3::x_axis(),
                    };
                    let turn = Rotation3::from_axis_angle(&axis, f.amount.to_radians());
                    let mut right = rig.right().clone();
                    right.pose.rotation = turn * right.pose.rotation;
                    right.pose.translation = turn * right.pose.translation;
                    (f.at_s, right)
                }),
        }
    }

    /// The finger at `t` and what its muscles hold of the pressures `p` commanded then.
    fn finger(&self, t: f64, mut p: Pressures) -> (&Plant, Pressures) {
        if let Some((at, share)) = self.leak {
            p[0] *= 1.0 - share * ((t - at) / 60.0).clamp(0.0, 1.0);
        }
        let changed = self.after.iter().rev().find(|(at, _)| t >= *at);
        (changed.map_or(&self.before, |(_, plant)| plant), p)
    }

    /// The finger as it starts (for what stays put: its base).
    pub fn plant(&self) -> &Plant {
        &self.before
    }

    /// The tip at `t` of the `motion`.
    ///
    /// # Errors
    /// The plant's, for pressures out of its range.
    pub fn tip(&self, motion: &Motion, t: f64) -> Result<[f64; 3], PlantError> {
        let (plant, p) = self.finger(t, motion.at(t));
        plant.tip(p)
    }

    /// The settled tip of pressures `p` commanded at `t`.
    ///
    /// # Errors
    /// As [`Timeline::tip`].
    pub fn settled_tip(&self, t: f64, p: Pressures) -> Result<[f64; 3], PlantError> {
        let (plant, p) = self.finger(t, p);
        plant.tip(p)
    }

    /// The centre line at `t` of the `motion`.
    ///
    /// # Errors
    /// As [`Timeline::tip`].
    pub fn centre_line(&self, motion: &Motion, t: f64) -> Result<Vec<[f64; 3]>, PlantError> {
        let (plant, p) = self.finger(t, motion.at(t));
        plant.centre_line(p)
    }

    /// The camera at place `camera` of `rig` as it is at `t`.
    pub fn camera<'a>(&'a self, rig: &'a Rig, camera: usize, t: f64) -> &'a Camera {
        match (camera, &self.knocked) {
            (1, Some((at, knocked))) if t >= *at => knocked,
            _ => &rig.cameras[camera],
        }
    }

    /// The second camera knocked, and from when.
    pub fn knocked(&self) -> Option<&(f64, Camera)> {
        self.knocked.as_ref()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn faults_parse_and_bad_ones_are_named() {
        let f: Fault = "stiffness@40=-0.1".parse().unwrap();
        assert_eq!(f.kind, FaultKind::Stiffness);
        assert_eq!((f.at_s, f.amount), (40.0, -0.1));
        let f: Fault = "payload@4=0.2".parse().unwrap();
        assert_eq!((f.kind, f.amount), (FaultKind::Payload, 0.2));
        for bad in [
            "stiffness",
            "payload@4=-0.2",
            "mass@4=0.2",
            "leak@x=0.1",
            "leak@10=2",
            "camera@-1=0.5",
        ] {
            assert!(bad.parse::<Fault>().is_err(), "{bad}");
        }
    }

    /// A softer finger bends further from its time on; a leak lowers the tip it gives over the
    /// minute after it, not before; a payload pulls it back from its time on, the finger still
    /// the softer one.
    #[test]
    fn the_finger_changes_at_its_fault_and_not_before() {
        let rig = crate::synth::camera::RigConfig::default().build(1);
        let faults =
            ["payload@90=0.5", "stiffness@10=-0.2", "leak@20=0.5"].map(|f| f.parse().unwrap());
        let timeline = Timeline::new(&PlantParams::default(), &rig, &faults);
        let p = [150.0, 0.0, 0.0];
        let at = |t| timeline.settled_tip(t, p).unwrap();
        let bend = |tip: [f64; 3]| tip[0].hypot(tip[1]);
        assert_eq!(at(0.0), at(9.9));
        assert!(
            bend(at(10.0)) > 1.1 * bend(at(9.9)),
            "{:?} {:?}",
            at(10.0),
            at(9.9)
        );
        assert!(bend(at(80.0)) < 0.8 * bend(at(20.0)));
        assert!(
            (bend(at(50.0)) - 0.5 * (bend(at(20.0)) + bend(at(80.0)))).abs() < 0.3 * bend(at(20.0))
        );
        assert!(bend(at(90.0)) < bend(at(89.9)) - 0.05);
        let q = PlantParams::default();
        let both = Plant::new(PlantParams {
            bend_stiffness_x_nmm2: q.bend_stiffness_x_nmm2 * 0.8,
            bend_stiffness_y_nmm2: q.bend_stiffness_y_nmm2 * 0.8,
            axial_stiffness_n: q.axial_stiffness_n * 0.8,
            tip_load_g: 0.5,
            ..q
        });
        let want = both.tip([75.0, 0.0, 0.0]).unwrap();
        assert!((0..3).all(|k| (at(100.0)[k] - want[k]).abs() < 1e-9));
        assert_eq!(timeline.camera(&rig, 1, 1e6), rig.right());
    }
}
