//! The dynamic inverse and learning from repetitions (issue 45), on the virtual plant in time
//! (`synth::dynamics`, no cameras): a history model fitted on a dynamic session follows a
//! figure-eight far better than the pointwise inverse of its settled map, and learning closes
//! the rest of the gap on the plant the model only approximates.

use std::fmt::Write as _;
use std::path::Path;

use handcap::session::protocol::{self, DynamicDesign};
use handcap::synth::dynamics::{Dynamics, Motion};
use handcap::synth::plant::{Plant, PlantParams, Pressures};

use crate::common::{csv_rows, handcap, handcap_err, handcap_ok, tempdir, write};

/// Camera rate of the sessions and the path (Hz).
const RATE: f64 = 30.0;

/// The plant's tip (hand frame, origin at rest) at `t` of a motion.
fn tip(plant: &Plant, motion: &Motion, t: f64) -> [f64; 3] {
    let rest = plant.tip([0.0; 3]).unwrap();
    let p = plant.tip(motion.at(t)).unwrap();
    std::array::from_fn(|i| p[i] - rest[i])
}

/// A dynamic session on the plant, logged at [`RATE`]: time_s,phase,P1..P3 (in force),x,y,z.
fn session(
    plant: &Plant,
    dynamics: &Dynamics,
    seed: u64,
    trials: usize,
    duration_s: f64,
) -> String {
    let design = DynamicDesign {
        duration_s,
        rate_hz: RATE,
        trials,
        seed,
        max_kpa: 250.0,
    };
    let steps = protocol::dynamic(&design).unwrap();
    let (starts, end) = protocol::start_times(&steps);
    let commands: Vec<(f64, Pressures)> = starts
        .iter()
        .zip(&steps)
        .map(|(&t, s)| (t, s.pressures))
        .collect();
    let motion = Motion::simulate(&commands, dynamics, 0.0, end);
    let mut csv = String::from("time_s,phase,P1_kpa,P2_kpa,P3_kpa,x_mm,y_mm,z_mm\n");
    let mut k = 0;
    for (i, s) in steps.iter().enumerate() {
        let until = starts.get(i + 1).copied().unwrap_or(end);
        while (k as f64) / RATE < until {
            let t = k as f64 / RATE;
            let x = tip(plant, &motion, t);
            let p = s.pressures;
            let _ = writeln!(
                csv,
                "{t:.6},{},{},{},{},{:.6},{:.6},{:.6}",
                s.phase, p[0], p[1], p[2], x[0], x[1], x[2]
            );
            k += 1;
        }
    }
    csv
}

/// A figure-eight of ±2.5 × ±1.5 mm and period `period_s` about the tip at 125 kPa each,
/// after a 1.5 s lead-in at its centre: time_s,x_mm,y_mm,z_mm (and the rows to score from).
/// Each point is the settled tip of pressures inside the box (the pressures that move the
/// tip by the figure's offsets to first order), so the whole path is within reach once settled.
pub fn figure_eight(plant: &Plant, period_s: f64) -> (String, usize) {
    let rest = plant.tip([0.0; 3]).unwrap();
    let centre = [125.0; 3];
    let j = settled_jacobian(plant, centre);
    let lead = (1.5 * RATE) as usize;
    let rows = lead + (2.0 * period_s * RATE) as usize;
    let mut csv = String::from("time_s,x_mm,y_mm,z_mm\n");
    for k in 0..rows {
        let t = k as f64 / RATE;
        let phase = std::f64::consts::TAU * (t - 1.5).max(0.0) / period_s;
        let offset = [2.5 * phase.sin(), 1.5 * (2.0 * phase).sin(), 0.0];
        let dp = solve3(j, offset);
        let p: Pressures = std::array::from_fn(|i| centre[i] + dp[i]);
        assert!(p.iter().all(|&v| (10.0..=240.0).contains(&v)), "{p:?}");
        let x = plant.tip(p).unwrap();
        let _ = writeln!(
            csv,
            "{t:.6},{:.6},{:.6},{:.6}",
            x[0] - rest[0],
            x[1] - rest[1],
            x[2] - rest[2]
        );
    }
    (csv, lead)
}

