//! MSVR against oracles that follow from its equations (`notes/msvr.md`) and an independent
//! solver written here.

// Index loops read like the matrix equations they check.
#![allow(clippy::needless_range_loop)]

use faer::{Mat, MatRef, Par};

use handcap::data::{Columns, Dataset};
use handcap::model::file::{ModelFile, StoredModel};
use handcap::model::msvr::irwls::{self, Problem, SolverOptions, StopReason};
use handcap::model::msvr::PAPER_TABLE2;
use handcap::model::msvr::{kernel, Loss, MsvrParams, ROBUST_ZONE};
use handcap::model::Predict;
use handcap::provenance::Provenance;
use handcap::synth::{self, SynthConfig};

use crate::common::{dataset, tempdir, Lcg};

const OPTIONS: SolverOptions = SolverOptions {
    factor_updates: true,
    tol: 1e-12,
    max_iter: 500,
    par: Par::Seq,
    since: handcap::control::Since::START,
};

/// Random inputs in [0, 1]^d and smooth nonlinear targets with noise.
fn random_problem(seed: u64, n: usize, d: usize, q: usize) -> (Columns, Mat<f64>) {
    let mut rng = Lcg(seed);
    let x = Columns::new((0..d).map(|j| format!("x{j}")).collect(), rng.vec(n * d));
    let y = Mat::from_fn(n, q, |i, j| {
        let r = x.row(i);
        (3.0 * r[0] + j as f64).sin()
            + r[d - 1] * r[d - 1] * (j as f64 + 1.0)
            + 0.05 * (rng.next() - 0.5)
    });
    (x, y)
}

/// Solves the dense system `a z = rhs` by Gaussian elimination with partial pivoting.
fn gauss_solve(mut a: Vec<Vec<f64>>, mut rhs: Vec<Vec<f64>>) -> Vec<Vec<f64>> {
    let n = a.len();
    for col in 0..n {
        let pivot = (col..n)
            .max_by(|&i, &j| a[i][col].abs().total_cmp(&a[j][col].abs()))
            .unwrap();
        a.swap(col, pivot);
        rhs.swap(col, pivot);
        for row in col + 1..n {
            let f = a[row][col] / a[col][col];
            for k in col..n {
                a[row][k] -= f * a[col][k];
            }
            for k in 0..rhs[row].len() {
                rhs[row][k] -= f * rhs[col][k];
            }
        }
    }
    for col in (0..n).rev() {
        for k in 0..rhs[col].len() {
            let s: f64 = (col + 1..n).map(|j| a[col][j] * rhs[j][k]).sum();
            rhs[col][k] = (rhs[col][k] - s) / a[col][col];
        }
    }
    rhs
}

#[test]
fn epsilon_zero_is_kernel_ridge_regression() {
    let (n, q, c) = (40, 3, 50.0);
    let (x, y) = random_problem(1, n, 3, q);
    let k = kernel::rbf(&x, &x, 0.4);
    let problem = Problem {
        kernel: k.as_ref(),
        targets: y.as_ref(),
        c,
        epsilon: 0.0,
        loss: Loss::Quadratic,
        weights: Default::default(),
    };
    let sol = irwls::solve(&problem, &OPTIONS, None).unwrap();

    // [K + I/(2C)  1; 1ᵀ 0] [β; bᵀ] = [Y; 0]
    let a: Vec<Vec<f64>> = (0..=n)
        .map(|i| {
            (0..=n)
                .map(|j| match (i < n, j < n) {
                    (true, true) => k[(i, j)] + if i == j { 1.0 / (2.0 * c) } else { 0.0 },
                    (false, false) => 0.0,
                    _ => 1.0,
                })
                .collect()
        })
        .collect();
    let rhs: Vec<Vec<f64>> = (0..=n)
        .map(|i| {
            (0..q)
                .map(|j| if i < n { y[(i, j)] } else { 0.0 })
                .collect()
        })
        .collect();
    let z = gauss_solve(a, rhs);
    for j in 0..q {
        assert!(
            (sol.bias[j] - z[n][j]).abs() < 1e-8,
            "bias {j}: {} vs {}",
            sol.bias[j],
            z[n][j]
        );
        for i in 0..n {
            let diff = (sol.beta[(i, j)] - z[i][j]).abs();
            assert!(
                diff < 1e-7 * (1.0 + z[i][j].abs()),
                "β[{i},{j}] off by {diff}"
            );
        }
    }
    assert!(
        sol.iterations <= 2,
        "ε = 0 takes one step, took {}",
        sol.iterations
    );
}

