//! `handcap export --c`: the model as a C99 header, compiled by the system's C compiler and
//! run against `handcap predict` (issue 45).

use std::path::Path;
use std::process::Command;

use handcap::model::file::ModelFile;
use handcap::model::Differentiable;

use crate::common::{csv_rows, handcap_err, handcap_ok, tempdir, write};
use crate::history::{fit_lagging, lagging_plant, COLUMNS};

/// Reads `time_s` then the inputs per line, one series: `reset_at` the first row's inputs (as
/// `handcap predict` starts a group), `step` by each row's time difference; prints the outputs.
/// With `-s`, the settled map and its Jacobian at each line's inputs instead, and the settled
/// map's central differences (the Jacobian's check). With `-r`, each interval's level and
/// radius, a line each, and nothing else.
const HARNESS: &str = r#"
#include <stdio.h>
#include <string.h>
#include "model.h"
int main(int argc, char **argv) {
    double state[HANDCAP_STATE_LEN], u[HANDCAP_N_INPUTS], y[HANDCAP_N_OUTPUTS], t, last = 0;
    double jac[HANDCAP_N_OUTPUTS * HANDCAP_N_INPUTS];
    int first = 1, settled = argc > 1 && strcmp(argv[1], "-s") == 0, i, o;
    if (argc > 1 && strcmp(argv[1], "-r") == 0) {
#if HANDCAP_N_INTERVALS > 0
        for (i = 0; i < HANDCAP_N_INTERVALS; i++)
            printf("%.17g %.17g\n", handcap_interval_level[i], handcap_interval_radius[i]);
#endif
        return 0;
    }
    while (scanf("%lf", &t) == 1) {
        for (i = 0; i < HANDCAP_N_INPUTS; i++)
            if (scanf("%lf", &u[i]) != 1) return 1;
        if (settled) {
            handcap_predict(u, y);
            handcap_jacobian(u, jac);
            for (o = 0; o < HANDCAP_N_OUTPUTS; o++) printf("%.17g ", y[o]);
            for (i = 0; i < HANDCAP_N_OUTPUTS * HANDCAP_N_INPUTS; i++) printf("%.17g ", jac[i]);
            for (i = 0; i < HANDCAP_N_INPUTS; i++) {
                double up[HANDCAP_N_OUTPUTS], down[HANDCAP_N_OUTPUTS], keep = u[i], h = 1e-4;
                u[i] = keep + h; handcap_predict(u, up);
                u[i] = keep - h; handcap_predict(u, down);
                u[i] = keep;
                for (o = 0; o < HANDCAP_N_OUTPUTS; o++) printf("%.17g ", (up[o] - down[o]) / (2 * h));
            }
            printf("\n");
            continue;
        }
        if (first) { handcap_reset_at(state, u); last = t; first = 0; }
        handcap_step(state, t - last, u, y);
        last = t;
        for (o = 0; o < HANDCAP_N_OUTPUTS; o++) printf("%.17g ", y[o]);
        printf("\n");
    }
    return 0;
}
"#;