/// ∂tip/∂P of the plant's settled map at `p` (central differences of 1 kPa): `j[i][o]` is
/// output o's derivative over pressure i.
fn settled_jacobian(plant: &Plant, p: Pressures) -> [[f64; 3]; 3] {
    std::array::from_fn(|i| {
        let (mut up, mut down) = (p, p);
        up[i] += 1.0;
        down[i] -= 1.0;
        let (a, b) = (plant.tip(up).unwrap(), plant.tip(down).unwrap());
        std::array::from_fn(|o| (a[o] - b[o]) / 2.0)
    })
}

/// The pressure change Δ with Σ_i j[i] Δ_i = `b` (Cramer's rule).
fn solve3(j: [[f64; 3]; 3], b: [f64; 3]) -> [f64; 3] {
    let det = |c: [[f64; 3]; 3]| {
        c[0][0] * (c[1][1] * c[2][2] - c[2][1] * c[1][2])
            - c[1][0] * (c[0][1] * c[2][2] - c[2][1] * c[0][2])
            + c[2][0] * (c[0][1] * c[1][2] - c[1][1] * c[0][2])
    };
    std::array::from_fn(|i| {
        let mut m = j;
        m[i] = b;
        det(m) / det(j)
    })
}

/// A finger the commands are played on: its settled map, its dynamics and its play (kPa).
struct Bench<'a> {
    plant: &'a Plant,
    dynamics: Dynamics,
    play_kpa: f64,
}

/// A textbook P-type ILC handed the bench's own settled map and each muscle's lead (its delay and
/// lag, in rows): the first commands are, muscle by muscle, the settled inverse of the target
/// that muscle's lead ahead (Newton's method on the map); each repetition adds `gain` times the
/// map's inverse Jacobian applied to the error a muscle's lead ahead (that muscle's share),
/// smoothed by a zero-phase moving average of ±`q_half` rows (the Q-filter). Plays `reps`
/// repetitions after the first; the tracking RMS of each.
fn textbook_ilc(
    d: &Path,
    bench: &Bench,
    first: &[Pressures],
    gain: f64,
    q_half: usize,
    (lead, reps): (usize, usize),
) -> Vec<f64> {
    let plant = bench.plant;
    let targets = tips(&d.join("target.csv"));
    let leads = muscle_leads(&bench.dynamics);
    let clamp = |p: [f64; 3]| p.map(|v| v.clamp(0.0, 250.0));
    let mut u = first.to_vec();
    let n = u.len();
    let mut errors = Vec::new();
    for rep in 0..=reps {
        write_commands(d, &u);
        errors.push(play(d, bench, lead));
        if rep == reps {
            break;
        }
        let run = tips(&d.join("run.csv"));
        let steps: Vec<[f64; 3]> = (0..n)
            .map(|k| {
                let j = settled_jacobian(plant, u[k]);
                std::array::from_fn(|i| {
                    let at = (k + leads[i]).min(n - 1);
                    let e: [f64; 3] = std::array::from_fn(|o| targets[at][o] - run[at][o]);
                    solve3(j, e)[i]
                })
            })
            .collect();
        for (k, p) in u.iter_mut().enumerate() {
            let (lo, hi) = (k.saturating_sub(q_half), (k + q_half).min(n - 1));
            let step: [f64; 3] = std::array::from_fn(|i| {
                (lo..=hi).map(|j| steps[j][i]).sum::<f64>() / (hi - lo + 1) as f64
            });
            *p = clamp(std::array::from_fn(|i| p[i] + gain * step[i]));
        }
    }
    errors
}

/// Each muscle's lead: its delay and lag in rows of the path.
fn muscle_leads(dynamics: &Dynamics) -> [usize; 3] {
    dynamics
        .lag_s
        .map(|lag| ((dynamics.delay_s + lag) * RATE).round() as usize)
}

