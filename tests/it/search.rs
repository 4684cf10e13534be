//! Hyper-parameter searches on cheap objectives with a known optimum, and the MSVR fitness.

use std::sync::atomic::AtomicBool;

use handcap::data::Dataset;
use handcap::model::msvr::MsvrParams;
use handcap::model::msvr::{Hyper, PAPER_TABLE2 as T2};
use handcap::search::aco_paper::{decode, is_valid_path, AcoPaper};
use handcap::search::aco_r::AcoR;
use handcap::search::grid::Grid;
use handcap::search::{Method, Point, Search, SearchSpace, SearchStop};
use handcap::select::fitness::{Fitness, FitnessKind};
use handcap::select::tune;
use handcap::synth::{self, SynthConfig};

/// A cheap objective whose optimum is the paper's Table 2 : the
/// relative distance from it, plus 0.01.
fn table2_bowl(batch: &[Point], _bar: f64) -> Vec<f64> {
    batch
        .iter()
        .map(Hyper::from_point)
        .map(|h| {
            if h.check().is_err() {
                return f64::INFINITY;
            }
            0.01 + ((h.c / T2.c).ln().abs()
                + (h.epsilon / T2.epsilon).ln().abs()
                + (h.sigma / T2.sigma).ln().abs())
                / 3.0
        })
        .collect()
}

/// The same optimum with distances measured in each parameter's digit range (C to 999.9, ε to
/// 0.9999, σ to 9.999), the scale the paper's colony resolves, plus 0.05.
fn table2_linear(batch: &[Point], _bar: f64) -> Vec<f64> {
    batch
        .iter()
        .map(Hyper::from_point)
        .map(|h| {
            if h.check().is_err() {
                return f64::INFINITY;
            }
            0.05 + (h.c - T2.c).abs() / 999.9
                + (h.epsilon - T2.epsilon).abs() / 0.9999
                + (h.sigma - T2.sigma).abs() / 9.999
        })
        .collect()
}

/// A batch's (C, ε, σ).
fn hypers(batch: &[Point]) -> Vec<Hyper> {
    batch.iter().map(Hyper::from_point).collect()
}

fn never() -> AtomicBool {
    AtomicBool::new(false)
}

#[test]
fn aco_paper_is_deterministic_per_seed() {
    let aco = AcoPaper {
        max_iter: 15,
        ..AcoPaper::default()
    };
    let a = aco.run(&table2_bowl, &mut (), &never()).unwrap();
    let b = aco.run(&table2_bowl, &mut (), &never()).unwrap();
    assert_eq!(a, b);
    let c = AcoPaper { seed: 99, ..aco }
        .run(&table2_bowl, &mut (), &never())
        .unwrap();
    assert_ne!(a.history, c.history);
}

#[test]
fn aco_paper_finds_the_optimum_in_most_seeded_runs() {
    // The colony ends within 0.05 (summed range-relative distance) of the optimum in at least 16
    // of 20 seeds. A random search of the same 1600 paths gets there with probability ≈ 0.24
    // (the L1 ball of radius 0.05 holds 1.7e-4 of the box). The colony rarely hits the exact
    // digits: with Δτ = 1/L ≫ τ0 it commits to its first good paths within a few iterations.
    let runs = 20;
    let mut hits = 0;
    let mut bests = Vec::new();
    for seed in 0..runs {
        let r = AcoPaper {
            seed,
            ..AcoPaper::default()
        }
        .run(&table2_linear, &mut (), &never())
        .unwrap();
        bests.push(r.best_fitness);
        if r.best_fitness < 0.05 + 0.05 {
            hits += 1;
        }
    }
    assert!(
        hits >= 16,
        "optimum reached in {hits} of {runs} runs: {bests:?}"
    );
}

#[test]
fn aco_paper_stops_when_every_ant_takes_the_same_path() {
    // Fast evaporation makes the colony commit: every ant soon walks the same path.
    let aco = AcoPaper {
        rho: 0.9,
        ..AcoPaper::default()
    };
    let r = aco.run(&table2_bowl, &mut (), &never()).unwrap();
    assert_eq!(r.stop, SearchStop::SamePath);
    assert!(
        r.history.len() < aco.max_iter,
        "{} iterations",
        r.history.len()
    );
    // On the last iteration all ants scored the same.
    let last = r.history.last().unwrap();
    assert_eq!(last.min, last.max);
}

