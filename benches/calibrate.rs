//! `calibrate` on 20 synthetic 1280×720 chessboard pairs (+ the reference pair): detection,
//! both cameras, the stereo calibration and the quality checks. Target (issue: calibrate):
//! under 5 s.
//!
//! Run: `cargo bench --bench calibrate`.

use std::sync::atomic::AtomicBool;

use criterion::{criterion_group, criterion_main, Criterion};

use handcap::calib::{self, CalibOptions};
use handcap::provenance::Provenance;
use handcap::synth::capture::{self, CaptureConfig};
use handcap::synth::SynthConfig;

fn bench(c: &mut Criterion) {
    let dir = tempfile::tempdir().expect("temp dir");
    let synth = SynthConfig {
        grid_step_kpa: 250.0,
        sweep_step_kpa: 250.0,
        ..SynthConfig::default()
    };
    let config = CaptureConfig::default();
    capture::write_capture(
        dir.path(),
        &synth,
        &config,
        &Provenance::new(vec!["bench".into()], None),
        &|_, _| {},
        &AtomicBool::new(false),
    )
    .expect("capture");
    let board = config.board;
    let mut g = c.benchmark_group("calibrate");
    g.sample_size(10);
    g.bench_function("20 pairs 1280x720", |b| {
        b.iter(|| {
            calib::calibrate(
                &dir.path().join("calib"),
                &board,
                &CalibOptions::default(),
                &|_, _| {},
            )
            .expect("calibrates")
        })
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