/// The textbook ILC's first commands on `bench`: muscle by muscle, the settled inverse of the
/// target its lead ahead.
fn textbook_start(d: &Path, bench: &Bench) -> Vec<Pressures> {
    let plant = bench.plant;
    let rest = plant.tip([0.0; 3]).unwrap();
    let targets = tips(&d.join("target.csv"));
    let inverse: Vec<Pressures> = targets
        .iter()
        .map(|target| {
            let mut p = [125.0; 3];
            for _ in 0..20 {
                let x = plant.tip(p).unwrap();
                let miss: [f64; 3] = std::array::from_fn(|o| target[o] - (x[o] - rest[o]));
                let step = solve3(settled_jacobian(plant, p), miss);
                p = std::array::from_fn(|i| (p[i] + step[i]).clamp(0.0, 250.0));
            }
            p
        })
        .collect();
    let leads = muscle_leads(&bench.dynamics);
    let n = inverse.len();
    (0..n)
        .map(|k| std::array::from_fn(|i| inverse[(k + leads[i]).min(n - 1)][i]))
        .collect()
}

/// The textbook ILC tuned on `bench`: of the gains 0.3-1 and Q-filters of ±0-0.2 s, the one
/// whose sixth repetition tracks best; its tracking RMS per repetition.
fn tuned_textbook_ilc(d: &Path, bench: &Bench, lead: usize) -> Vec<f64> {
    let first = textbook_start(d, bench);
    let mut best: Option<Vec<f64>> = None;
    for gain in [0.3, 0.5, 0.75, 1.0] {
        for q_half in [0, 3, 6] {
            let errors = textbook_ilc(d, bench, &first, gain, q_half, (lead, 6));
            if best.as_ref().is_none_or(|b| errors[6] < b[6]) {
                best = Some(errors);
            }
        }
    }
    best.unwrap()
}

/// Writes `commands.csv`: one row per path row, at [`RATE`].
fn write_commands(d: &Path, u: &[Pressures]) {
    let mut csv = String::from("time_s,P1_kpa,P2_kpa,P3_kpa\n");
    for (k, p) in u.iter().enumerate() {
        let _ = writeln!(csv, "{:.6},{},{},{}", k as f64 / RATE, p[0], p[1], p[2]);
    }
    write(d, "commands.csv", &csv);
}

/// The x, y, z of every row of a CSV file.
fn tips(path: &Path) -> Vec<[f64; 3]> {
    csv_rows(path)
        .iter()
        .map(|r| ["x_mm", "y_mm", "z_mm"].map(|k| r[k].parse::<f64>().unwrap()))
        .collect()
}

/// Plays `commands.csv` on the bench; writes the tip at each row's time to `run.csv` (the
/// bench's truth: no camera in between) and returns the tracking RMS against `target.csv` from
/// row `from` on.
fn play(d: &Path, bench: &Bench, from: usize) -> f64 {
    let rows = csv_rows(&d.join("commands.csv"));
    let f = |r: &std::collections::HashMap<String, String>, k: &str| r[k].parse::<f64>().unwrap();
    let commands: Vec<(f64, Pressures)> = rows
        .iter()
        .map(|r| {
            (
                f(r, "time_s"),
                [f(r, "P1_kpa"), f(r, "P2_kpa"), f(r, "P3_kpa")],
            )
        })
        .collect();
    let end = commands.last().unwrap().0 + 1.0;
    let motion = Motion::simulate(&commands, &bench.dynamics, bench.play_kpa, end);
    let targets = tips(&d.join("target.csv"));
    let mut run = String::from("time_s,x_mm,y_mm,z_mm\n");
    let mut sum = 0.0;
    for (k, (&(t, _), target)) in commands.iter().zip(&targets).enumerate() {
        let x = tip(bench.plant, &motion, t);
        let _ = writeln!(run, "{t:.6},{},{},{}", x[0], x[1], x[2]);
        if k >= from {
            sum += (0..3).map(|o| (x[o] - target[o]).powi(2)).sum::<f64>();
        }
    }
    write(d, "run.csv", &run);
    (sum / (commands.len() - from) as f64).sqrt()
}

/// The run just played as rows of a session (without the header) in phase `phase`: a second
/// at rest, then `commands.csv` and the bench's tips in `run.csv`.
fn run_rows(d: &Path, phase: &str) -> Vec<String> {
    let rest = (0..RATE as usize).map(|k| format!("{:.6},{phase},0,0,0,0,0,0", k as f64 / RATE));
    let commands = csv_rows(&d.join("commands.csv"));
    let played = commands.iter().zip(tips(&d.join("run.csv"))).map(|(c, x)| {
        let t = 1.0 + c["time_s"].parse::<f64>().unwrap();
        let p = [&c["P1_kpa"], &c["P2_kpa"], &c["P3_kpa"]];
        format!(
            "{t:.6},{phase},{},{},{},{:.6},{:.6},{:.6}",
            p[0], p[1], p[2], x[0], x[1], x[2]
        )
    });
    rest.chain(played).collect()
}

