//! `report.md`: the model run in words and tables (errors, the previous model, the input
//! history, the intervals, the sweeps' figures).

use std::fmt::Write as _;

use super::{IntervalReport, ModelReport, PreviousSummary, SweepFigures, TestResult};
use crate::data::format_number;
use crate::model::history::HistoryDecision;
use crate::model::interval::Coverage;
use crate::select::family::FamilyDecision;
use crate::select::tune::SearchSummary;

/// The previous model's constants, default and calibrated, and how the calibration went.
pub(super) fn previous_section(p: &PreviousSummary) -> String {
    let (d, c) = (&p.default, &p.calibrated);
    let mut s = String::from("## Previous physics model\n\n");
    s += "The constant-curvature model of the paper's §2.2 (eqs. 1-7): McKibben muscle lengths, the plane through three cylinder tops, one arc. `previous-default` uses the documented physical constants; `previous-calibrated` fits five of them to the training data by Levenberg-Marquardt.\n\n";
    s += "| constant | default | calibrated |\n|---|---|---|\n";
    let rows = [
        (
            "rest braid angle α₀ (°)",
            d.braid_angle_deg,
            c.braid_angle_deg,
        ),
        ("load stiffness K (N)", d.load_n, c.load_n),
        (
            "threshold pressure P_th (kPa)",
            d.threshold_kpa,
            c.threshold_kpa,
        ),
        ("lever-arm scale s_x", d.arm_x, c.arm_x),
        ("lever-arm scale s_y", d.arm_y, c.arm_y),
    ];
    for (name, a, b) in rows {
        let _ = writeln!(s, "| {name} | {a:.4} | {b:.4} |");
    }
    let cal = &p.calibration;
    let _ = writeln!(
        s,
        "\nFixed: L₀ = {} mm, muscle bore D₀ = {} mm, n = {} pieces. Calibration on {} rows: residual RMS {:.4} mm per coordinate, {} evaluations, {} ({}), best of starts at α₀ = {:?}°.\n",
        d.length_mm,
        d.bore_mm,
        d.pieces,
        cal.rows,
        cal.rms_mm,
        cal.evaluations,
        if cal.converged { "converged" } else { "NOT converged" },
        cal.termination,
        cal.start_braid_angles_deg
    );
    s
}

/// The table of held-out errors, as printed and as in `report.md`.
pub fn errors_table(tests: &[TestResult], outputs: &[String]) -> String {
    let mut out = format!(
        "| model | test | rows | MAE | mean Euclidean | max Euclidean | {} |\n",
        outputs
            .iter()
            .map(|o| format!("MAE {o}"))
            .collect::<Vec<_>>()
            .join(" | ")
    );
    out += &format!(
        "|---|---|---|---|---|---|{}\n",
        "---|".repeat(outputs.len())
    );
    for t in tests {
        let e = &t.errors;
        let _ = writeln!(
            out,
            "| {} | {} | {} | {:.4} | {:.4} | {:.4} | {} |",
            t.model,
            t.test,
            e.rows,
            e.mae,
            e.euclid,
            e.max_euclid,
            e.per_output_mae
                .iter()
                .map(|v| format!("{v:.4}"))
                .collect::<Vec<_>>()
                .join(" | ")
        );
    }
    out
}

/// The model's family: which, why, and each one `auto` searched.
fn family_section(family: &FamilyDecision) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "Model: {} ({}).\n", family.used.title(), family.reason);
    if !family.tried.is_empty() {
        let _ = writeln!(
            s,
            "| model | cross-validated fitness | held-out MAE per fold | C | ε | σ |"
        );
        let _ = writeln!(s, "|---|---|---|---|---|---|");
        for t in &family.tried {
            let folds: Vec<String> = t.folds.iter().map(|v| format!("{v:.4}")).collect();
            let p = &t.params;
            let _ = writeln!(
                s,
                "| {} | {:.5} | {} | {:.4} | {:.4} | {:.4} |",
                t.family.title(),
                t.fitness,
                folds.join(", "),
                p.c,
                p.epsilon,
                p.sigma
            );
        }
        s.push('\n');
    }
    s
}