#[test]
fn a_tube_wider_than_every_residual_gives_beta_zero() {
    let (n, q) = (30, 2);
    let (x, y) = random_problem(2, n, 2, q);
    let mean: Vec<f64> = (0..q)
        .map(|j| y.col(j).iter().sum::<f64>() / n as f64)
        .collect();
    let widest = (0..n)
        .map(|i| {
            (0..q)
                .map(|j| (y[(i, j)] - mean[j]).powi(2))
                .sum::<f64>()
                .sqrt()
        })
        .fold(0.0, f64::max);
    let k = kernel::rbf(&x, &x, 0.3);
    let problem = Problem {
        kernel: k.as_ref(),
        targets: y.as_ref(),
        c: 100.0,
        epsilon: widest * 1.01,
        loss: Loss::Quadratic,
        weights: Default::default(),
    };
    // From the default start and from a warm start far from β = 0: an iterate with every
    // sample inside the tube must step towards β = 0, not stop or collapse elsewhere.
    let far = Mat::from_fn(n, q, |i, j| 0.01 * ((i + j) as f64).sin());
    for start in [None, Some((far.as_ref(), mean.as_slice()))] {
        let sol = irwls::solve(&problem, &OPTIONS, start).unwrap();
        let biggest = sol
            .beta
            .col_iter()
            .flat_map(|c| c.iter().copied())
            .fold(0.0f64, |m, v| m.max(v.abs()));
        assert!(biggest < 1e-6, "β not zero: max |β| = {biggest}");
        assert!(sol.objective < 1e-10, "objective {}", sol.objective);
        for i in 0..n {
            let u = (0..q)
                .map(|j| (y[(i, j)] - sol.bias[j]).powi(2))
                .sum::<f64>()
                .sqrt();
            assert!(u <= problem.epsilon, "sample {i} outside the tube: {u}");
        }
    }
}

/// F(W, b) = ½‖W‖² + C Σ L(‖yᵢ − Wᵀφᵢ − b‖) and its gradient, for an explicit feature map Φ.
/// The primal objective and gradient in (W, b) for K = ΦΦᵀ, with the loss (u − ε)² up to
/// u = ε + `zone` and linear beyond (`zone` = ∞: the paper's quadratic loss).
fn primal(
    phi: MatRef<f64>,
    y: MatRef<f64>,
    (c, eps, zone): (f64, f64, f64),
    z: &[f64],
) -> (f64, Vec<f64>) {
    let (n, m) = phi.shape();
    let q = y.ncols();
    let (w, b) = z.split_at(m * q);
    let mut f = 0.5 * w.iter().map(|v| v * v).sum::<f64>();
    let mut grad: Vec<f64> = w
        .iter()
        .copied()
        .chain(std::iter::repeat_n(0.0, q))
        .collect();
    for i in 0..n {
        let e: Vec<f64> = (0..q)
            .map(|j| y[(i, j)] - b[j] - (0..m).map(|k| w[k * q + j] * phi[(i, k)]).sum::<f64>())
            .collect();
        let u = e.iter().map(|v| v * v).sum::<f64>().sqrt();
        if u > eps {
            let excess = u - eps;
            f += c * if excess <= zone {
                excess * excess
            } else {
                zone * (2.0 * excess - zone)
            };
            let s = 2.0 * c * excess.min(zone) / u;
            for j in 0..q {
                for k in 0..m {
                    grad[k * q + j] -= s * e[j] * phi[(i, k)];
                }
                grad[m * q + j] -= s * e[j];
            }
        }
    }
    (f, grad)
}