/// A history model and a static model of a dynamic session on the pneumatic plant, in `d`
/// (`model.json`, `static.json`): the kernel `handcap model`'s search chooses on it, given to
/// spare the test the search (4020 rows, a basis of 200 centres), and the history the demo's
/// search chooses on such sessions.
pub fn fit_models(d: &Path, plant: &Plant) {
    write(
        d,
        "session.csv",
        &session(plant, &Dynamics::PNEUMATIC, 3, 6, 20.0),
    );
    let columns = [
        "--inputs",
        "P1_kpa,P2_kpa,P3_kpa",
        "--outputs",
        "x_mm,y_mm,z_mm",
    ];
    fit_history_model(d, "session.csv", &[], "model.json");
    // The static model of the same session: its plan is the pointwise inverse of its map.
    let mut fixed = vec!["model", "session.csv"];
    fixed.extend(columns);
    fixed.extend([
        "--search",
        "none",
        "--c",
        "5000",
        "--epsilon",
        "0.005",
        "--sigma",
        "6.7",
    ]);
    handcap_ok(d, &[&fixed[..], &["--out", "static.json"]].concat());
}

/// The history model of `data` (a session as [`session`] writes it) with the kernel and
/// history [`fit_models`] gives, and `more` options, into `out`.
pub fn fit_history_model(d: &Path, data: &str, more: &[&str], out: &str) {
    let mut history = vec!["model", data, "--inputs", "P1_kpa,P2_kpa,P3_kpa"];
    history.extend([
        "--outputs",
        "x_mm,y_mm,z_mm",
        "--time",
        "time_s",
        "--group-by",
        "phase",
    ]);
    history.extend(["--history", "ema:0.0167,0.0667,0.267", "--search", "none"]);
    history.extend(["--c", "156.67", "--epsilon", "0.0301", "--sigma", "1.364"]);
    handcap_ok(d, &[&history[..], more, &["--out", out]].concat());
}

/// Plans the path `target.csv` with `model`, writes `commands.csv`; what handcap said.
fn plan_path(d: &Path, model: &str) -> String {
    handcap_ok(
        d,
        &[
            "inverse",
            model,
            "--trajectory",
            "target.csv",
            "--out",
            "commands.csv",
        ],
    )
}

/// Six repetitions of `handcap inverse --previous --measured` on the bench, from the commands
/// in `commands.csv` (played first): the tracking RMS of each run, against the bench's truth.
/// With `refit`, before each learning step the history model is fitted again with the same
/// settings on the session and every run played so far (each its own phase, after a second at
/// rest: its commands and the bench's tips), the runs' rows weighed so that together they
/// weigh as much as the session's (`--weight`), and the step learns with that model.
fn learn_six_times(d: &Path, bench: &Bench, lead: usize, refit: bool) -> Vec<f64> {
    let session = std::fs::read_to_string(d.join("session.csv")).unwrap();
    let mut runs = Vec::new();
    let mut errors = vec![play(d, bench, lead)];
    for rep in 0..6 {
        let model = if refit {
            runs.extend(run_rows(d, &format!("run{rep}")));
            let weight = (session.lines().count() - 1) as f64 / runs.len() as f64;
            let mut lines = session.lines();
            let mut text = format!("{},weight\n", lines.next().unwrap());
            lines.for_each(|l| text += &format!("{l},1\n"));
            runs.iter().for_each(|l| text += &format!("{l},{weight}\n"));
            write(d, "refit.csv", &text);
            fit_history_model(d, "refit.csv", &["--weight", "weight"], "refit.json");
            "refit.json"
        } else {
            "model.json"
        };
        std::fs::copy(d.join("commands.csv"), d.join("previous.csv")).unwrap();
        let args = ["inverse", model, "--trajectory", "target.csv"];
        let learn = ["--previous", "previous.csv", "--measured", "run.csv"];
        let said = handcap_ok(d, &[&args[..], &learn, &["--out", "commands.csv"]].concat());
        assert!(said.contains("tracking RMS"), "{said}");
        errors.push(play(d, bench, lead));
    }
    errors
}

