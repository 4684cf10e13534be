//! The reduced basis (issue 27): against exact MSVR on the same data, its two feature paths
//! against each other, and `--basis` as a user runs it.

use faer::Mat;

use handcap::data::{Columns, Dataset};
use handcap::model::msvr::basis::{kmeans_pp, NystromMap};
use handcap::model::msvr::reduced::{self, FeatureRows, ReducedProblem};
use handcap::model::msvr::{Basis, Loss, MinMaxScaler, MsvrParams};
use handcap::model::{evaluate, ModelSpec};
use handcap::select::fitness::{Fitness, FitnessKind};

use crate::common::{handcap_ok, handcap_usage, read_json, tempdir, write, Lcg};

/// n rows of a smooth 3 → 3 map of inputs in [0, 250] with noise of sd ≈ 0.03.
fn smooth(seed: u64, n: usize) -> Dataset {
    let mut rng = Lcg(seed);
    let x: Vec<f64> = (0..3 * n).map(|_| 250.0 * rng.next()).collect();
    let y: Vec<f64> = x
        .chunks(3)
        .flat_map(|p| {
            let noise = |r: &mut Lcg| 0.1 * (r.next() - 0.5);
            [
                10.0 * (p[0] / 80.0).sin() + 0.002 * p[1] * p[2] / 10.0 + noise(&mut rng),
                5.0 * (p[1] / 60.0).cos() - p[0] / 50.0 + noise(&mut rng),
                0.03 * (p[0] + p[1] + p[2]) + 2.0 * (p[2] / 40.0).sin() + noise(&mut rng),
            ]
        })
        .collect();
    Dataset {
        source: "smooth".into(),
        inputs: Columns::new(vec!["P1_kpa".into(), "P2_kpa".into(), "P3_kpa".into()], x),
        outputs: Columns::new(vec!["x_mm".into(), "y_mm".into(), "z_mm".into()], y),
        weights: None,
    }
}

fn params(basis: Basis) -> MsvrParams {
    MsvrParams::new(100.0, 0.05, 0.3)
        .loss(Loss::Robust)
        .basis(basis)
}

#[test]
fn a_reduced_basis_is_within_2_percent_of_exact_msvr_at_n_2000() {
    let (train, test) = (smooth(1, 2000), smooth(2, 1000));
    let exact = ModelSpec::Msvr(params(Basis::Exact)).fit(&train).unwrap();
    let reduced = ModelSpec::Msvr(params(Basis::Reduced {
        centres: 400,
        seed: 3,
    }))
    .fit(&train)
    .unwrap();
    let e = evaluate(exact.predictor(), &test).unwrap().mae;
    let r = evaluate(reduced.predictor(), &test).unwrap().mae;
    assert!(
        (r - e).abs() <= 0.02 * e,
        "held-out MAE: exact {e:.5}, 400 centres {r:.5}"
    );
    // A restriction of the exact problem: its optimum is no lower, and close.
    let (fe, fr) = (
        exact.diagnostics().objective,
        reduced.diagnostics().objective,
    );
    assert!(
        fr >= fe * (1.0 - 1e-6) && fr <= fe * 1.01,
        "objective exact {fe}, reduced {fr}"
    );
    let terms = reduced.diagnostics().support_vectors;
    assert!((350..=400).contains(&terms), "{terms} centres kept of 400");
}

#[test]
fn every_row_as_a_centre_is_exact_msvr() {
    let train = smooth(4, 150);
    let exact = ModelSpec::Msvr(params(Basis::Exact)).fit(&train).unwrap();
    let all = ModelSpec::Msvr(params(Basis::Reduced {
        centres: 150,
        seed: 1,
    }))
    .fit(&train)
    .unwrap();
    let (fe, fa) = (exact.diagnostics().objective, all.diagnostics().objective);
    assert!(
        (fa - fe).abs() <= 1e-5 * fe,
        "objective exact {fe}, all rows {fa}"
    );
    let (pe, pa) = (
        exact.predictor().predict(&train.inputs).unwrap(),
        all.predictor().predict(&train.inputs).unwrap(),
    );
    let worst = pe
        .values
        .iter()
        .zip(&pa.values)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    assert!(worst < 1e-3, "predictions differ by {worst} mm");
}

