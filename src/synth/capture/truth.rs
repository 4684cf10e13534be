//! The ground truth a capture writes beside its images (`truth/`), and the regulator's log.

use nalgebra::{Matrix3, Point3};

use super::boards::Sighted;
use super::timing::{occluder, Filmed};
use super::{CaptureConfig, SynthError};
use crate::data::{Csv, HAND_INPUTS, HAND_OUTPUTS};
use crate::opencv_yaml::FileStorage;
use crate::session::protocol::Step;
use crate::synth::camera::Rig;
use crate::synth::dynamics::Motion;
use crate::synth::faults::Timeline;

fn mat3(m: &Matrix3<f64>) -> Vec<f64> {
    (0..3)
        .flat_map(|r| (0..3).map(move |c| m[(r, c)]))
        .collect()
}

pub(crate) fn rig_yaml(rig: &Rig, provenance: &crate::provenance::Provenance) -> String {
    let cams = rig.stereo();
    // The virtual world is the hand frame: the left camera's pose inverted.
    let hand_from_left = rig.left().pose.inverse();
    let mut fs = FileStorage::new();
    crate::calib::file::write_rig(&mut fs, &cams)
        .matrix("E", 3, 3, &mat3(&cams.essential()))
        .matrix("F", 3, 3, &mat3(&cams.fundamental()))
        .matrix("R_hand", 3, 3, &hand_from_left.rotation_rows())
        .matrix("t_hand", 3, 1, &hand_from_left.translation_array())
        .string("handcap_version", &provenance.handcap_version)
        .string("command", &provenance.command.join(" "));
    if let Some(seed) = provenance.seed {
        fs.int("seed", seed as i64);
    }
    fs.text().to_string()
}

/// A rig of more than two cameras as `calibrate` writes it (Anipose's TOML): the first
/// camera's frame the world, the hand frame's axes as `hand_rotation`.
pub(super) fn cameras_toml(rig: &Rig) -> String {
    use crate::calib::file::AniposeCamera;
    use crate::geometry::{relative, CamFromWorld};
    let (names, first) = (rig.names(), rig.left().pose);
    let cameras: Vec<AniposeCamera> = rig
        .cameras
        .iter()
        .zip(&names)
        .map(|(cam, name)| {
            let between = relative(&first, &cam.pose);
            AniposeCamera {
                name,
                size: [cam.width as i32, cam.height as i32],
                intrinsics: &cam.intrinsics,
                pose: CamFromWorld::new(between.rotation, between.translation),
            }
        })
        .collect();
    crate::calib::file::cameras_toml(&cameras, 0.0, Some(first.rotation.inverse()))
}

/// Each board's pose in the first (left) camera, the reference (last) as `ref`.
pub(super) fn boards_csv(rig: &Rig, boards: &[Sighted]) -> String {
    let mut csv = Csv::new(["view", "rx", "ry", "rz", "tx_mm", "ty_mm", "tz_mm"]);
    for (k, b) in boards.iter().enumerate() {
        let name = if k + 1 == boards.len() {
            "ref".to_string()
        } else {
            format!("{k:02}")
        };
        let left_from_board = b.board.pose.then(&rig.left().pose);
        let (r, t) = (
            left_from_board.rotation.scaled_axis(),
            left_from_board.translation,
        );
        csv.row(
            [name]
                .into_iter()
                .chain(text([r.x, r.y, r.z, t.x, t.y, t.z])),
        );
    }
    csv.into_string()
}

/// Numbers as `Display` writes them (the shortest form that reads back the same).
fn text<const N: usize>(values: [f64; N]) -> [String; N] {
    values.map(|v| v.to_string())
}

/// The regulator's log: each step at its command time `starts`.
pub(super) fn pressures_csv(steps: &[Step], starts: &[f64]) -> String {
    crate::session::pressures::pressures_csv(steps.iter().zip(starts).map(|(s, &time_s)| {
        crate::session::pressures::Logged {
            time_s,
            command_end_s: None,
            hold_s: s.hold_s,
            pressures_kpa: s.pressures,
            step: s.step,
            phase: &s.phase,
            measured_kpa: None,
        }
    }))
}

