//! Row weights (`handcap model --weight`): a row of weight k is fitted as k copies of it, by
//! both solvers and both losses; weights reach every fit of a cross-validation; bad weights
//! are refused with one line.

use faer::Mat;

use handcap::data::{Columns, Dataset};
use handcap::model::msvr::basis::{kmeans_pp, NystromMap};
use handcap::model::msvr::reduced::{self, FeatureRows, ReducedProblem};
use handcap::model::msvr::{Basis, Hyper, Loss, MinMaxScaler, MsvrParams, RowWeights};
use handcap::model::ModelSpec;
use handcap::select::fitness::{Fitness, FitnessKind};

use crate::common::{handcap_err, handcap_ok, handcap_usage, tempdir, write, Lcg};

/// n rows of a smooth 2 → 2 map with noise, and each row's weight (1, 2 or 3).
fn rows(seed: u64, n: usize) -> (Dataset, Vec<usize>) {
    let mut rng = Lcg(seed);
    let x = rng.vec(2 * n);
    let y: Vec<f64> = x
        .chunks(2)
        .flat_map(|p| [(3.0 * p[0]).sin() + p[1], p[0] * p[1]])
        .map(|v| v + 0.2 * (rng.next() - 0.5))
        .collect();
    let copies = (0..n).map(|i| 1 + i % 3).collect();
    let data = Dataset {
        source: "generated".into(),
        inputs: Columns::new(vec!["a".into(), "b".into()], x),
        outputs: Columns::new(vec!["u".into(), "v".into()], y),
        weights: None,
    };
    (data, copies)
}

/// The rows weighted by their copies, and the rows copied as many times instead.
fn weighted_and_copied(data: &Dataset, copies: &[usize]) -> (Dataset, Dataset) {
    let weighted = Dataset {
        weights: Some(copies.iter().map(|&k| k as f64).collect()),
        ..data.clone()
    };
    let repeated: Vec<usize> = (0..data.rows())
        .flat_map(|i| std::iter::repeat_n(i, copies[i]))
        .collect();
    (weighted, data.select_rows(&repeated))
}

fn largest_difference(a: &Columns, b: &Columns) -> f64 {
    a.values
        .iter()
        .zip(&b.values)
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max)
}

#[test]
fn a_row_of_weight_k_is_fitted_as_k_copies_of_it_by_the_exact_solver() {
    let (data, copies) = rows(1, 60);
    let (weighted, copied) = weighted_and_copied(&data, &copies);
    let probe = rows(2, 40).0.inputs;
    for loss in [Loss::Quadratic, Loss::Robust] {
        let params = MsvrParams::new(30.0, 0.02, 0.4).loss(loss).tol(1e-13);
        let fit = |d: &Dataset| ModelSpec::Msvr(params).fit(d).unwrap();
        let (w, c) = (fit(&weighted), fit(&copied));
        let (pw, pc) = (
            w.predictor().predict(&probe).unwrap(),
            c.predictor().predict(&probe).unwrap(),
        );
        let apart = largest_difference(&pw, &pc);
        assert!(apart < 1e-6, "{loss}: predictions {apart} apart");
        // Unweighted, the same rows fit otherwise: the weights did something.
        let plain = fit(&data).predictor().predict(&probe).unwrap();
        assert!(largest_difference(&pw, &plain) > 1e-3, "{loss}");
    }
}

#[test]
fn a_row_of_weight_k_is_fitted_as_k_copies_of_it_by_the_reduced_solver() {
    let (data, copies) = rows(3, 300);
    let (weighted, copied) = weighted_and_copied(&data, &copies);
    let scaled = MinMaxScaler::fit(&data.inputs).transform(&data.inputs);
    let map = NystromMap::new(&scaled.select_rows(&kmeans_pp(&scaled, 40, 5)), 0.3);
    let solve = |d: &Dataset, loss, c| {
        let features = map.features(&MinMaxScaler::fit(&d.inputs).transform(&d.inputs));
        let y = Mat::from_fn(d.rows(), 2, |i, j| d.outputs.row(i)[j]);
        let problem = ReducedProblem {
            features: FeatureRows::Stored {
                all: features.as_ref(),
                rows: None,
            },
            targets: y.as_ref(),
            tube: MsvrParams::new(c, 0.02, 0.3).loss(loss).tube(),
            weights: d.row_weights(),
            gram: None,
        };
        let since = handcap::control::Since::START;
        reduced::solve(&problem, 1e-13, 2000, faer::Par::Seq, since).expect("a fit")
    };
    for loss in [Loss::Quadratic, Loss::Robust] {
        let (w, c) = (solve(&weighted, loss, 30.0), solve(&copied, loss, 30.0));
        assert!(
            (w.objective - c.objective).abs() <= 1e-9 * c.objective,
            "{loss}: objective weighted {}, copied {}",
            w.objective,
            c.objective
        );
        let apart = (&w.w - &c.w).norm_max();
        assert!(
            apart < 1e-5 * c.w.norm_max(),
            "{loss}: weights {apart} apart"
        );
        // Rows of weight 1 beside rows of a weight whose 2Cw rounds otherwise than
        // 1/(1/(2Cw)) does (C = 10, w = 4020/1639, a lab's refit): the second kind, in the
        // loss's quadratic zone, once counted as leaving it with a negative share, and the
        // step's system was not positive definite.
        let w = 4020.0 / 1639.0;
        let mixed = Dataset {
            weights: Some((0..data.rows()).map(|i| [1.0, w][i % 2]).collect()),
            ..data.clone()
        };
        let fitted = solve(&mixed, loss, 10.0);
        assert!(fitted.stop.converged(), "{loss}: {:?}", fitted.stop);
    }
}