/// Whether the model sees its inputs' history: what was used, why, and what was compared.
pub(super) fn history_section(h: &HistoryDecision) -> String {
    let mut s = String::new();
    match &h.used {
        Some(used) => {
            let _ = writeln!(
                s,
                "Input history: {} on time column `{}`{} ({}). The model's inputs are the present inputs and their history features; `predict` needs the time{} column, and `inverse` uses the steady state (every filter equal to the input).\n",
                used.memory,
                used.time,
                used.group
                    .as_ref()
                    .map_or_else(String::new, |g| format!(", restarted in each `{g}`")),
                h.reason,
                if used.group.is_some() { " and group" } else { "" }
            );
        }
        None => {
            let _ = writeln!(s, "Input history: none ({}).\n", h.reason);
        }
    }
    if !h.tried.is_empty() {
        let _ = writeln!(s, "| inputs | cross-validated fitness |");
        let _ = writeln!(s, "|---|---|");
        for t in &h.tried {
            let name = t
                .memory
                .as_ref()
                .map_or_else(|| "present only".to_string(), |m| format!("present + {m}"));
            let _ = writeln!(s, "| {name} | {:.5} |", t.fitness);
        }
        s.push('\n');
    }
    if !h.screened.is_empty() {
        let _ = writeln!(
            s,
            "Time constants screened on a small grid around the present-input model's parameters (σ widened by √copies, then ×½, 1; C ×1, 10), each at its best point; the best was searched:\n"
        );
        let _ = writeln!(s, "| history | cross-validated fitness |");
        let _ = writeln!(s, "|---|---|");
        for t in &h.screened {
            if let Some(m) = &t.memory {
                let _ = writeln!(s, "| {m} | {:.5} |", t.fitness);
            }
        }
        s.push('\n');
    }
    s
}

/// A group's label as the data write it (integers without ".0").
pub(super) fn group_label(g: Option<f64>) -> String {
    g.map_or_else(|| "all".into(), format_number)
}

/// Percent with one decimal.
pub(super) fn percent(share: f64) -> String {
    format!("{:.1} %", share * 100.0)
}

/// The conformal radii, what they promise, and how they covered each test file and group.
pub(super) fn intervals_section(report: &IntervalReport) -> String {
    let i = &report.held_out;
    let mut s = String::new();
    let _ = writeln!(
        s,
        "## Prediction intervals
"
    );
    if i.radii.is_empty() {
        let _ = writeln!(
            s,
            "None: {} held-out rows are too few for a 90 % radius (it needs 9).
",
            i.rows
        );
        return s;
    }
    let _ = writeln!(
        s,
        "Conformal radii of the tip's Euclidean error ‖y − ŷ‖₂ (output units), from {} held-out rows of the cross-validation ({}): {}. `handcap predict --interval 0.9` writes the radius beside each prediction.
",
        i.rows,
        i.folds,
        i.radii
            .iter()
            .map(|r| format!("{} within {:.4}", percent(r.level), r.radius))
            .collect::<Vec<_>>()
            .join(", ")
    );
    if report.widens {
        let _ = writeln!(
            s,
            "These are the radii where the inputs are as near the training rows as nine held-out rows in ten were; farther from them the radius widens by the spread of a Gaussian process with the model's kernel (conditioned on the training rows) over that of those rows, and `predict` writes each row's.
"
        );
    }
    let _ = writeln!(
        s,
        "The guarantee is marginal: over new rows exchangeable with the held-out ones, at least that share falls within the radius. It is not a promise for each input or each run: a run unlike the training runs (another day, a drifted actuator) can fall outside more often. The coverage per group below shows where.
"
    );
    if let Some(band) = &i.runs {
        let _ = writeln!(
            s,
            "Per-run band, from the worst error of each of the {} held-out runs: {}.
",
            band.worst.len(),
            match band.radii.as_slice() {
                [] => "none (a 90 % band needs 9 runs)".to_string(),
                radii => radii
                    .iter()
                    .map(|r| format!(
                        "{} of whole runs stay within {:.4}",
                        percent(r.level),
                        r.radius
                    ))
                    .collect::<Vec<_>>()
                    .join(", "),
            }
        );
    }
    let first = i.radii[0];
    if !i.groups.is_empty() {
        let _ = writeln!(
            s,
            "Held-out groups at the {} radius ({:.4}):
",
            percent(first.level),
            first.radius
        );
        s += &coverage_table(&i.groups);
    }
    for t in &report.tests {
        let pooled = t
            .coverage
            .pooled
            .iter()
            .map(|(r, c)| {
                format!(
                    "{} covered at {} ({:.4})",
                    percent(*c),
                    percent(r.level),
                    r.radius
                )
            })
            .collect::<Vec<_>>()
            .join("; ");
        let runs = t
            .coverage
            .runs
            .iter()
            .map(|r| {
                format!(
                    "; {} of {} whole runs inside the {} band ({:.4})",
                    r.inside,
                    r.runs,
                    percent(r.radius.level),
                    r.radius.radius
                )
            })
            .collect::<String>();
        let _ = writeln!(
            s,
            "Test `{}`: {pooled}{runs}.
",
            t.test
        );
        if let (Some(column), false) = (&t.column, t.coverage.groups.is_empty()) {
            let _ = writeln!(
                s,
                "Per `{column}` at the {} radius:
",
                percent(first.level)
            );
            s += &coverage_table(&t.coverage.groups);
        }
    }
    s
}

pub(super) fn coverage_table(groups: &[Coverage]) -> String {
    let mut s = String::from("| group | rows | covered |\n|---|---|---|\n");
    for g in groups {
        let _ = writeln!(
            s,
            "| {} | {} | {} |",
            group_label(g.group),
            g.rows,
            percent(g.covered)
        );
    }
    s.push('\n');
    s
}