/// L-BFGS with Armijo backtracking, to a gradient norm of `gtol`.
fn lbfgs(f: impl Fn(&[f64]) -> (f64, Vec<f64>), mut z: Vec<f64>, gtol: f64) -> f64 {
    let dot = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>();
    let (mut fz, mut g) = f(&z);
    let mut history: Vec<(Vec<f64>, Vec<f64>)> = Vec::new();
    for _ in 0..20_000 {
        if dot(&g, &g).sqrt() < gtol {
            break;
        }
        // Two-loop recursion.
        let mut d: Vec<f64> = g.iter().map(|v| -v).collect();
        let mut alphas = Vec::new();
        for (s, yv) in history.iter().rev() {
            let a = dot(s, &d) / dot(yv, s);
            d.iter_mut().zip(yv).for_each(|(di, yi)| *di -= a * yi);
            alphas.push(a);
        }
        if let Some((s, yv)) = history.last() {
            let gamma = dot(s, yv) / dot(yv, yv);
            d.iter_mut().for_each(|di| *di *= gamma);
        }
        for ((s, yv), a) in history.iter().zip(alphas.iter().rev()) {
            let beta = dot(yv, &d) / dot(yv, s);
            d.iter_mut()
                .zip(s)
                .for_each(|(di, si)| *di += (a - beta) * si);
        }
        let slope = dot(&g, &d);
        let mut t = 1.0;
        let (z_new, f_new, g_new) = loop {
            let trial: Vec<f64> = z.iter().zip(&d).map(|(a, b)| a + t * b).collect();
            let (ft, gt) = f(&trial);
            if ft <= fz + 1e-4 * t * slope || t < 1e-20 {
                break (trial, ft, gt);
            }
            t *= 0.5;
        };
        let s: Vec<f64> = z_new.iter().zip(&z).map(|(a, b)| a - b).collect();
        let yv: Vec<f64> = g_new.iter().zip(&g).map(|(a, b)| a - b).collect();
        if dot(&s, &yv) > 1e-300 {
            history.push((s, yv));
            if history.len() > 10 {
                history.remove(0);
            }
        }
        (z, fz, g) = (z_new, f_new, g_new);
    }
    fz
}

#[test]
fn objective_matches_an_independent_lbfgs_solver() {
    // K = ΦΦᵀ with an explicit feature map, so the problem has a small, well-conditioned primal
    // in (W, b) that L-BFGS solves to high accuracy. Q = 1 is the single-output L2-loss SVR.
    // Every seventh row is an outlier 3 units off, so the robust loss's linear part is used.
    let mut rng = Lcg(3);
    for (case, (n, m, q, c, eps, loss)) in [
        (25, 5, 3, 10.0, 0.1, Loss::Quadratic),
        (40, 6, 2, 200.0, 0.05, Loss::Quadratic),
        (30, 4, 1, 1.0, 0.02, Loss::Quadratic),
        (25, 5, 3, 10.0, 0.1, Loss::Robust),
        (40, 6, 2, 200.0, 0.05, Loss::Robust),
        (30, 4, 1, 1.0, 0.02, Loss::Robust),
    ]
    .into_iter()
    .enumerate()
    {
        let phi = Mat::from_fn(n, m, |_, _| rng.next() - 0.5);
        let y = Mat::from_fn(n, q, |i, j| {
            let outlier = if i % 7 == 0 && j == 0 { 3.0 } else { 0.0 };
            (phi[(i, 0)] * 4.0 + j as f64).sin() + 0.3 * rng.next() + outlier
        });
        let k = &phi * phi.transpose();
        let problem = Problem {
            kernel: k.as_ref(),
            targets: y.as_ref(),
            c,
            epsilon: eps,
            loss,
            weights: Default::default(),
        };
        let sol = irwls::solve(&problem, &OPTIONS, None).unwrap();
        assert!(sol.stop.converged(), "case {case}: {:?}", sol.stop);
        let zone = match loss {
            Loss::Quadratic => f64::INFINITY,
            Loss::Robust => ROBUST_ZONE * eps,
        };
        let f_ref = lbfgs(
            |z| primal(phi.as_ref(), y.as_ref(), (c, eps, zone), z),
            vec![0.0; (m + 1) * q],
            1e-10,
        );
        let rel = (sol.objective - f_ref).abs() / f_ref;
        assert!(
            rel < 1e-6,
            "case {case}: IRWLS {} vs L-BFGS {f_ref} (relative {rel:e})",
            sol.objective
        );
        // The reported objective is the true F at the returned point.
        let k_beta = k.as_ref() * sol.beta.as_ref();
        let recomputed = problem.objective(sol.beta.as_ref(), k_beta.as_ref(), &sol.bias);
        assert!((recomputed - sol.objective).abs() <= 1e-9 * f_ref);
    }
}