#[test]
fn aco_paper_paths_with_a_zero_parameter_are_invalid() {
    assert!(!is_valid_path(&decode(&[0; 12])));
    assert!(!is_valid_path(&decode(&[
        1, 0, 0, 0, 0, 0, 0, 0, 1, 0, 0, 0
    ]))); // ε = 0
    assert!(is_valid_path(&decode(&[
        0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1
    ]))); // smallest values
          // ε = 0 is a valid MSVR parameter (kernel ridge regression): the zero rule is the
          // encoding's, not the model's.
    assert!(
        Hyper::from_point(&decode(&[1, 0, 0, 0, 0, 0, 0, 0, 1, 0, 0, 0]))
            .check()
            .is_ok()
    );
}

#[test]
fn interrupted_search_keeps_its_best() {
    let stop = AtomicBool::new(true);
    let err = AcoPaper::default()
        .run(&table2_bowl, &mut (), &stop)
        .unwrap_err();
    assert_eq!(err, handcap::search::SearchError::NothingValid);
    // Interrupt after a few iterations through the observer.
    struct StopAfter<'a>(usize, &'a AtomicBool);
    impl handcap::search::Observer for StopAfter<'_> {
        fn iteration(&mut self, r: &handcap::search::IterationRecord) {
            if r.iteration == self.0 {
                self.1.store(true, std::sync::atomic::Ordering::SeqCst);
            }
        }
    }
    let flag = never();
    let r = AcoPaper::default()
        .run(&table2_bowl, &mut StopAfter(3, &flag), &flag)
        .unwrap();
    assert_eq!(r.stop, SearchStop::Interrupted);
    assert_eq!(r.history.len(), 3);
}

fn table2_space() -> SearchSpace {
    SearchSpace::default()
        .with("c", (0.1, 1e5))
        .with("epsilon", (1e-4, 1.0))
        .with("sigma", (0.01, 5.0))
}

#[test]
fn aco_r_finds_the_optimum_in_most_seeded_runs() {
    let runs = 20;
    let hits = (0..runs)
        .filter(|&seed| {
            let r = AcoR {
                seed,
                ..AcoR::default()
            }
            .run(&table2_space(), &table2_bowl, &mut (), &never())
            .unwrap();
            r.best_fitness < 0.01 + 0.05
        })
        .count();
    assert!(hits >= 16, "optimum reached in {hits} of {runs} runs");
}

#[test]
fn aco_r_is_deterministic_and_keeps_its_budget() {
    let aco = AcoR {
        budget: 100,
        ..AcoR::default()
    };
    let a = aco
        .run(&table2_space(), &table2_bowl, &mut (), &never())
        .unwrap();
    let b = aco
        .run(&table2_space(), &table2_bowl, &mut (), &never())
        .unwrap();
    assert_eq!(a, b);
    let scored: usize = a.history.iter().map(|r| r.valid).sum();
    assert_eq!(scored, 100);
    assert_eq!(a.stop, SearchStop::Budget);
}

#[test]
fn grid_covers_the_box_log_evenly() {
    let grid = Grid {
        budget: 125,
        batch: 20,
    };
    assert_eq!(grid.per_axis(3), 5);
    let seen = std::sync::Mutex::new(Vec::new());
    let record = |batch: &[Point], _bar: f64| {
        seen.lock()
            .unwrap()
            .extend(batch.iter().map(Hyper::from_point));
        table2_bowl(batch, _bar)
    };
    let r = grid
        .run(&table2_space(), &record, &mut (), &never())
        .unwrap();
    let seen = seen.into_inner().unwrap();
    assert_eq!(seen.len(), 125);
    let mut cs: Vec<f64> = seen.iter().map(|h| h.c).collect();
    cs.sort_by(f64::total_cmp);
    cs.dedup();
    assert_eq!(cs.len(), 5);
    assert!((cs[0] - 0.1).abs() < 1e-12 && (cs[4] - 1e5).abs() < 1e-6);
    assert!(
        (cs[1] / cs[0] - cs[2] / cs[1]).abs() < 1e-9,
        "not log-spaced: {cs:?}"
    );
    assert!(r.best_fitness >= 0.01);
}