#[test]
fn streamed_features_give_the_stored_fit() {
    let data = smooth(5, 3000);
    let scaled = MinMaxScaler::fit(&data.inputs).transform(&data.inputs);
    let map = NystromMap::new(&scaled.select_rows(&kmeans_pp(&scaled, 60, 9)), 0.3);
    let stored = map.features(&scaled);
    let y = Mat::from_fn(data.rows(), 3, |i, j| data.outputs.row(i)[j]);
    let tube = params(Basis::Exact).tube();
    let solve = |features| {
        let problem = ReducedProblem {
            features,
            targets: y.as_ref(),
            tube,
            gram: None,
            weights: Default::default(),
        };
        reduced::solve(
            &problem,
            1e-10,
            500,
            faer::Par::Seq,
            handcap::control::Since::START,
        )
        .unwrap()
    };
    let a = solve(FeatureRows::Stored {
        all: stored.as_ref(),
        rows: None,
    });
    let b = solve(FeatureRows::Streamed {
        map: &map,
        x: &scaled,
        rows: None,
    });
    assert_eq!(a.iterations, b.iterations);
    assert!((a.objective - b.objective).abs() <= 1e-9 * a.objective);
    assert!(a.stop.converged());
}

#[test]
fn model_basis_writes_a_reduced_model_that_predict_reads() {
    let dir = tempdir();
    let train = smooth(6, 300);
    let mut csv = String::from("P1_kpa,P2_kpa,P3_kpa,x_mm,y_mm,z_mm\n");
    for (x, y) in train.inputs.iter_rows().zip(train.outputs.iter_rows()) {
        let row: Vec<String> = x.iter().chain(y).map(|v| v.to_string()).collect();
        csv += &(row.join(",") + "\n");
    }
    write(dir.path(), "train.csv", &csv);
    let out = handcap_ok(
        dir.path(),
        &[
            "model",
            "train.csv",
            "--search",
            "none",
            "--c",
            "100",
            "--epsilon",
            "0.05",
            "--sigma",
            "0.3",
            "--basis",
            "50",
            "--out",
            "m.json",
        ],
    );
    assert!(out.contains("basis = 50 centres"), "{out}");
    let file = read_json(&dir.path().join("m.json"));
    assert_eq!(file["model"]["params"]["basis"]["centres"], 50);
    assert_eq!(
        file["model"]["support_vectors"].as_array().unwrap().len(),
        50
    );
    assert!(file["basis"]["reason"]
        .as_str()
        .unwrap()
        .contains("basis=50"));
    handcap_ok(
        dir.path(),
        &["predict", "m.json", "train.csv", "--out", "p.csv"],
    );
    // `auto` on 300 rows: exact, and the file says why.
    handcap_ok(
        dir.path(),
        &["model", "train.csv", "--search", "none", "--out", "a.json"],
    );
    let file = read_json(&dir.path().join("a.json"));
    assert_eq!(file["model"]["params"]["basis"]["kind"], "exact");
    assert!(file["basis"]["reason"]
        .as_str()
        .unwrap()
        .contains("affordable"));
    // More centres than rows: one line saying what would fit, nothing written.
    let err = handcap_usage(
        dir.path(),
        &[
            "model",
            "train.csv",
            "--search",
            "none",
            "--basis",
            "301",
            "--out",
            "n.json",
        ],
    );
    assert!(err.contains("--basis 300 or fewer"), "{err}");
    assert!(!dir.path().join("n.json").exists());
}

#[test]
fn the_search_scores_a_reduced_basis_as_it_fits() {
    let data = smooth(7, 400);
    let solver = params(Basis::Reduced {
        centres: 60,
        seed: 2,
    });
    let fitness = Fitness::new(&data, FitnessKind::Train, 1, None, &solver).unwrap();
    let scored = fitness.evaluate(&[solver.hyper()], f64::INFINITY)[0];
    let model = ModelSpec::Msvr(solver).fit(&data).unwrap();
    let mae = evaluate(model.predictor(), &data).unwrap().mae;
    assert!(
        (scored - mae).abs() <= 1e-3 * mae,
        "training MAE scored {scored:.6}, fitted {mae:.6}"
    );
    assert_eq!(fitness.kept_centres(solver.sigma), 60);
}