#[test]
fn objective_matches_lbfgs_on_a_well_conditioned_rbf_kernel() {
    // Points on a coarse grid with σ below the spacing keep K near the identity, so L-BFGS in
    // (β, b) with ∇β F = K(β − G), ∇b F = −Σ Gᵢ converges without a feature map.
    let (n, q, c, eps) = (16, 2, 30.0, 0.05);
    let x = Columns::new(
        vec!["u".into(), "v".into()],
        (0..n)
            .flat_map(|i| [(i % 4) as f64 / 3.0, (i / 4) as f64 / 3.0])
            .collect(),
    );
    let y = Mat::from_fn(n, q, |i, j| {
        (x.row(i)[0] * 3.0 + j as f64).cos() * x.row(i)[1]
    });
    let k = kernel::rbf(&x, &x, 0.2);
    let problem = Problem {
        kernel: k.as_ref(),
        targets: y.as_ref(),
        c,
        epsilon: eps,
        loss: Loss::Quadratic,
        weights: Default::default(),
    };
    let sol = irwls::solve(&problem, &OPTIONS, None).unwrap();
    let dual = |z: &[f64]| {
        let beta = Mat::from_fn(n, q, |i, j| z[i * q + j]);
        let b = &z[n * q..];
        let kb = k.as_ref() * beta.as_ref();
        let f = problem.objective(beta.as_ref(), kb.as_ref(), b);
        let mut g_mat = Mat::<f64>::zeros(n, q);
        let mut grad_b = vec![0.0; q];
        for i in 0..n {
            let e: Vec<f64> = (0..q).map(|j| y[(i, j)] - kb[(i, j)] - b[j]).collect();
            let u = e.iter().map(|v| v * v).sum::<f64>().sqrt();
            if u > eps {
                for j in 0..q {
                    g_mat[(i, j)] = 2.0 * c * (u - eps) / u * e[j];
                    grad_b[j] -= g_mat[(i, j)];
                }
            }
        }
        let grad_beta = k.as_ref() * (&beta - &g_mat);
        let grad: Vec<f64> = (0..n)
            .flat_map(|i| (0..q).map(move |j| (i, j)))
            .map(|(i, j)| grad_beta[(i, j)])
            .chain(grad_b)
            .collect();
        (f, grad)
    };
    let f_ref = lbfgs(dual, vec![0.0; (n + 1) * q], 1e-11);
    let rel = (sol.objective - f_ref).abs() / f_ref;
    assert!(
        rel < 1e-6,
        "IRWLS {} vs L-BFGS {f_ref} (relative {rel:e})",
        sol.objective
    );
}