/// A bowl over any named axes: the mean distance in decades from `optimum`, plus 0.01.
fn bowl(optimum: &Point) -> impl Fn(&[Point], f64) -> Vec<f64> + Sync + '_ {
    move |batch: &[Point], _bar: f64| {
        batch
            .iter()
            .map(|p| {
                let far: f64 = optimum
                    .iter()
                    .map(|(name, best)| (p.get(name).unwrap() / best).log10().abs())
                    .sum();
                0.01 + far / optimum.len() as f64
            })
            .collect()
    }
}

/// The searches take any number of named axes: ACO_R finds a 5-axis optimum, the grid spreads
/// ⌊B^(1/d)⌋ values over each of d axes, the last axis varying slowest, and both name every
/// candidate's values by the box's axes.
#[test]
fn searches_take_any_named_axes() {
    let names = ["gain", "lag", "width", "ridge", "tau"];
    let optimum: Point = names.into_iter().zip([3.0, 0.2, 40.0, 1e-3, 7.0]).collect();
    let space: SearchSpace = names.into_iter().map(|n| (n, (1e-4, 1e3))).collect();
    let hits = (0..10)
        .filter(|&seed| {
            let r = AcoR {
                seed,
                budget: 1000,
                ..AcoR::default()
            }
            .run(&space, &bowl(&optimum), &mut (), &never())
            .unwrap();
            let axes: Vec<&str> = r.best.iter().map(|(n, _)| n).collect();
            assert_eq!(axes, names);
            // Within a quarter decade of the optimum on average.
            r.best_fitness < 0.01 + 0.25
        })
        .count();
    assert!(hits >= 8, "5-axis optimum reached in {hits} of 10 runs");

    let two = SearchSpace::default()
        .with("a", (1.0, 100.0))
        .with("b", (0.01, 1.0));
    let grid = Grid {
        budget: 30,
        batch: 5,
    };
    assert_eq!((grid.per_axis(2), grid.points(2)), (5, 25));
    let seen = std::sync::Mutex::new(Vec::new());
    let record = |batch: &[Point], bar: f64| {
        seen.lock().unwrap().push(batch.to_vec());
        bowl(&Point::default().with("a", 10.0).with("b", 0.1))(batch, bar)
    };
    let r = grid.run(&two, &record, &mut (), &never()).unwrap();
    let batches = seen.into_inner().unwrap();
    assert_eq!(batches.len(), 5);
    for batch in &batches {
        // Each batch of 5 walks the first axis at one value of the last.
        let a: Vec<f64> = batch.iter().map(|p| p.get("a").unwrap()).collect();
        let b = batch[0].get("b").unwrap();
        assert!(batch.iter().all(|p| p.get("b") == Some(b)), "{batch:?}");
        assert!(
            (a[0] - 1.0).abs() < 1e-12 && (a[4] - 100.0).abs() < 1e-9,
            "{a:?}"
        );
    }
    assert!((r.best.get("a").unwrap() - 10.0).abs() < 1e-9);
    assert!((r.best.get("b").unwrap() - 0.1).abs() < 1e-12);
    assert!((r.best_fitness - 0.01).abs() < 1e-12, "{}", r.best_fitness);

    // An axis held at one value (lo = hi) takes that value alone: the budget goes to the others.
    let held = two.with("c", (3.0, 3.0));
    let seen = std::sync::Mutex::new(Vec::new());
    let record = |batch: &[Point], _bar: f64| {
        seen.lock().unwrap().extend_from_slice(batch);
        vec![1.0; batch.len()]
    };
    grid.run(&held, &record, &mut (), &never()).unwrap();
    let seen = seen.into_inner().unwrap();
    assert_eq!(seen.len(), 25);
    assert!(seen.iter().all(|p| p.get("c") == Some(3.0)));
    let mut distinct: Vec<String> = seen.iter().map(|p| format!("{p}")).collect();
    distinct.sort();
    distinct.dedup();
    assert_eq!(distinct.len(), 25);
}