/// Compiles the harness with `header` as strictly as C99 allows (warnings are errors).
fn compile(dir: &Path) -> std::path::PathBuf {
    write(dir, "harness.c", HARNESS);
    let exe = dir.join("harness");
    let out = Command::new("cc")
        .current_dir(dir)
        .args([
            "-std=c99",
            "-pedantic",
            "-Wall",
            "-Wextra",
            "-Werror",
            "-O2",
        ])
        .args(["harness.c", "-lm", "-o"])
        .arg(&exe)
        .output()
        .expect("the system C compiler (cc) runs");
    assert!(
        out.status.success(),
        "the header compiles: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    exe
}

/// Runs the harness with `flag` on `rows` (`time inputs…` per row), one line of numbers per
/// row.
fn run(exe: &Path, flag: Option<&str>, rows: &[Vec<f64>]) -> Vec<Vec<f64>> {
    use std::io::Write as _;
    let mut child = Command::new(exe)
        .args(flag)
        .stdin(std::process::Stdio::piped())
        .stdout(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let mut text = String::new();
    for r in rows {
        let line: Vec<String> = r.iter().map(f64::to_string).collect();
        text.push_str(&line.join(" "));
        text.push('\n');
    }
    child
        .stdin
        .take()
        .unwrap()
        .write_all(text.as_bytes())
        .unwrap();
    let out = child.wait_with_output().unwrap();
    assert!(out.status.success());
    String::from_utf8(out.stdout)
        .unwrap()
        .lines()
        .map(|l| l.split_whitespace().map(|v| v.parse().unwrap()).collect())
        .collect()
}

/// The largest difference between `a` and `b` relative to the largest magnitude in `b`.
fn relative(a: &[f64], b: &[f64]) -> f64 {
    let scale = b.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    a.iter()
        .zip(b)
        .fold(0.0f64, |m, (x, y)| m.max((x - y).abs()))
        / scale
}

#[test]
fn the_c_header_predicts_what_handcap_predict_does() {
    let dir = tempdir();
    let d = dir.path();
    write(d, "train.csv", &lagging_plant(1, 4, 80));
    write(d, "test.csv", &lagging_plant(2, 1, 80));
    for (history, model) in [
        ("ema:0.2,0.8", "history.json"),
        ("lags:2", "lags.json"),
        ("none", "static.json"),
    ] {
        fit_lagging(d, history, model);
        let said = handcap_ok(d, &["export", model, "--c", "model.h"]);
        assert!(said.contains("wrote model.h"), "{said}");
        let exe = compile(d);

        // Along the held-out trial, step by step: `handcap predict`'s outputs.
        handcap_ok(d, &["predict", model, "test.csv", "--out", "pred.csv"]);
        let test = csv_rows(&d.join("test.csv"));
        let rows: Vec<Vec<f64>> = test
            .iter()
            .map(|r| {
                ["t_s", "P1_kpa", "P2_kpa"]
                    .map(|k| r[k].parse().unwrap())
                    .to_vec()
            })
            .collect();
        let c: Vec<f64> = run(&exe, None, &rows).concat();
        let rust: Vec<f64> = csv_rows(&d.join("pred.csv"))
            .iter()
            .flat_map(|r| ["x_mm", "y_mm"].map(|k| r[k].parse::<f64>().unwrap()))
            .collect();
        assert_eq!(c.len(), rust.len());
        let differs = relative(&c, &rust);
        assert!(
            differs <= 1e-9,
            "{model}: C against predict, {differs:e} relative"
        );

        // The settled map and its Jacobian: against the Rust model's (issue 61: they were
        // checked only against the header's own finite differences), and the Jacobian against
        // the map's central differences.
        let settled = run(&exe, Some("-s"), &rows);
        let file = ModelFile::load(&d.join(model)).unwrap();
        let steady = file.steady_state();
        for (line, row) in settled.iter().zip(&rows) {
            let (map, jac, fd) = (&line[..2], &line[2..6], &line[6..10]);
            let (mut out, mut rust_jac) = ([0.0; 2], [0.0; 4]);
            steady.predict_with_jacobian(&row[1..], &mut out, &mut rust_jac);
            assert!(
                relative(map, &out) <= 1e-12,
                "{model}: {map:?} against {out:?}"
            );
            assert!(
                relative(jac, &rust_jac) <= 1e-10,
                "{model}: Jacobian {jac:?} against the Rust model's {rust_jac:?}"
            );
            // fd is column by column (input-major), jac row-major (output-major).
            let fd_rows = [fd[0], fd[2], fd[1], fd[3]];
            let differs = relative(jac, &fd_rows);
            assert!(
                differs <= 1e-5,
                "{model}: Jacobian {jac:?} against {fd_rows:?}"
            );
        }
        if history == "none" {
            // Without history, settled and stepped are the same map.
            assert!(
                relative(
                    &settled
                        .iter()
                        .flat_map(|l| l[..2].to_vec())
                        .collect::<Vec<_>>(),
                    &rust
                ) <= 1e-12
            );
        }
    }
}

#[test]
fn the_c_header_carries_the_model_files_interval_radii() {
    let dir = tempdir();
    let d = dir.path();
    write(d, "train.csv", &lagging_plant(1, 4, 80));
    let mut args = vec!["model", "train.csv"];
    args.extend(COLUMNS);
    args.extend(["--c", "100", "--epsilon", "0.01", "--sigma", "2"]);
    for (intervals, model) in [(true, "with.json"), (false, "without.json")] {
        let mut args = args.clone();
        args.extend(intervals.then_some("--intervals"));
        args.extend(["--out", model]);
        handcap_ok(d, &args);
        handcap_ok(d, &["export", model, "--c", "model.h"]);
        let header = std::fs::read_to_string(d.join("model.h")).unwrap();
        let printed = run(&compile(d), Some("-r"), &[]);
        let file = ModelFile::load(&d.join(model)).unwrap();
        let radii = file.intervals.map(|i| i.held_out.radii).unwrap_or_default();
        assert_eq!(radii.is_empty(), !intervals, "{model}");
        assert!(
            header.contains(&format!("#define HANDCAP_N_INTERVALS {}", radii.len())),
            "{header}"
        );
        // The same numbers, to the bit, at the same levels.
        let expected: Vec<Vec<f64>> = radii.iter().map(|r| vec![r.level, r.radius]).collect();
        assert_eq!(printed, expected, "{model}");
    }
}

#[test]
fn export_refuses_what_is_not_a_model_and_writes_nothing() {
    let dir = tempdir();
    let d = dir.path();
    write(d, "data.csv", "P1_kpa,x_mm\n1,2\n");
    let err = handcap_err(d, &["export", "data.csv", "--c", "model.h"]);
    assert!(
        err.contains("data.csv") && err.lines().count() == 1,
        "{err}"
    );
    assert!(!d.join("model.h").exists());
}

/// Calls the header's functions on the inputs that have no answer and prints what they return:
/// a negative, an infinite and a NaN `dt_s`, an infinite and a NaN input, then a step whose
/// outputs must equal a fresh filter's (the state left as it was), and inputs outside the
/// training range.
const HOSTILE: &str = r#"
#include <math.h>
#include <stdio.h>
#include "model.h"
int main(void) {
    double state[HANDCAP_STATE_LEN], fresh[HANDCAP_STATE_LEN], u[HANDCAP_N_INPUTS];
    double y[HANDCAP_N_OUTPUTS], z[HANDCAP_N_OUTPUTS], jac[HANDCAP_N_OUTPUTS * HANDCAP_N_INPUTS];
    double dts[3];
    int i, k, r;
    dts[0] = -0.1; dts[1] = INFINITY; dts[2] = NAN;
    for (i = 0; i < HANDCAP_N_INPUTS; i++) u[i] = 100.0;
    handcap_reset_at(state, u);
    handcap_reset_at(fresh, u);
    for (i = 0; i < HANDCAP_N_INPUTS; i++) u[i] = 120.0;
    for (k = 0; k < 3; k++) {
        r = handcap_step(state, dts[k], u, y);
        printf("dt %d %d\n", r, isnan(y[0]) != 0);
    }
    u[0] = INFINITY;
    r = handcap_step(state, 0.1, u, y);
    printf("inf %d %d\n", r, isnan(y[0]) != 0);
    r = handcap_predict(u, y);
    printf("inf-predict %d %d\n", r, isnan(y[0]) != 0);
    r = handcap_jacobian(u, jac);
    printf("inf-jacobian %d %d\n", r, isnan(jac[0]) != 0);
    u[0] = NAN;
    r = handcap_step(state, 0.1, u, y);
    printf("nan %d %d\n", r, isnan(y[0]) != 0);
    u[0] = 120.0;
    handcap_step(state, 0.1, u, y);
    handcap_step(fresh, 0.1, u, z);
    printf("kept %d\n", y[0] == z[0] && y[1] == z[1]);
    printf("inside %d\n", handcap_step(state, 0.1, u, y));
    u[0] = 1e4;
    r = handcap_step(state, 0.1, u, y);
    k = handcap_predict(u, z);
    printf("outside %d %d %d\n", r, k, isfinite(y[0]) && isfinite(z[0]));
    return 0;
}
"#;

/// Hostile probe 7 (issue 61): `handcap_step` with a negative or infinite `dt` extrapolated its
/// filters, an infinite input gave the bias as a finite tip, a NaN poisoned the state until a
/// reset, nothing said an input was outside the training range; a `/*` in a name or path and a
/// model without support vectors broke the compile; the header carried the machine's absolute
/// paths.
#[test]
fn hostile_c_header_refuses_what_has_no_answer_and_always_compiles() {
    let dir = tempdir();
    let d = dir.path();
    write(d, "train.csv", &lagging_plant(1, 4, 80));
    fit_lagging(d, "ema:0.2,0.8", "history.json");
    let model = d.join("history.json");
    handcap_ok(d, &["export", model.to_str().unwrap(), "--c", "model.h"]);
    let header = std::fs::read_to_string(d.join("model.h")).unwrap();
    let home = d.to_str().unwrap();
    assert!(!header.contains(home), "the header names {home}");
    write(d, "hostile.c", HOSTILE);
    let exe = d.join("hostile");
    let cc = Command::new("cc")
        .current_dir(d)
        .args(["-std=c99", "-pedantic", "-Wall", "-Wextra", "-Werror"])
        .args(["hostile.c", "-lm", "-o"])
        .arg(&exe)
        .output()
        .unwrap();
    assert!(
        cc.status.success(),
        "{}",
        String::from_utf8_lossy(&cc.stderr)
    );
    let out = String::from_utf8(Command::new(&exe).output().unwrap().stdout).unwrap();
    assert_eq!(
        out,
        "dt -1 1\ndt -1 1\ndt -1 1\ninf -1 1\ninf-predict -1 1\ninf-jacobian -1 1\n\
         nan -1 1\nkept 1\ninside 0\noutside 1 1 1\n"
    );

    // A `/*` in the names and the path, and a model without support vectors (its file
    // emptied of them: a constant, the bias): the strict compile passes.
    let odd = std::fs::read_to_string(d.join("train.csv"))
        .unwrap()
        .replacen("P1_kpa", "P1/*a*/_kpa", 1);
    std::fs::create_dir(d.join("runs")).unwrap();
    write(&d.join("runs"), "odd.csv", &odd);
    let mut args = vec!["model", "runs/odd.csv", "--inputs", "P1/*a*/_kpa,P2_kpa"];
    args.extend(&COLUMNS[2..]);
    args.extend(["--search", "none", "--c", "100", "--epsilon", "0.01"]);
    args.extend(["--sigma", "2", "--out", "runs/*odd.json"]);
    handcap_ok(d, &args);
    let mut json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(d.join("runs/*odd.json")).unwrap()).unwrap();
    json["model"]["support_vectors"] = serde_json::json!([]);
    json["model"]["coefficients"] = serde_json::json!([]);
    write(&d.join("runs"), "*empty.json", &json.to_string());
    handcap_ok(d, &["export", "runs/*empty.json", "--c", "model.h"]);
    let header = std::fs::read_to_string(d.join("model.h")).unwrap();
    assert!(header.contains("#define HANDCAP_N_CENTRES 0"), "{header}");
    let exe = compile(d);
    let settled = run(&exe, Some("-s"), &[vec![0.0, 50.0, 50.0]]);
    let file = ModelFile::load(&d.join("runs/*empty.json")).unwrap();
    let mut bias = [0.0; 2];
    file.steady_state()
        .predict_with_jacobian(&[50.0, 50.0], &mut bias, &mut [0.0; 4]);
    assert_eq!(&settled[0][..2], &bias[..]);
}
