//! MSVR fit time at n = 250, 1000, 2000 samples (3 pressures → 3 tip coordinates), on random
//! pressures through the virtual micro-hand with 0.02 mm noise and the paper's Table 2
//! parameters, with the paper's quadratic loss and the robust one. Targets (DESIGN.md): n = 1000
//! in ≤ 0.15 s, n = 2000 in ≤ 1 s. And the default search (ACO_R, robust loss, 5 folds, racing)
//! on 1000 rows × 6 inputs (two virtual hands in series), at 40 candidates to keep the
//! benchmark short; the default budget for 1000 rows is 120. The reduced basis: 400 centres at
//! n = 2000 and 200 centres at n = 20 000; and `--basis auto` on 360 000 rows (its choice of
//! basis and the fit on every row; target ≤ 60 s in ≤ 2 GB, the peak memory printed). The
//! intervals' widening: calibrated on 3000 rows of 12 inputs, and the factors of 7,620 rows.
//!
//! Run: `cargo bench --bench msvr`.

use std::hint::black_box;
use std::sync::OnceLock;

use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

use handcap::data::{names, Columns, Dataset, HAND_INPUTS, HAND_OUTPUTS};
use std::sync::atomic::AtomicBool;

use handcap::model::interval::Widening;
use handcap::model::msvr::PAPER_TABLE2;
use handcap::model::msvr::{Basis, Hyper, Loss, MsvrParams, ValidMsvrParams};
use handcap::model::Predict;
use handcap::search::aco_r::AcoR;
use handcap::search::Method;
use handcap::select::fitness::FitnessKind;
use handcap::select::folds::{self, FoldsBy};
use handcap::select::tune;
use handcap::select::tune::BasisChoice;
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
        weights: None,
    }
}

/// Six pressures → tip: two virtual hands in series (the tips add).
fn random_six_input_data(n: usize, seed: u64) -> Dataset {
    let (a, b) = (random_hand_data(n, seed), random_hand_data(n, seed + 1));
    let inputs = (0..n)
        .flat_map(|i| [a.inputs.row(i), b.inputs.row(i)].concat())
        .collect();
    let outputs = (0..n)
        .flat_map(|i| {
            let (p, q) = (a.outputs.row(i), b.outputs.row(i));
            [p[0] + q[0], p[1] + q[1], p[2] + q[2]]
        })
        .collect();
    Dataset {
        source: "bench".into(),
        inputs: Columns::new((0..6).map(|i| format!("p{i}_kPa")).collect(), inputs),
        outputs: Columns::new(names(&HAND_OUTPUTS), outputs),
        weights: None,
    }
}

fn fit(c: &mut Criterion) {
    let mut group = c.benchmark_group("msvr_fit");
    group.sample_size(10);
    for loss in [Loss::Quadratic, Loss::Robust] {
        let params = MsvrParams::default()
            .with_hyper(PAPER_TABLE2)
            .loss(loss)
            .check()
            .unwrap();
        for n in [250, 1000, 2000] {
            let data = random_hand_data(n, 1);
            let model = params.fit(&data).unwrap();
            eprintln!(
                "{loss} loss, n = {n}: {} iterations, {} support vectors, converged {}",
                model.fit.iterations, model.fit.support_vectors, model.fit.converged
            );
            group.bench_with_input(BenchmarkId::new(loss.to_string(), n), &data, |b, data| {
                b.iter(|| params.fit(black_box(data)).unwrap())
            });
        }
    }
    group.finish();
}

/// The reduced basis: 400 centres at n = 2000 (beside the exact fit above) and 200 centres at
/// n = 20 000, Table 2's parameters, robust loss.
fn fit_reduced(c: &mut Criterion) {
    let mut group = c.benchmark_group("msvr_fit_reduced");
    group.sample_size(10);
    for (n, centres) in [(2000, 400), (20_000, 200)] {
        let params = MsvrParams::default()
            .with_hyper(PAPER_TABLE2)
            .loss(Loss::Robust)
            .basis(Basis::Reduced { centres, seed: 1 })
            .check()
            .unwrap();
        let data = random_hand_data(n, 1);
        let model = params.fit(&data).unwrap();
        eprintln!(
            "{centres} centres, n = {n}: {} iterations, {} kept, converged {}",
            model.fit.iterations, model.fit.support_vectors, model.fit.converged
        );
        group.bench_with_input(
            BenchmarkId::new(format!("{centres}_centres"), n),
            &data,
            |b, data| b.iter(|| params.fit(black_box(data)).unwrap()),
        );
    }
    group.finish();
}