fn hand_train() -> Dataset {
    let rec = synth::record(&SynthConfig::default()).unwrap().remove(0);
    Dataset {
        source: "train.csv".into(),
        inputs: rec.pressures,
        outputs: rec.tips,
        weights: None,
    }
}

#[test]
fn cv_fitness_is_honest_and_memoised() {
    let data = hand_train();
    let solver = MsvrParams::new(1.0, 0.01, 1.0);
    let cv = Fitness::new(&data, FitnessKind::Cv { folds: 5 }, 3, None, &solver).unwrap();
    let train = Fitness::new(&data, FitnessKind::Train, 3, None, &solver).unwrap();
    // A narrow kernel with a large C interpolates the training data, noise included: its
    // training MAE is far below the noise, its cross-validated MAE is not.
    let overfit = Hyper {
        c: 999.9,
        epsilon: 0.0001,
        sigma: 0.05,
    };
    let sane = Hyper {
        c: 300.0,
        epsilon: 0.02,
        sigma: 0.3,
    };
    let [t_over, t_sane] = train.evaluate(&[overfit, sane], f64::INFINITY)[..] else {
        unreachable!()
    };
    let [cv_over, cv_sane] = cv.evaluate(&[overfit, sane], f64::INFINITY)[..] else {
        unreachable!()
    };
    assert!(
        t_over < t_sane,
        "training MAE prefers the over-fit: {t_over} vs {t_sane}"
    );
    assert!(
        cv_over > cv_sane,
        "cross-validation does not: {cv_over} vs {cv_sane}"
    );
    assert!(
        t_over < 0.005,
        "training MAE {t_over} mm for an interpolating model"
    );

    let before = cv.counters();
    let again = cv.evaluate(&[sane, sane, Hyper { c: 0.0, ..sane }], f64::INFINITY);
    assert_eq!(again[0], cv_sane);
    assert_eq!(again[2], f64::INFINITY);
    let after = cv.counters();
    assert_eq!(after.evaluations, before.evaluations);
    assert_eq!(after.memo_hits, before.memo_hits + 2);
    assert_eq!(before.fits, 10);
}

#[test]
fn racing_never_changes_what_a_search_finds() {
    // Racing stops a candidate once its partial error shows it cannot enter ACO_R's archive
    // or beat the grid's best: each search must end exactly where it ends scoring every fold.
    let data = hand_train();
    let solver = MsvrParams::new(1.0, 0.01, 1.0);
    let space = tune::space_for(&data);
    let fitness = || Fitness::new(&data, FitnessKind::Cv { folds: 5 }, 3, None, &solver).unwrap();
    for method in [
        Method::AcoR(AcoR {
            budget: 60,
            ..AcoR::default()
        }),
        Method::Grid(Grid {
            budget: 64,
            ..Grid::default()
        }),
    ] {
        let (raced, full) = (fitness(), fitness());
        let a = method
            .run(
                &space,
                &|b: &[Point], bar| raced.evaluate(&hypers(b), bar),
                &mut (),
                &never(),
            )
            .unwrap();
        let b = method
            .run(
                &space,
                &|b: &[Point], _| full.evaluate(&hypers(b), f64::INFINITY),
                &mut (),
                &never(),
            )
            .unwrap();
        assert_eq!(
            (a.best, a.best_fitness),
            (b.best, b.best_fitness),
            "{method}"
        );
        let (r, f) = (raced.counters(), full.counters());
        assert!(r.raced > 0 && r.fits < f.fits, "{method}: {r:?} vs {f:?}");
        assert_eq!(f.raced, 0);
    }
}