fn hand_data(name: &str) -> Dataset {
    let recs = synth::record(&SynthConfig::default()).unwrap();
    let rec = recs.into_iter().find(|r| r.name == name).unwrap();
    Dataset {
        source: format!("{name}.csv").into(),
        inputs: rec.pressures,
        outputs: rec.tips,
        weights: None,
    }
}

fn permute_rows(c: &Columns, order: &[usize]) -> Columns {
    Columns::new(
        c.names.clone(),
        order.iter().flat_map(|&i| c.row(i).to_vec()).collect(),
    )
}

fn permute_cols(c: &Columns, order: &[usize]) -> Columns {
    Columns::new(
        order.iter().map(|&j| c.names[j].clone()).collect(),
        c.iter_rows()
            .flat_map(|r| order.iter().map(|&j| r[j]).collect::<Vec<_>>())
            .collect(),
    )
}

#[test]
fn permuting_rows_or_outputs_permutes_the_solution() {
    let train = hand_data("train");
    let test = hand_data("sweep_b");
    let params = MsvrParams::new(300.0, 0.02, 0.3)
        .tol(1e-12)
        .check()
        .unwrap();
    let base = params.fit(&train).unwrap();
    let base_pred = base.predict(&test.inputs).unwrap();

    let n = train.rows();
    let order: Vec<usize> = (0..n).map(|i| (i * 97 + 13) % n).collect();
    let shuffled = Dataset {
        source: train.source.clone(),
        inputs: permute_rows(&train.inputs, &order),
        outputs: permute_rows(&train.outputs, &order),
        weights: None,
    };
    let rows = params.fit(&shuffled).unwrap();
    let rel = (rows.fit.objective - base.fit.objective).abs() / base.fit.objective;
    assert!(rel < 1e-9, "row order changed the objective by {rel:e}");
    let pred = rows.predict(&test.inputs).unwrap();
    let worst = pred
        .values
        .iter()
        .zip(&base_pred.values)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    assert!(worst < 1e-6, "row order changed predictions by {worst} mm");

    let out_order = [2, 0, 1];
    let swapped = Dataset {
        outputs: permute_cols(&train.outputs, &out_order),
        ..train.clone()
    };
    let cols = params.fit(&swapped).unwrap();
    assert_eq!(cols.outputs(), ["z_mm", "x_mm", "y_mm"]);
    let pred = cols.predict(&test.inputs).unwrap();
    let expected = permute_cols(&base_pred, &out_order);
    let worst = pred
        .values
        .iter()
        .zip(&expected.values)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    assert!(
        worst < 1e-6,
        "output order changed predictions by {worst} mm"
    );
}

#[test]
fn save_load_predicts_identically() {
    let train = hand_data("train");
    let test = hand_data("sweep_a");
    let model = MsvrParams::default()
        .with_hyper(PAPER_TABLE2)
        .check()
        .unwrap()
        .fit(&train)
        .unwrap();
    let dir = tempdir();
    let path = dir.path().join("model.json");
    let file = ModelFile::new(
        StoredModel::Msvr(model.clone()),
        None,
        None,
        None,
        None,
        Provenance::new(vec!["test".into()], None),
    );
    file.save(&path).unwrap();
    let loaded = ModelFile::load(&path).unwrap();
    assert_eq!(loaded, file);
    let StoredModel::Msvr(back) = loaded.model;
    assert_eq!(
        back.predict(&test.inputs).unwrap(),
        model.predict(&test.inputs).unwrap()
    );
}

#[test]
fn fits_the_virtual_hand_and_generalises_to_the_sweeps() {
    let model = MsvrParams::default()
        .with_hyper(PAPER_TABLE2)
        .check()
        .unwrap()
        .fit(&hand_data("train"))
        .unwrap();
    assert!(model.fit.converged);
    for sweep in ["sweep_a", "sweep_b"] {
        let e = handcap::model::evaluate(&model, &hand_data(sweep)).unwrap();
        // The sweeps pass between grid points 50 kPa apart; 0.2 mm MAE on ~10 mm travel.
        assert!(e.mae < 0.2, "{sweep}: MAE {} mm", e.mae);
    }
}

