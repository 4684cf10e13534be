//! Every reader of a user's file, on bytes it was never meant to read: no panic, ever; an
//! `Err` (or, for damage that leaves a valid file, an `Ok`). The inputs are arbitrary bytes and
//! real files cut short, overwritten here and there or spliced with noise, which reach deeper
//! into each parser than random bytes do.
//!
//! CI runs proptest's default 256 cases per reader; `scripts/fuzz.sh` runs many more
//! (`PROPTEST_CASES`).

use std::path::Path;

use proptest::prelude::*;

use handcap::calib::file::{read_board, read_calibration};
use handcap::data::read_dataset;
use handcap::model::file::ModelFile;
use handcap::session::frames::read_frame_list;
use handcap::session::pressures::read_pressure_log;

const CSV: &str = "P1_kpa,P2_kpa,P3_kpa,x_mm,y_mm,z_mm\n0,0,0,0,0,0\n50,0,0,0.12,-1.5,0.3\n\
                   100,50,0,\"0.5\",-2.25,1e-3\n150,100,50,1.5,-3,0.9\n";
const LOG: &str = "time_s,P1_kpa,P2_kpa,P3_kpa,step,phase\n0.000,0,0,0,0,train\n\
                   0.300,0,0,125,1,train\n0.600,0,125,0,2,sweep_a\n0.900,0,0,0,3,sweep_a\n";
const FRAMES: &str = "frame,camera,time_s\n0,left,0.105\n1,left,0.138\n0,right,0.11\n";
const BOARD: &str = include_str!("../../calib/board.yml");
const CALIBRATION: &str = include_str!("../../calib/example_calib.yml");

/// Arbitrary bytes, or `sample` damaged: cut short, bytes overwritten, noise spliced in.
fn damaged(sample: &'static str) -> impl Strategy<Value = Vec<u8>> {
    let bytes = sample.as_bytes().to_vec();
    let n = bytes.len();
    prop_oneof![
        prop::collection::vec(any::<u8>(), 0..512),
        (0..=n).prop_map({
            let b = bytes.clone();
            move |k| b[..k].to_vec()
        }),
        prop::collection::vec((0..n, any::<u8>()), 1..8).prop_map({
            let b = bytes.clone();
            move |edits| {
                let mut b = b.clone();
                for (k, v) in edits {
                    b[k] = v;
                }
                b
            }
        }),
        (0..=n, prop::collection::vec(any::<u8>(), 1..64)).prop_map(move |(k, noise)| {
            let mut b = bytes.clone();
            b.splice(k..k, noise);
            b
        }),
    ]
}

/// Writes `bytes` as `name` in a fresh directory and runs `read` on it.
fn on_file<T>(name: &str, bytes: &[u8], read: impl FnOnce(&Path) -> T) -> T {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join(name);
    std::fs::write(&path, bytes).unwrap();
    read(&path)
}

fn names(list: &str) -> Vec<String> {
    list.split(',').map(str::to_string).collect()
}

proptest! {
    #[test]
    fn the_csv_reader_never_panics(bytes in damaged(CSV)) {
        let read = on_file("d.csv", &bytes, |p| {
            read_dataset(p, &names("P1_kpa,P2_kpa,P3_kpa"), &names("x_mm,y_mm,z_mm"))
        });
        if let Ok(d) = read {
            prop_assert!(d.inputs.values.iter().chain(&d.outputs.values).all(|v| v.is_finite()));
        }
    }

    #[test]
    fn the_pressure_log_reader_never_panics(bytes in damaged(LOG)) {
        let _ = on_file("pressures.csv", &bytes, read_pressure_log);
    }

    #[test]
    fn the_frame_index_reader_never_panics(bytes in damaged(FRAMES)) {
        let _ = on_file("frames.csv", &bytes, |p| read_frame_list(p.parent().unwrap()));
    }

    #[test]
    fn the_model_file_reader_never_panics(bytes in damaged(MODEL)) {
        let _ = on_file("m.json", &bytes, ModelFile::load);
    }

    #[test]
    fn the_opencv_yaml_readers_never_panic(
        board in damaged(BOARD),
        calibration in damaged(CALIBRATION),
    ) {
        let _ = on_file("board.yml", &board, read_board);
        if let Ok(c) = on_file("calib.yml", &calibration, read_calibration) {
            // What reads is usable: a rotation, a positive focal length.
            prop_assert!(c.rig.left.fx() > 0.0 && c.rig.right.fx() > 0.0);
            prop_assert!(c.rig.right_from_left.rotation.matrix().determinant() > 0.0);
        }
    }
}

/// A small model file as `handcap model` writes it (two inputs, one output, three support
/// vectors).
const MODEL: &str = r#"{
  "format": "handcap-model",
  "version": 1,
  "kind": "msvr",
  "model": {
    "inputs": ["a", "b"],
    "outputs": ["y"],
    "params": {"c": 10.0, "epsilon": 0.1, "sigma": 0.5, "tol": 1e-6, "max_iter": 100},
    "scaler": {"min": [0.0, 0.0], "max": [1.0, 2.0]},
    "support_vectors": [[0.0, 0.0], [0.5, 0.5], [1.0, 1.0]],
    "coefficients": [[0.5], [-0.25], [1.0]],
    "bias": [0.1],
    "fit": {"rows": 3, "iterations": 2, "objective": 0.5, "support_vectors": 3, "converged": true, "stop": "tolerance"}
  },
  "provenance": {"handcap_version": "0", "command": ["handcap"], "seed": null, "inputs": []}
}"#;

#[test]
fn the_undamaged_samples_read() {
    on_file("d.csv", CSV.as_bytes(), |p| {
        read_dataset(p, &names("P1_kpa,P2_kpa,P3_kpa"), &names("x_mm,y_mm,z_mm")).unwrap()
    });
    on_file("pressures.csv", LOG.as_bytes(), read_pressure_log).unwrap();
    on_file("frames.csv", FRAMES.as_bytes(), |p| {
        read_frame_list(p.parent().unwrap())
    })
    .unwrap();
    on_file("m.json", MODEL.as_bytes(), ModelFile::load).unwrap();
    on_file("board.yml", BOARD.as_bytes(), read_board).unwrap();
    on_file("calib.yml", CALIBRATION.as_bytes(), read_calibration).unwrap();
}