/// `--basis auto` on a long log, 360 000 rows (an hour at 100 Hz), as `handcap model --search
/// none` runs it: the first basis, its growth scored on the search's evenly spaced rows (5
/// folds), and the fit on every row. The whole runs once, each step timed and printed; the
/// benchmark repeats the fit on every row at the basis chosen. All of it only when this
/// benchmark is run: running the others builds none of it.
fn fit_auto_large(c: &mut Criterion) {
    let chosen: OnceLock<(Dataset, ValidMsvrParams)> = OnceLock::new();
    let mut group = c.benchmark_group("msvr_fit_auto");
    group.sample_size(10);
    group.bench_function("360000_rows", |b| {
        let (data, params) = chosen.get_or_init(auto_once);
        b.iter(|| params.fit(black_box(data)).unwrap())
    });
    group.finish();
}

/// The 360 000 rows and the parameters `auto` chose for them, each step timed and printed.
fn auto_once() -> (Dataset, ValidMsvrParams) {
    let data = random_hand_data(360_000, 5);
    let solver = MsvrParams::default()
        .with_hyper(PAPER_TABLE2)
        .loss(Loss::Robust);
    let clock = std::time::Instant::now();
    let start = tune::initial_basis(BasisChoice::Auto, data.rows(), 1).unwrap();
    let scored = data.subsample(tune::SEARCH_ROWS);
    let plan = folds::plan(&FoldsBy::Auto, &scored, &[], 5).unwrap();
    // `handcap model --basis auto` with the parameters given: the growth at them.
    let choice = tune::Choice {
        rows: &scored,
        fitness: FitnessKind::Cv { folds: 5 },
        folds: &plan,
        search: None,
        axes: &Hyper::AXES,
        pinned: tune::Pinned::default(),
        grow: true,
        score: false,
    };
    let never = AtomicBool::new(false);
    let chosen = tune::choose(&choice, &solver, start, &mut (), &never).unwrap();
    let grown = clock.elapsed().as_secs_f64();
    let params = chosen.params.check().unwrap();
    let model = params.fit(&data).unwrap();
    eprintln!(
        "auto, n = {}: {} ({}): chosen in {grown:.1} s, fitted on every row in {:.1} s ({} iterations, converged {}); peak memory {:.2} GB",
        data.rows(),
        chosen.basis.basis,
        chosen.basis.reason,
        clock.elapsed().as_secs_f64() - grown,
        model.fit.iterations,
        model.fit.converged,
        peak_memory_gb()
    );
    (data, params)
}

/// The process's peak resident memory.
fn peak_memory_gb() -> f64 {
    // SAFETY: getrusage fills the struct it is given.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    unsafe { libc::getrusage(libc::RUSAGE_SELF, &mut usage) };
    usage.ru_maxrss as f64 / 1024.0 / 1024.0
}

fn search(c: &mut Criterion) {
    let data = random_six_input_data(1000, 4);
    let method = Method::AcoR(AcoR {
        budget: 40,
        ..AcoR::default()
    });
    let solver = MsvrParams::default().loss(Loss::Robust);
    let plan = folds::plan(&FoldsBy::Auto, &data, &[], 5).unwrap();
    let mut group = c.benchmark_group("search");
    group.sample_size(10);
    group.bench_function("aco_r_40_candidates_1000x6", |b| {
        b.iter(|| {
            tune::run(
                &method,
                black_box(&data),
                FitnessKind::Cv { folds: 5 },
                1,
                &plan,
                &solver,
                &Hyper::AXES,
                &tune::Pinned::default(),
                &mut (),
                &AtomicBool::new(false),
            )
            .unwrap()
        })
    });
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

/// The intervals' widening at a search's size: calibrated on 3000 rows of 12 inputs in 5 folds
/// (1000 centres per fold), then the factors of 7,620 rows (`predict --interval` of a
/// 30 Hz session).
fn widening(c: &mut Criterion) {
    let x = random_six_input_data(3000, 4).inputs;
    let wide = Columns::new(
        (0..12).map(|i| format!("u{i}")).collect(),
        (0..x.rows())
            .flat_map(|i| [x.row(i), x.row((i * 7) % x.rows())].concat())
            .collect(),
    );
    let fold_of: Vec<usize> = (0..wide.rows()).map(|i| i * 5 / wide.rows()).collect();
    let mut group = c.benchmark_group("interval_widening");
    group.sample_size(10);
    group.bench_function("calibrate_3000x12", |b| {
        b.iter(|| Widening::calibrate(black_box(&wide), &fold_of, 1.4, 6600.0, 7).unwrap())
    });
    let (widening, _) = Widening::calibrate(&wide, &fold_of, 1.4, 6600.0, 7).unwrap();
    let queries = Columns::new(
        wide.names.clone(),
        wide.values
            .iter()
            .cycle()
            .take(7620 * 12)
            .copied()
            .collect(),
    );
    group.bench_function("factors_7620_rows", |b| {
        b.iter(|| widening.widener().unwrap().factors(black_box(&queries)))
    });
    group.finish();
}

criterion_group!(
    benches,
    fit,
    fit_reduced,
    fit_auto_large,
    search,
    predict,
    widening
);
criterion_main!(benches);
