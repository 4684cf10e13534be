//! Speed of the monitor per row, so that it runs at the cameras' rate: the band, the
//! exceedance and response tests and the camera's over an hour of rows at 30 fps
//! (`monitor::watch`). The model's prediction of the
//! rows, the rest of `handcap monitor`'s cost, is `predict`'s (`cargo bench --bench msvr`).
//!
//! Run: `cargo bench --bench monitor`.

use std::hint::black_box;

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use handcap::monitor::{watch, Outputs, Series, Settings};

fn bench(c: &mut Criterion) {
    let n = 30 * 3600;
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let times: Vec<f64> = (0..n).map(|k| k as f64 / 30.0).collect();
    let errors: Vec<f64> = (0..n).map(|_| rng.random::<f64>()).collect();
    let residuals: Vec<f64> = (0..n).map(|_| 0.1 * rng.random::<f64>()).collect();
    let predicted: Vec<f64> = (0..3 * n).map(|_| 8.0 * rng.random::<f64>()).collect();
    let measured: Vec<f64> = predicted
        .iter()
        .map(|p| p + 0.1 * rng.random::<f64>())
        .collect();
    let mut group = c.benchmark_group("monitor");
    group.throughput(Throughput::Elements(n as u64));
    group.bench_function("watch an hour at 30 fps (every test)", |b| {
        b.iter(|| {
            let errors = Series {
                times: &times,
                values: &errors,
            };
            let geometry = Series {
                times: &times,
                values: &residuals,
            };
            let outputs = Outputs {
                predicted: &predicted,
                measured: &measured,
                rest: &[0.0; 3],
            };
            let m = watch(
                errors,
                Some(geometry),
                &[],
                Some(outputs),
                0.9,
                &Settings::default(),
            );
            black_box(m.coverage)
        })
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