#[test]
fn the_dynamic_inverse_anticipates_the_lag_and_learning_closes_the_rest() {
    let dir = tempdir();
    let d = dir.path();
    let plant = Plant::new(PlantParams::default());
    fit_models(d, &plant);
    let bench = Bench {
        plant: &plant,
        dynamics: Dynamics::PNEUMATIC,
        play_kpa: 0.0,
    };
    for period in [6.5, 3.5] {
        let (target, lead) = figure_eight(&plant, period);
        write(d, "target.csv", &target);
        // The pointwise inverse of the settled map, played at the same times: late by the lag.
        assert!(plan_path(d, "static.json").contains("pointwise inverse"));
        let pointwise = play(d, &bench, lead);
        assert!(plan_path(d, "model.json").contains("predicted tracking RMS"));
        for figure in ["commands_path.svg", "commands_path.png"] {
            assert!(d.join(figure).exists(), "{figure}");
        }
        let errors = learn_six_times(d, &bench, lead, false);
        assert!(
            errors[0] <= 0.5 * pointwise,
            "figure-eight of {period} s: dynamic feed-forward {:.4} mm RMS, pointwise {pointwise:.4}",
            errors[0]
        );
        let textbook = tuned_textbook_ilc(d, &bench, lead);
        eprintln!("figure-eight of {period} s: pointwise {pointwise:.4}, planned and learning {errors:.4?}, tuned textbook ILC {textbook:.4?}");
        // Each repetition no worse than the one before (to 2 %), 0.1 mm RMS or better after
        // six, and at least as good as a textbook ILC handed the plant's own map, each
        // muscle's lead, a Q-filter and its gain tuned on this plant.
        for w in errors.windows(2) {
            assert!(w[1] <= w[0] * 1.02, "learning went back: {errors:?}");
        }
        let last = *errors.last().unwrap();
        assert!(last <= 0.1, "after 6 repetitions {errors:.4?}");
        assert!(
            last <= textbook[6],
            "after 6 repetitions {errors:.4?}, tuned textbook ILC {textbook:.4?}"
        );
    }
}

/// Issue 61: the learning loop was tested only on the plant its model was fitted on. Here the
/// model of the pneumatic plant (30 ms of delay, lags 0.15, 0.25, 0.4 s, 8 % creeping over 3 s,
/// no play) learns on three fingers whose dynamics it does not know, fitted again before each
/// learning step on its session and the runs played so far, weighed together as much as the
/// session (as `follow --refit` does), each scored against its truth beside the textbook ILC
/// tuned on it:
///
/// | finger | delay | lags (s) | creep | play | 6.5 s: handcap, textbook | 3.5 s: handcap, textbook |
/// |---|---|---|---|---|---|---|
/// | slower | 50 ms | 0.3, 0.12, 0.22 | 12 % over 5 s | 8 kPa | 0.0257, 0.0266 | 0.0458, 0.0552 |
/// | quicker | 40 ms | 0.2, 0.35, 0.1 | 5 % over 2 s | 4 kPa | 0.0155, 0.0250 | 0.0269, 0.0662 |
/// | playful | 20 ms | 0.25, 0.5, 0.3 | 10 % over 4 s | 12 kPa | 0.0672, 0.0685 | 0.1110, 0.2170 |
///
/// (mm RMS after six repetitions). Without the refit the same loop ends at 0.0323, 0.0476;
/// 0.0258, 0.0735; 0.0801, 0.0867 (two of the six below the textbook). Asserted, the issue's
/// bar: every repetition better than the one before, and after six no worse than the textbook
/// ILC tuned on the finger, at both periods on every finger.
#[test]
fn learning_holds_on_a_finger_the_model_does_not_know() {
    let dir = tempdir();
    let d = dir.path();
    let plant = Plant::new(PlantParams::default());
    fit_models(d, &plant);
    let finger = |delay_s, lag_s, (creep_share, creep_s), play_kpa| Bench {
        plant: &plant,
        dynamics: Dynamics {
            delay_s,
            lag_s,
            creep_share,
            creep_s,
        },
        play_kpa,
    };
    for bench in [
        finger(0.05, [0.3, 0.12, 0.22], (0.12, 5.0), 8.0),
        finger(0.04, [0.2, 0.35, 0.1], (0.05, 2.0), 4.0),
        finger(0.02, [0.25, 0.5, 0.3], (0.10, 4.0), 12.0),
    ] {
        for period in [6.5, 3.5] {
            let (target, lead) = figure_eight(&plant, period);
            write(d, "target.csv", &target);
            plan_path(d, "model.json");
            let errors = learn_six_times(d, &bench, lead, true);
            let textbook = tuned_textbook_ilc(d, &bench, lead);
            let said = format!("lags {:?} s, play {} kPa, figure-eight of {period} s: planned and learning {errors:.4?}, tuned textbook ILC {textbook:.4?}", bench.dynamics.lag_s, bench.play_kpa);
            eprintln!("{said}");
            for w in errors.windows(2) {
                assert!(w[1] < w[0], "learning went back: {said}");
            }
            let last = *errors.last().unwrap();
            assert!(last <= textbook[6], "{said}");
        }
    }
}