/// The search's section of the report: what it did and what it found.
fn search_section(s: &mut String, search: &SearchSummary) {
    let _ = writeln!(s, "## Hyper-parameter search\n");
    let _ = writeln!(
        s,
        "{} scored by {}{}: {} iterations, stopped by {:?}; {} candidates scored ({} stopped early by racing, {} fits, {} memo hits). Best fitness {:.5} at C = {}, ε = {}, σ = {}. Per-iteration history: `history.csv`; Figures 7-8: `fig7_min_mae.png`, `fig8_mean_mae.png` (and `.svg`).\n",
        search.method,
        search.fitness,
        search
            .folds
            .as_ref()
            .map(|f| format!(" over {f}"))
            .unwrap_or_default(),
        search.iterations,
        search.stop,
        search.evaluations,
        search.raced,
        search.fits,
        search.memo_hits,
        search.best_fitness,
        search.best.c,
        search.best.epsilon,
        search.best.sigma
    );
}

pub(super) fn markdown(r: &ModelReport, sweeps: &[SweepFigures]) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "# handcap model report\n");
    let _ = writeln!(
        s,
        "{} fitted on `{}`: inputs {} → outputs {} (errors in output units; mm for the micro-hand).\n",
        r.family.used.title(),
        r.training_file,
        r.inputs.join(", "),
        r.outputs.join(", ")
    );
    if let Some(search) = &r.search {
        search_section(&mut s, search);
    }
    let _ = writeln!(s, "## Fit\n");
    let settings = r.settings();
    let head: Vec<&str> = settings.iter().map(|(name, _)| *name).collect();
    let _ = writeln!(
        s,
        "| {} | rows | iterations | objective | terms | converged | stop |",
        head.join(" | ")
    );
    let _ = writeln!(s, "|{}", "---|".repeat(settings.len() + 6));
    let values: Vec<&str> = settings.iter().map(|(_, v)| v.as_str()).collect();
    let _ = writeln!(
        s,
        "| {} | {} | {} | {:.6e} | {} | {} | {:?} |\n",
        values.join(" | "),
        r.fit.rows,
        r.fit.iterations,
        r.fit.objective,
        r.fit.support_vectors,
        r.fit.converged,
        r.fit.stop
    );
    let _ = writeln!(
        s,
        "Basis: {} ({}). Terms are the kernel's centres: support vectors of an exact fit, the kept centres of a reduced one.\n",
        r.basis.basis, r.basis.reason
    );
    if !r.basis.tried.is_empty() {
        let _ = writeln!(s, "| centres | kept at σ | cross-validated fitness |");
        let _ = writeln!(s, "|---|---|---|");
        for t in &r.basis.tried {
            let _ = writeln!(s, "| {} | {} | {:.5} |", t.centres, t.kept, t.fitness);
        }
        s.push('\n');
    }
    s += &family_section(&r.family);
    if let Some(h) = &r.history {
        s += &history_section(h);
    }
    let _ = writeln!(
        s,
        "Training error (the data the model was fitted on, not a test): MAE {:.4}, mean Euclidean {:.4}.\n",
        r.train_errors.mae, r.train_errors.euclid
    );
    if let Some(p) = &r.previous {
        s += &previous_section(p);
    }
    if !r.tests.is_empty() {
        let _ = writeln!(s, "## Held-out errors\n");
        let _ = writeln!(
            s,
            "Errors on test files the models were not fitted on (`metrics.csv` has the same numbers).\n"
        );
        s += &errors_table(&r.tests, &r.outputs);
        s.push('\n');
    }
    if let Some(i) = &r.intervals {
        s += &intervals_section(i);
    }
    if !sweeps.is_empty() {
        let _ = writeln!(s, "## Sweeps (the paper's Figures 9-14)\n");
        let _ = writeln!(
            s,
            "Each output against the swept pressure: measured points and every model's curve; then every model's Euclidean tip error at the measured points (log scale). The paper's Figures 9-11 are its sweep A (P1 = P2 = 0, P3 rising), Figures 12-14 its sweep B (P1 = 0, P2 = P3 rising).\n"
        );
        for f in sweeps {
            let _ = writeln!(s, "### {} — {} swept, {}\n", f.test, f.sweep_label, f.held);
            for stem in &f.stems {
                let _ = writeln!(s, "![{stem}]({stem}.png)");
            }
            s.push('\n');
        }
    }
    let _ = writeln!(s, "## Provenance\n");
    let _ = writeln!(s, "- handcap {}", r.provenance.handcap_version);
    let _ = writeln!(s, "- command: `{}`", r.provenance.command.join(" "));
    if let Some(seed) = r.provenance.seed {
        let _ = writeln!(s, "- seed: {seed}");
    }
    for input in &r.provenance.inputs {
        let _ = writeln!(s, "- input `{}` sha256 `{}`", input.path, input.sha256);
    }
    s
}