/// Per step the settled tip in the hand frame and in the first camera's (`left_x_mm` … of a
/// pair, `cam1_x_mm` … of more cameras).
pub(super) fn tips_csv(rig: &Rig, steps: &[Step], tips: &[[f64; 3]]) -> String {
    let first = &rig.names()[0];
    let mut csv = Csv::new(
        ["step", "phase"]
            .into_iter()
            .map(String::from)
            .chain(HAND_INPUTS.map(String::from))
            .chain(HAND_OUTPUTS.map(String::from))
            .chain(["x", "y", "z"].map(|a| format!("{first}_{a}_mm"))),
    );
    for (
        k,
        (
            Step {
                phase,
                pressures: p,
                ..
            },
            tip,
        ),
    ) in steps.iter().zip(tips).enumerate()
    {
        let left = rig.left().pose.apply(&Point3::from(*tip));
        csv.row(
            [k.to_string(), phase.clone()]
                .into_iter()
                .chain(text([p[0], p[1], p[2], tip[0], tip[1], tip[2]]))
                .chain(text([left.x, left.y, left.z])),
        );
    }
    csv.into_string()
}

pub(super) fn truth_frames(
    rig: &Rig,
    timeline: &Timeline,
    motion: &Motion,
    seed: u64,
    c: &CaptureConfig,
    frames: &[Filmed],
) -> Result<String, SynthError> {
    let mut csv = Csv::new(
        ["frame", "camera", "exposure_s", "step"]
            .into_iter()
            .chain(HAND_OUTPUTS)
            .chain(["u_px", "v_px", "occluded"]),
    );
    let names = rig.names();
    for f in frames {
        let tip = timeline.tip(motion, f.exposure_s)?;
        let cam = timeline.camera(rig, f.camera, f.exposure_s);
        let [u, v] = cam
            .project(&Point3::from(tip))
            .unwrap_or([f64::NAN, f64::NAN]);
        let occluded = occluder(seed, c, f.camera, f.index).is_some();
        csv.row(
            [
                f.index.to_string(),
                names[f.camera].clone(),
                format!("{:.6}", f.exposure_s),
                f.step.to_string(),
            ]
            .into_iter()
            .chain(text([tip[0], tip[1], tip[2], u, v]))
            .chain([u8::from(occluded).to_string()]),
        );
    }
    Ok(csv.into_string())
}

/// A dynamic session's truth as the dataset `triangulate --per-frame` should give: one row per
/// frame of the first (left) camera, at its timestamp, the command in force then and the true tip at its exposure
/// (`time_s,phase,P1_kpa,P2_kpa,P3_kpa,x_mm,y_mm,z_mm,frame,exposure_s`).
pub(super) fn per_frame_csv(
    timeline: &Timeline,
    motion: &Motion,
    steps: &[Step],
    frames: &[Filmed],
) -> Result<String, SynthError> {
    let mut csv = Csv::new(
        ["time_s", "phase"]
            .into_iter()
            .chain(HAND_INPUTS)
            .chain(HAND_OUTPUTS)
            .chain(["frame", "exposure_s"]),
    );
    for f in frames.iter().filter(|f| f.camera == 0) {
        let tip = timeline.tip(motion, f.exposure_s)?;
        let Step {
            phase,
            pressures: p,
            ..
        } = &steps[f.step];
        csv.row(
            [format!("{:.6}", f.stamp_s), phase.clone()]
                .into_iter()
                .chain(text([p[0], p[1], p[2], tip[0], tip[1], tip[2]]))
                .chain([f.index.to_string(), format!("{:.6}", f.exposure_s)]),
        );
    }
    Ok(csv.into_string())
}