#[test]
fn bad_trajectories_get_one_line_and_nothing_is_written() {
    let dir = tempdir();
    let d = dir.path();
    write(d, "train.csv", &crate::history::lagging_plant(1, 4, 60));
    crate::history::fit_lagging(d, "ema:0.2", "m.json");
    write(d, "back.csv", "t_s,x_mm,y_mm\n0,1,1\n0.1,1,1\n0.1,1,1\n");
    let err = handcap_err(
        d,
        &[
            "inverse",
            "m.json",
            "--trajectory",
            "back.csv",
            "--out",
            "c.csv",
        ],
    );
    assert!(
        err.contains("back.csv: line 4") && err.contains("does not increase"),
        "{err}"
    );
    write(
        d,
        "path.csv",
        "t_s,x_mm,y_mm\n0,1,1\n0.1,1,1\n0.2,1,1\n0.3,1,1\n",
    );
    handcap_ok(
        d,
        &[
            "inverse",
            "m.json",
            "--trajectory",
            "path.csv",
            "--out",
            "c.csv",
        ],
    );
    // Hostile probe 11 (issue 61): `time_s` was refused for a model whose time column is
    // `t_s`, though the help says either. The commands keep the path's name.
    write(
        d,
        "path_time_s.csv",
        "time_s,x_mm,y_mm\n0,1,1\n0.1,1,1\n0.2,1,1\n0.3,1,1\n",
    );
    let args = ["inverse", "m.json", "--trajectory", "path_time_s.csv"];
    handcap_ok(d, &[&args[..], &["--out", "c_time_s.csv"]].concat());
    assert_eq!(csv_rows(&d.join("c_time_s.csv"))[3]["time_s"], "0.3");
    let learn_from = |measured: &str| {
        let args = [
            "inverse",
            "m.json",
            "--trajectory",
            "path.csv",
            "--previous",
            "c.csv",
        ];
        handcap_err(
            d,
            &[&args[..], &["--measured", measured, "--out", "next.csv"]].concat(),
        )
    };
    write(d, "short.csv", "t_s,x_mm,y_mm\n0,1,1\n0.1,1,1\n");
    let err = learn_from("short.csv");
    assert!(
        err.contains("short.csv") && err.contains("whole run"),
        "{err}"
    );
    write(d, "other.csv", "t_s,x_mm,z_mm\n0,1,1\n0.3,1,1\n");
    let err = learn_from("other.csv");
    assert!(err.contains("no column `y_mm`"), "{err}");
    assert!(!d.join("next.csv").exists());
    // Hostile probe 10 (issue 61): a model that does not describe the run (here: another
    // finger's, 10 m away) was learned from, and its plan reported every row reached.
    let shifted: String = crate::history::lagging_plant(1, 4, 60)
        .lines()
        .enumerate()
        .map(|(k, line)| match k {
            0 => format!("{line}\n"),
            _ => {
                let mut cells: Vec<String> = line.split(',').map(String::from).collect();
                for c in &mut cells[4..] {
                    *c = (c.parse::<f64>().unwrap() + 1e4).to_string();
                }
                cells.join(",") + "\n"
            }
        })
        .collect();
    write(d, "train.csv", &shifted);
    crate::history::fit_lagging(d, "ema:0.2", "other_finger.json");
    write(d, "on_target.csv", "t_s,x_mm,y_mm\n0,1,1\n0.3,1,1\n");
    let args = ["inverse", "other_finger.json", "--trajectory", "path.csv"];
    let learn = ["--previous", "c.csv", "--measured", "on_target.csv"];
    let err = handcap_err(d, &[&args[..], &learn, &["--out", "next.csv"]].concat());
    assert!(
        err.contains("the model predicts the run played") && err.contains("fit the model"),
        "{err}"
    );
    assert!(!d.join("next.csv").exists());
    // A target far out of reach: followed as closely as the box allows, flagged, said.
    write(d, "far.csv", "t_s,x_mm,y_mm\n0,1,1\n0.1,500,500\n0.2,1,1\n");
    let out = crate::common::handcap(
        d,
        &[
            "inverse",
            "m.json",
            "--trajectory",
            "far.csv",
            "--out",
            "far_c.csv",
        ],
    );
    assert!(out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("out of the model's reach"), "{stderr}");
    let rows = csv_rows(&d.join("far_c.csv"));
    assert_eq!(rows[1]["reached"], "0");
}