#[test]
fn cv_needs_enough_rows_per_fold() {
    let data = hand_train();
    let solver = MsvrParams::new(1.0, 0.01, 1.0);
    assert!(Fitness::new(&data, FitnessKind::Cv { folds: 1 }, 0, None, &solver).is_err());
    assert!(Fitness::new(&data, FitnessKind::Cv { folds: 200 }, 0, None, &solver).is_err());
}

#[test]
fn grouped_folds_hold_out_whole_groups() {
    // Label rows by P1 (6 levels of 36 rows): with 3 grouped folds, each fold's score is a
    // prediction of two unseen P1 levels, so it differs from row-wise CV, and 7 folds cannot be
    // made from 6 groups.
    let data = hand_train();
    let labels: Vec<f64> = data.inputs.column(0).collect();
    let solver = MsvrParams::new(1.0, 0.01, 1.0);
    let grouped = Fitness::new(
        &data,
        FitnessKind::Cv { folds: 3 },
        1,
        Some(&labels),
        &solver,
    )
    .unwrap();
    let rows = Fitness::new(&data, FitnessKind::Cv { folds: 3 }, 1, None, &solver).unwrap();
    let h = [Hyper {
        c: 300.0,
        epsilon: 0.02,
        sigma: 0.3,
    }];
    let (g, r) = (
        grouped.evaluate(&h, f64::INFINITY)[0],
        rows.evaluate(&h, f64::INFINITY)[0],
    );
    assert!(
        g > 2.0 * r,
        "grouped CV {g} should be far harsher than row-wise {r}: whole P1 levels are unseen"
    );
    let err = Fitness::new(
        &data,
        FitnessKind::Cv { folds: 7 },
        1,
        Some(&labels),
        &solver,
    )
    .err()
    .unwrap();
    assert!(err.to_string().contains("6 groups"), "{err}");
}

/// Every setting rule of every search, and of the box, refuses its value and names it.
#[test]
fn every_search_setting_rule_is_checked_and_named() {
    use handcap::search::{Method, Search, SearchError};
    let paper = AcoPaper::default();
    let aco_r = AcoR::default();
    let grid = Grid::default();
    let cases = [
        (Method::AcoPaper(AcoPaper { ants: 0, ..paper }), "ants"),
        (Method::AcoPaper(AcoPaper { rho: 1.0, ..paper }), "rho"),
        (Method::AcoPaper(AcoPaper { tau0: 0.0, ..paper }), "tau0"),
        (
            Method::AcoPaper(AcoPaper {
                max_iter: 0,
                ..paper
            }),
            "max_iter",
        ),
        (
            Method::AcoR(AcoR {
                archive: 1,
                ..aco_r
            }),
            "archive",
        ),
        (Method::AcoR(AcoR { ants: 0, ..aco_r }), "ants"),
        (Method::AcoR(AcoR { budget: 5, ..aco_r }), "budget"),
        (
            Method::AcoR(AcoR {
                q: f64::NAN,
                ..aco_r
            }),
            "q",
        ),
        (Method::AcoR(AcoR { xi: -1.0, ..aco_r }), "xi"),
        (Method::Grid(Grid { budget: 7, ..grid }), "budget"),
        (Method::Grid(Grid { batch: 0, ..grid }), "batch"),
    ];
    let never =
        |_: &[Point], _: f64| -> Vec<f64> { panic!("a bad setting must stop before any fit") };
    for (method, name) in cases {
        let err = method
            .run(&table2_space(), &never, &mut (), &AtomicBool::new(false))
            .unwrap_err();
        assert!(
            matches!(err, SearchError::InvalidSetting { name: n, .. } if n == name),
            "{method:?}: {err}"
        );
    }
    let boxes = [
        ("c", (0.0, 10.0)),
        ("epsilon", (0.1, 0.01)),
        ("sigma", (0.1, f64::INFINITY)),
    ];
    for (name, range) in boxes {
        let space = table2_space().with(name, range);
        for method in [Method::AcoR(aco_r), Method::Grid(grid)] {
            let err = method
                .run(&space, &never, &mut (), &AtomicBool::new(false))
                .unwrap_err();
            assert!(
                matches!(&err, SearchError::InvalidAxis { name: n, .. } if n == name),
                "{space:?}: {err}"
            );
            assert!(err.to_string().contains(name), "{err}");
        }
    }
    for method in [Method::AcoR(aco_r), Method::Grid(grid)] {
        let err = method
            .run(
                &SearchSpace::default(),
                &never,
                &mut (),
                &AtomicBool::new(false),
            )
            .unwrap_err();
        assert_eq!(err, SearchError::NoAxes);
    }
}