#[test]
fn iteration_cap_is_reported_as_not_converged() {
    let model = MsvrParams::default()
        .with_hyper(PAPER_TABLE2)
        .max_iter(1)
        .check()
        .unwrap()
        .fit(&hand_data("train"))
        .unwrap();
    assert_eq!(model.fit.stop, StopReason::IterationCap);
    assert!(!model.fit.converged && model.fit.iterations == 1);
}

#[test]
fn monotone_objective_and_few_iterations_on_a_larger_problem() {
    let (x, y) = random_problem(4, 300, 3, 3);
    let k = kernel::rbf(&x, &x, 0.25);
    let problem = Problem {
        kernel: k.as_ref(),
        targets: y.as_ref(),
        c: 500.0,
        epsilon: 0.01,
        loss: Loss::Quadratic,
        weights: Default::default(),
    };
    let mut last = f64::INFINITY;
    for iters in 1..=8 {
        let opts = SolverOptions {
            max_iter: iters,
            ..OPTIONS
        };
        let sol = irwls::solve(&problem, &opts, None).unwrap();
        assert!(sol.objective <= last, "objective rose at iteration {iters}");
        last = sol.objective;
    }
    let full = irwls::solve(
        &problem,
        &SolverOptions {
            tol: 1e-8,
            ..OPTIONS
        },
        None,
    )
    .unwrap();
    assert!(
        full.stop.converged() && full.iterations < 60,
        "{} iterations",
        full.iterations
    );
}

#[test]
fn invalid_parameters_are_named() {
    let data = dataset(1, vec![0.0, 1.0, 2.0], 1, vec![0.0, 1.0, 0.0]);
    for (params, name) in [
        (MsvrParams::new(0.0, 0.1, 1.0), "C"),
        (MsvrParams::new(1.0, -0.1, 1.0), "epsilon"),
        (MsvrParams::new(1.0, 0.1, f64::NAN), "sigma"),
        (MsvrParams::new(f64::INFINITY, 0.1, 1.0), "C"),
        (MsvrParams::new(1.0, f64::INFINITY, 1.0), "epsilon"),
        (MsvrParams::new(1.0, 0.1, 0.0), "sigma"),
        (MsvrParams::new(1.0, 0.1, 1.0).max_iter(0), "max_iter"),
        (
            MsvrParams::new(1.0, 0.0, 1.0).loss(handcap::model::msvr::Loss::Robust),
            "epsilon",
        ),
        (
            MsvrParams {
                tol: 1.0,
                ..MsvrParams::new(1.0, 0.1, 1.0)
            },
            "tol",
        ),
    ] {
        let err = params.check().unwrap_err().to_string();
        assert!(err.starts_with(name), "{err}");
    }
    assert!(MsvrParams::new(1.0, 0.0, 1.0)
        .check()
        .unwrap()
        .fit(&data)
        .is_ok());
}

#[test]
fn support_vectors_are_exactly_the_samples_outside_the_tube() {
    // At the optimum βᵢ = 0 exactly when uᵢ ≤ ε (the strict support set), so the model keeps
    // only the samples outside the tube.
    let train = hand_data("train");
    let eps = 0.05;
    let model = MsvrParams::new(300.0, eps, 0.3)
        .check()
        .unwrap()
        .fit(&train)
        .unwrap();
    let pred = model.predict(&train.inputs).unwrap();
    let outside = train
        .outputs
        .iter_rows()
        .zip(pred.iter_rows())
        .filter(|(y, p)| {
            y.iter()
                .zip(p.iter())
                .map(|(a, b)| (a - b) * (a - b))
                .sum::<f64>()
                .sqrt()
                > eps
        })
        .count();
    let svs = model.fit.support_vectors;
    assert!(
        svs < train.rows(),
        "no sparsity: {svs} of {} rows",
        train.rows()
    );
    assert!(
        outside.abs_diff(svs) <= 1,
        "{outside} samples outside the tube, {svs} support vectors"
    );
    assert_eq!(model.support_vector_count(), svs);
}