/// Hostile probe (stop 85): `--interval` was ignored along a path. The commands file now has
/// each row's radius where the model has intervals; a level asked of a model without them, or
/// beyond its held-out rows, is refused before anything is planned; the default level is said
/// in a note when there is none.
#[test]
fn a_planned_path_carries_the_interval_around_each_row() {
    let dir = tempdir();
    let d = dir.path();
    write(d, "train.csv", &crate::history::lagging_plant(1, 4, 60));
    crate::history::fit_lagging(d, "ema:0.2", "plain.json");
    crate::history::fit_lagging_with(d, "ema:0.2", "m.json", &["--intervals"]);
    write(
        d,
        "path.csv",
        "t_s,x_mm,y_mm\n0,1,1\n0.1,1.2,1\n0.2,1.4,1.1\n0.3,1.5,1.2\n",
    );
    fn plan<'a>(model: &'a str, more: &[&'a str]) -> Vec<&'a str> {
        let args = [
            "inverse",
            model,
            "--trajectory",
            "path.csv",
            "--out",
            "c.csv",
        ];
        [&args[..], more].concat()
    }
    let said = handcap_ok(d, &plan("m.json", &[]));
    assert!(said.contains("90 % interval radius"), "{said}");
    let rows = csv_rows(&d.join("c.csv"));
    assert_eq!(rows.len(), 4);
    for r in &rows {
        let radius: f64 = r["interval_radius"].parse().unwrap();
        assert!(radius.is_finite() && radius > 0.0, "{r:?}");
    }
    std::fs::remove_file(d.join("c.csv")).unwrap();
    let err = handcap_err(d, &plan("m.json", &["--interval", "0.999999"]));
    assert!(
        err.contains("--interval 0.999999") && err.contains("99.9999 %"),
        "{err}"
    );
    let err = handcap_err(d, &plan("plain.json", &["--interval", "0.9"]));
    assert!(err.contains("no prediction intervals"), "{err}");
    assert!(!d.join("c.csv").exists());
    // Not asked: planned without the column, and said.
    let out = handcap(d, &plan("plain.json", &[]));
    assert!(out.status.success());
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("note: no interval"), "{stderr}");
    assert!(!csv_rows(&d.join("c.csv"))[0].contains_key("interval_radius"));
}