/// A measured time series in miniature: one input ramping slowly between random targets, the
/// output a smooth function of it plus a slow drift (lag, temperature) that neighbours share.
/// Returns `ramps` ramps of 30 rows.
fn drifting_ramps(seed: u64, ramps: usize) -> Dataset {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let (mut x, mut y) = (Vec::new(), Vec::new());
    let (mut at, mut drift) = (0.5f64, 0.0f64);
    for _ in 0..ramps {
        let to = rng.random_range(0.0..1.0);
        for k in 1..=30 {
            let p = at + (to - at) * k as f64 / 30.0;
            drift = 0.99 * drift + 0.05 * rng.random_range(-1.0..1.0);
            x.push(p);
            y.push((std::f64::consts::TAU * p).sin() + drift);
        }
        at = to;
    }
    handcap::data::Dataset {
        source: "ramps.csv".into(),
        inputs: handcap::data::Columns::new(vec!["p".into()], x),
        outputs: handcap::data::Columns::new(vec!["y".into()], y),
        weights: None,
    }
}

/// Shuffled folds on a time series reward interpolating the drift between neighbours: their CV
/// error is optimistic and the model chosen interpolates (large C, ε ≈ 0). The automatic folds
/// see a time series, hold out blocks, estimate the error on new ramps, and choose a model at
/// least as good there.
#[test]
fn auto_folds_on_a_time_series_estimate_the_error_on_new_ramps() {
    use handcap::model::evaluate;
    use handcap::select::folds::{self, FoldScheme, FoldsBy};
    use handcap::select::tune;
    let train = drifting_ramps(1, 24);
    let unseen = drifting_ramps(2, 12);
    let auto = folds::plan(&FoldsBy::Auto, &train, &[], 5).unwrap();
    assert_eq!(
        auto.choice.scheme,
        FoldScheme::Blocks,
        "{}",
        auto.choice.reason
    );
    let shuffled = folds::plan(&FoldsBy::Shuffle, &train, &[], 5).unwrap();
    let method = handcap::search::Method::Grid(Grid {
        budget: 216,
        ..Grid::default()
    });
    let choose = |plan| {
        let (summary, ..) = tune::run(
            &method,
            &train,
            FitnessKind::Cv { folds: 5 },
            7,
            plan,
            &MsvrParams::default(),
            &Hyper::AXES,
            &tune::Pinned::default(),
            &mut (),
            &never(),
        )
        .unwrap();
        let model = MsvrParams::default()
            .with_hyper(summary.best)
            .check()
            .unwrap()
            .fit(&train)
            .unwrap();
        (summary, evaluate(&model, &unseen).unwrap().mae)
    };
    let (by_blocks, blocks_mae) = choose(&auto);
    let (by_shuffle, shuffle_mae) = choose(&shuffled);
    let (cv_blocks, cv_shuffled) = (by_blocks.best_fitness, by_shuffle.best_fitness);
    assert!(
        cv_shuffled < 0.85 * shuffle_mae,
        "shuffled CV {cv_shuffled:.4} is not optimistic against {shuffle_mae:.4} on new ramps"
    );
    assert!(
        (cv_blocks / blocks_mae - 1.0).abs() < 0.15,
        "blocks CV {cv_blocks:.4} against {blocks_mae:.4} on new ramps"
    );
    assert!(
        by_shuffle.best.c > 10.0 * by_blocks.best.c,
        "shuffled folds pick C {} against {}",
        by_shuffle.best.c,
        by_blocks.best.c
    );
    assert!(
        blocks_mae <= 1.02 * shuffle_mae,
        "on new ramps: blocks {blocks_mae:.4}, shuffled {shuffle_mae:.4}"
    );
}