#[test]
fn the_robust_loss_resists_rows_far_off_the_surface() {
    // One training row in eight has its tip 3 mm off (a transient caught mid-move, a marker
    // lost for a frame): the quadratic loss bends the surface towards them, the robust loss
    // (linear beyond 10 ε) much less. The clean sweep measures the harm, against the same
    // losses fitted to the clean rows.
    let clean = hand_data("train");
    let mut corrupted = clean.clone();
    let width = clean.outputs.width();
    let mut values: Vec<f64> = clean.outputs.iter_rows().flatten().copied().collect();
    for row in (0..clean.rows()).step_by(8) {
        values[row * width] += 3.0;
    }
    corrupted.outputs = Columns::new(clean.outputs.names.clone(), values);
    let sweep = hand_data("sweep_a");
    let mae = |loss, train: &Dataset| {
        let model = MsvrParams::new(300.0, 0.02, 0.6)
            .loss(loss)
            .check()
            .unwrap()
            .fit(train)
            .unwrap();
        assert!(model.fit.converged, "{loss}");
        handcap::model::evaluate(&model, &sweep).unwrap().mae
    };
    let harm = |loss| mae(loss, &corrupted) - mae(loss, &clean);
    let (quadratic, robust) = (harm(Loss::Quadratic), harm(Loss::Robust));
    assert!(
        robust < 0.5 * quadratic,
        "the outliers add {robust} mm to the robust loss's error, {quadratic} mm to the quadratic's"
    );
}

#[test]
fn factor_updates_reach_the_same_optimum_with_fewer_factorisations() {
    // Rows join and leave the support set a few at a time once the first iterations are past:
    // the updated factor must give the optimum of a factor computed afresh at every change.
    // Every 50th row is an outlier, in the robust loss's linear part: its weight changes at
    // every iteration (a diagonal update).
    for (seed, loss) in [(5, Loss::Quadratic), (6, Loss::Robust)] {
        let (x, mut y) = random_problem(seed, 600, 3, 3);
        for i in (0..600).step_by(50) {
            y[(i, 0)] += 1.0;
        }
        let k = kernel::rbf(&x, &x, 0.4);
        let problem = Problem {
            kernel: k.as_ref(),
            targets: y.as_ref(),
            c: 50.0,
            epsilon: 0.02,
            loss,
            weights: Default::default(),
        };
        let fresh = irwls::solve(
            &problem,
            &SolverOptions {
                factor_updates: false,
                ..OPTIONS
            },
            None,
        )
        .unwrap();
        let updated = irwls::solve(&problem, &OPTIONS, None).unwrap();
        assert!(fresh.stop.converged() && updated.stop.converged());
        assert!(
            updated.factorizations < fresh.factorizations,
            "{loss}: {} factorisations with updates, {} without",
            updated.factorizations,
            fresh.factorizations
        );
        let rel = (updated.objective - fresh.objective).abs() / fresh.objective;
        assert!(rel < 1e-9, "{loss}: objectives differ by {rel:e}");
        let worst = (0..600)
            .flat_map(|i| (0..3).map(move |j| (i, j)))
            .map(|(i, j)| (updated.beta[(i, j)] - fresh.beta[(i, j)]).abs())
            .fold(0.0, f64::max);
        let scale = (0..600)
            .flat_map(|i| (0..3).map(move |j| (i, j)))
            .map(|(i, j)| fresh.beta[(i, j)].abs())
            .fold(0.0, f64::max);
        assert!(
            worst < 1e-6 * scale,
            "{loss}: β differs by {worst} (of {scale})"
        );
    }
}
