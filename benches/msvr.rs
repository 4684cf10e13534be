//! MSVR fit time at n = 250, 1000, 2000 samples (3 pressures → 3 tip coordinates), on random
//! pressures through the virtual micro-hand with 0.02 mm noise and the paper's Table 2
//! parameters. Targets (DESIGN.md): n = 1000 in ≤ 0.15 s, n = 2000 in ≤ 1 s.
//!
//! Run: `cargo bench --bench msvr`.

use std::hint::black_box;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

use handcap::data::{names, Columns, Dataset, HAND_INPUTS, HAND_OUTPUTS};
use handcap::model::msvr::MsvrParams;
use handcap::model::Predict;
use handcap::search::aco_paper::PAPER_TABLE2;
use handcap::synth::plant::Plant;

fn random_hand_data(n: usize, seed: u64) -> Dataset {
    let plant = Plant::default();
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let noise = Normal::new(0.0, 0.02).unwrap();
    let mut x = Vec::with_capacity(3 * n);
    let mut y = Vec::with_capacity(3 * n);
    for _ in 0..n {
        let p: [f64; 3] = std::array::from_fn(|_| rng.random_range(0.0..=250.0));
        let tip = plant.tip(p).unwrap();
        x.extend(p);
        y.extend(tip.map(|v| v + noise.sample(&mut rng)));
    }
    Dataset {
        source: "bench".into(),
        inputs: Columns::new(names(&HAND_INPUTS), x),
        outputs: Columns::new(names(&HAND_OUTPUTS), y),
    }
}

fn fit(c: &mut Criterion) {
    let params = MsvrParams::default()
        .with_hyper(PAPER_TABLE2)
        .check()
        .unwrap();
    let mut group = c.benchmark_group("msvr_fit");
    group.sample_size(10);
    for n in [250, 1000, 2000] {
        let data = random_hand_data(n, 1);
        let model = params.fit(&data).unwrap();
        eprintln!(
            "n = {n}: {} iterations, {} support vectors, converged {}",
            model.fit.iterations, model.fit.support_vectors, model.fit.converged
        );
        group.bench_with_input(BenchmarkId::from_parameter(n), &data, |b, data| {
            b.iter(|| params.fit(black_box(data)).unwrap())
        });
    }
    group.finish();
}

fn predict(c: &mut Criterion) {
    let params = MsvrParams::default()
        .with_hyper(PAPER_TABLE2)
        .check()
        .unwrap();
    let model = params.fit(&random_hand_data(216, 2)).unwrap();
    let queries = random_hand_data(100_000, 3);
    let mut group = c.benchmark_group("msvr_predict");
    group.sample_size(10);
    group.bench_function("100k_points", |b| {
        b.iter(|| model.predict(black_box(&queries.inputs)).unwrap())
    });
    group.finish();
}

criterion_group!(benches, fit, predict);
criterion_main!(benches);