#[test]
fn every_row_weighing_w_scores_as_c_times_w_in_every_fold() {
    // The weights reach each fold's fit (the reduced basis' per-fold Gram matrices too): rows
    // all weighing 2.5 fit as C × 2.5 unweighted, so every fold's held-out error is the same.
    let (data, _) = rows(4, 200);
    let weighted = Dataset {
        weights: Some(vec![2.5; data.rows()]),
        ..data.clone()
    };
    let h = Hyper {
        c: 4.0,
        epsilon: 0.02,
        sigma: 0.4,
    };
    for basis in [
        Basis::Exact,
        Basis::Reduced {
            centres: 50,
            seed: 2,
        },
    ] {
        let solver = MsvrParams::new(1.0, 0.1, 1.0).basis(basis).tol(1e-12);
        let cv = FitnessKind::Cv { folds: 4 };
        let score = |d: &Dataset, h: Hyper| {
            let fitness = Fitness::new(d, cv, 7, None, &solver).unwrap();
            fitness.evaluate(&[h], f64::INFINITY)[0]
        };
        let scaled = Hyper { c: 10.0, ..h };
        let (a, b) = (score(&weighted, h), score(&data, scaled));
        assert!((a - b).abs() <= 1e-6 * b, "{basis:?}: {a} against {b}");
        assert!(
            (a - score(&data, h)).abs() > 1e-4,
            "{basis:?}: weights ignored"
        );
    }
    assert_eq!(RowWeights(None).of(3), 1.0);
}

/// A CSV of `rows` with a weight column: the given weight on the rows listed, 1 elsewhere.
fn csv(data: &Dataset, weight: impl Fn(usize) -> String) -> String {
    let mut text = String::from("a,b,u,v,w\n");
    for i in 0..data.rows() {
        let (x, y) = (data.inputs.row(i), data.outputs.row(i));
        text += &format!("{},{},{},{},{}\n", x[0], x[1], y[0], y[1], weight(i));
    }
    text
}

#[test]
fn handcap_model_weighs_rows_by_a_column_as_copies_of_them() {
    let dir = tempdir();
    let d = dir.path();
    let (data, copies) = rows(5, 80);
    write(d, "weighted.csv", &csv(&data, |i| copies[i].to_string()));
    let (_, copied) = weighted_and_copied(&data, &copies);
    write(d, "copied.csv", &csv(&copied, |_| "1".into()));
    write(d, "probe.csv", &csv(&rows(6, 30).0, |_| "1".into()));
    let fit = ["--inputs", "a,b", "--outputs", "u,v", "--search", "none"];
    let fixed = [
        "--c",
        "30",
        "--epsilon",
        "0.02",
        "--sigma",
        "0.4",
        "--basis",
        "exact",
    ];
    let model = |data: &str, out: &str, more: &[&str]| {
        handcap_ok(
            d,
            &[&["model", data], &fit[..], &fixed, more, &["--out", out]].concat(),
        );
        let predicted = format!("{out}.csv");
        handcap_ok(d, &["predict", out, "probe.csv", "--out", &predicted]);
        crate::common::csv_rows(&d.join(predicted))
    };
    let weighted = model("weighted.csv", "weighted.json", &["--weight", "w"]);
    let copied = model("copied.csv", "copied.json", &[]);
    let unweighted = model("weighted.csv", "plain.json", &[]);
    let apart = |a: &[std::collections::HashMap<String, String>], b: &[_]| {
        a.iter()
            .zip(b)
            .flat_map(
                |(r, s): (
                    &std::collections::HashMap<String, String>,
                    &std::collections::HashMap<String, String>,
                )| {
                    ["u", "v"].map(|c| {
                        (r[c].parse::<f64>().unwrap() - s[c].parse::<f64>().unwrap()).abs()
                    })
                },
            )
            .fold(0.0, f64::max)
    };
    assert!(
        apart(&weighted, &copied) < 1e-5,
        "{}",
        apart(&weighted, &copied)
    );
    assert!(apart(&weighted, &unweighted) > 1e-3);
}

#[test]
fn bad_weights_are_refused_with_one_line_naming_the_row() {
    let dir = tempdir();
    let d = dir.path();
    let (data, _) = rows(7, 40);
    let args = |column| {
        let fit = [
            "model",
            "weighted.csv",
            "--inputs",
            "a,b",
            "--outputs",
            "u,v",
        ];
        [
            &fit[..],
            &["--search", "none", "--weight", column, "--out", "m.json"],
        ]
        .concat()
    };
    for (weight, says) in [
        (
            "0",
            "weighted.csv line 6: weight 0 in column `w`: give every row a weight above 0",
        ),
        ("-2", "weighted.csv line 6: weight -2 in column `w`"),
        (
            "heavy",
            "weighted.csv: line 6, column `w`: `heavy` is not a number",
        ),
    ] {
        let fifth = |i| if i == 4 { weight.into() } else { "1".into() };
        write(d, "weighted.csv", &csv(&data, fifth));
        let message = handcap_err(d, &args("w"));
        assert!(message.contains(says), "{weight}: {message}");
        assert!(!d.join("m.json").exists(), "{weight}: a model was written");
    }
    write(d, "weighted.csv", &csv(&data, |_| "1".into()));
    let message = handcap_err(d, &args("mass"));
    assert!(message.contains("no column `mass`"), "{message}");
    let message = handcap_usage(d, &args("u"));
    assert!(
        message.contains("--weight u: the model reads `u`"),
        "{message}"
    );
}