#[test]
fn synth_plays_a_protocol_file_as_a_dynamic_session() {
    let dir = tempdir();
    let d = dir.path();
    write(
        d,
        "protocol.csv",
        "step,phase,P1_kpa,P2_kpa,P3_kpa,hold_s\n0,rest,0,0,0,1\n1,path,150,0,40,0.25\n2,path,150,90,40,0.25\n3,rest,0,0,0,0.5\n",
    );
    let said = handcap_ok(
        d,
        &[
            "synth",
            "--out",
            "run",
            "--protocol",
            "protocol.csv",
            "--clean",
        ],
    );
    assert!(!said.contains("calib/"), "{said}");
    assert!(!d.join("run/calib").exists(), "no board pairs");
    // The log is the protocol's rows at their times; every frame has its truth.
    let log = csv_rows(&d.join("run/pressures.csv"));
    let times: Vec<&str> = log.iter().map(|r| r["time_s"].as_str()).collect();
    assert_eq!(times, ["0.000000", "1.000000", "1.250000", "1.500000"]);
    assert_eq!(log[2]["P2_kpa"], "90");
    let truth = csv_rows(&d.join("run/truth/per_frame.csv"));
    let frames = csv_rows(&d.join("run/frames/frames.csv"));
    let left = frames.iter().filter(|f| f["camera"] == "left").count();
    assert_eq!(truth.len(), left);
    // The finger moves during the path and lags it: still at the rest origin at 1.0 s.
    let tip_at = |t: f64| {
        let row = truth
            .iter()
            .min_by(|a, b| {
                let da = (a["time_s"].parse::<f64>().unwrap() - t).abs();
                let db = (b["time_s"].parse::<f64>().unwrap() - t).abs();
                da.total_cmp(&db)
            })
            .unwrap();
        row["x_mm"].parse::<f64>().unwrap().abs() + row["y_mm"].parse::<f64>().unwrap().abs()
    };
    assert!(tip_at(0.5) < 1e-9 && tip_at(1.45) > 0.5);
    write(
        d,
        "bad.csv",
        "step,phase,P1_kpa,P2_kpa,P3_kpa,hold_s\n0,rest,0,0,0,-1\n",
    );
    let err = handcap_err(d, &["synth", "--out", "bad", "--protocol", "bad.csv"]);
    assert!(err.contains("bad.csv") && err.contains("line 2"), "{err}");
}

/// Hostile probe 2 (issue 61): a model without history plans each row's pointwise inverse, and
/// `--max-rate` held nothing back (5,000+ kPa/s, rest to ~90 kPa in the first 33 ms). Every
/// change, the first row's from rest included, is now within the limit.
#[test]
fn hostile_slew_limit_holds_without_history() {
    let dir = tempdir();
    let d = dir.path();
    // With the finger at rest among the rows, the box holds 0 kPa: the first command can leave
    // rest as slowly as the limit asks.
    let mut train = crate::history::lagging_plant(1, 4, 60);
    train.push_str("4,0.00,0.0000,0.0000,0.000000,-2.000000\n");
    write(d, "train.csv", &train);
    let mut args = vec!["model", "train.csv"];
    args.extend(crate::history::COLUMNS);
    args.extend(["--search", "none", "--c", "100", "--epsilon", "0.01"]);
    args.extend(["--sigma", "2", "--out", "static.json"]);
    handcap_ok(d, &args);
    // Targets that jump: the training log's outputs, one every 1/30 s.
    let mut path = String::from("time_s,x_mm,y_mm\n");
    for (k, row) in csv_rows(&d.join("train.csv")).iter().take(40).enumerate() {
        let _ = writeln!(
            path,
            "{:.6},{},{}",
            k as f64 / RATE,
            row["x_mm"],
            row["y_mm"]
        );
    }
    write(d, "jumps.csv", &path);
    let args = ["inverse", "static.json", "--trajectory", "jumps.csv"];
    handcap_ok(
        d,
        &[&args[..], &["--max-rate", "100", "--out", "c.csv"]].concat(),
    );
    let rows = csv_rows(&d.join("c.csv"));
    let mut last = [0.0; 2];
    let mut fastest: f64 = 0.0;
    for (k, row) in rows.iter().enumerate() {
        let p = [
            row["P1_kpa"].parse::<f64>().unwrap(),
            row["P2_kpa"].parse().unwrap(),
        ];
        for i in 0..2 {
            fastest = fastest.max((p[i] - last[i]).abs() * RATE);
        }
        last = p;
        assert!(
            k > 0 || p.iter().all(|v| v.abs() <= 100.0 / RATE + 1e-6),
            "{p:?}"
        );
    }
    // The file's pressures are rounded to 0.1 Pa: 0.006 kPa/s at most between two rows.
    assert!(fastest <= 100.01, "fastest change {fastest} kPa/s");
    assert!(
        last.iter().any(|&v| v > 10.0),
        "the commands moved: {last:?}"
    );
}
