//! The learning loop closed by one command (`handcap follow`): the commands along a path
//! planned from the model, then each repetition played through the regulator while both
//! cameras film (a rest hold first: the hand frame's origin), triangulated per frame, scored,
//! and taught back (`inverse --previous --measured`) for the next.
//!
//! # Layout of `follow --out DIR`
//! - `commands_R.csv`: the commands repetition R played (`inverse --trajectory`'s columns),
//!   `commands_N.csv` the ones learned from the last, not played;
//! - `rep_R/`: repetition R's session as `capture` writes it (its protocol: the rest hold, the
//!   path's commands as phase `path`, a second's rest), `rep_R/rows.csv` its per-frame rows;
//! - `measured_R.csv`: the path's rows on the commands' clock (time from the path's first
//!   command), what the learning step reads;
//! - with `--refit`, `refit_R.csv` and `model_R.json`: the rows the model was fitted again on
//!   after repetition R and that model, which the next learning step uses ([`Refit`]);
//! - `follow.csv`: `repetition,rows,tracking_rms_triangulated_mm,tracking_rms_truth_mm`, each
//!   repetition's tracking RMS after the lead-in against the target, from the triangulated
//!   frames and, with `--truth LAB/truth` (`handcap lab`'s), from the lab's tip at each left
//!   exposure: what the finger did, which the loop never sees.

use std::collections::HashMap;
use std::path::{Path, PathBuf};

use super::fit::{self, FitJob};
use super::trajectory::{self, Request};
use super::{Event, PipelineError, Session};
use crate::capture::{CaptureOptions, Regulator};
use crate::model::file::ModelFile;
use crate::session::pressures::{read_pressure_log, PRESSURE_COLUMNS};
use crate::session::protocol::Step;
use crate::triangulate::TriangulateOptions;

/// What `follow` is given.
pub struct Follow<'a> {
    pub model: &'a Path,
    pub target: &'a Path,
    pub calib: &'a Path,
    pub out: &'a Path,
    pub repetitions: usize,
    /// The cameras as `capture` takes them (no protocol: each repetition's is made here).
    pub bench: CaptureOptions,
    pub regulator: Regulator,
    /// The rest hold before each repetition's path (s).
    pub rest_s: f64,
    /// The target's first seconds left out of the tracking RMS (the move from rest to the
    /// path).
    pub lead_in_s: f64,
    /// `handcap lab`'s truth folder, to score each repetition against the finger.
    pub truth: Option<&'a Path>,
    /// The learning step's and the planner's settings, as `inverse --trajectory` takes them.
    pub plan: Request<'a>,
    /// The session the model was fitted on, to fit it again after each repetition on that
    /// session and the repetitions played ([`Refit`]).
    pub refit: Option<&'a Path>,
}

/// One repetition's figures.
#[derive(Clone, Debug)]
pub struct Repetition {
    pub repetition: usize,
    /// The path's rows with a tip.
    pub rows: usize,
    pub triangulated_mm: f64,
    pub truth_mm: Option<f64>,
}

fn request(message: String) -> PipelineError {
    PipelineError::Request(message)
}

fn io(path: &Path) -> impl FnOnce(std::io::Error) -> PipelineError + '_ {
    move |source| PipelineError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// A CSV file's rows by column name.
fn rows(path: &Path) -> Result<Vec<HashMap<String, String>>, PipelineError> {
    let mut reader =
        csv::Reader::from_path(path).map_err(|e| request(format!("{}: {e}", path.display())))?;
    let header = reader
        .headers()
        .map_err(|e| request(format!("{}: {e}", path.display())))?
        .clone();
    reader
        .records()
        .map(|r| {
            let r = r.map_err(|e| request(format!("{}: {e}", path.display())))?;
            Ok(header
                .iter()
                .map(String::from)
                .zip(r.iter().map(String::from))
                .collect())
        })
        .collect()
}

fn number(row: &HashMap<String, String>, key: &str) -> Option<f64> {
    row.get(key)?.parse().ok().filter(|v: &f64| v.is_finite())
}

/// Rows of a path: (time, outputs).
type Timed = Vec<(f64, Vec<f64>)>;

/// The target's time column and outputs, and its rows (time, outputs).
struct Target {
    time: String,
    outputs: Vec<String>,
    rows: Timed,
}

impl Target {
    fn read(path: &Path) -> Result<Target, PipelineError> {
        let reader = csv::Reader::from_path(path);
        let header: Vec<String> = reader
            .and_then(|mut r| r.headers().map(|h| h.iter().map(String::from).collect()))
            .map_err(|e| request(format!("{}: {e}", path.display())))?;
        let (time, outputs) = header
            .split_first()
            .ok_or_else(|| request(format!("{}: no columns", path.display())))?;
        let rows = rows(path)?
            .iter()
            .filter_map(|r| {
                Some((
                    number(r, time)?,
                    outputs
                        .iter()
                        .map(|o| number(r, o))
                        .collect::<Option<Vec<f64>>>()?,
                ))
            })
            .collect();
        Ok(Target {
            time: time.clone(),
            outputs: outputs.to_vec(),
            rows,
        })
    }

    /// The target at `t`, linearly between its rows; `None` outside them.
    fn at(&self, t: f64) -> Option<Vec<f64>> {
        let k = self.rows.partition_point(|r| r.0 <= t);
        let (a, b) = (self.rows.get(k.checked_sub(1)?)?, self.rows.get(k)?);
        let w = (t - a.0) / (b.0 - a.0);
        Some(a.1.iter().zip(&b.1).map(|(x, y)| x + w * (y - x)).collect())
    }

    /// Tracking RMS of `(time, outputs)` after the lead-in, against the target (output units).
    fn rms(&self, seen: &[(f64, Vec<f64>)], lead_in_s: f64) -> f64 {
        let errors: Vec<f64> = seen
            .iter()
            .filter(|(t, _)| *t >= lead_in_s)
            .filter_map(|(t, y)| {
                let want = self.at(*t)?;
                Some(
                    y.iter()
                        .zip(&want)
                        .map(|(a, b)| (a - b).powi(2))
                        .sum::<f64>(),
                )
            })
            .collect();
        (errors.iter().sum::<f64>() / errors.len().max(1) as f64).sqrt()
    }
}

/// The commands file's rows as a protocol: the rest hold, the path (each command held until
/// the next; the last one period), a second's rest.
fn protocol_of(commands: &Path, rest_s: f64) -> Result<Vec<Step>, PipelineError> {
    let rows = rows(commands)?;
    let time = Target::read(commands)?.time;
    let timed: Vec<(f64, [f64; 3])> = rows
        .iter()
        .filter_map(|r| {
            let p = ["P1_kpa", "P2_kpa", "P3_kpa"].map(|k| number(r, k));
            Some((number(r, &time)?, [p[0]?, p[1]?, p[2]?]))
        })
        .collect();
    if timed.len() < 2 {
        return Err(request(format!(
            "{}: fewer than two commands with P1_kpa, P2_kpa, P3_kpa",
            commands.display()
        )));
    }
    let period = timed[1].0 - timed[0].0;
    let step = |k: usize, phase: &str, pressures: [f64; 3], hold_s: f64| Step {
        step: k,
        phase: phase.into(),
        pressures,
        hold_s,
        line: 0,
    };
    let mut steps = vec![step(0, "rest", [0.0; 3], rest_s)];
    for (k, (t, p)) in timed.iter().enumerate() {
        let hold = timed.get(k + 1).map_or(period, |next| next.0 - t);
        steps.push(step(k + 1, "path", *p, hold));
    }
    steps.push(step(timed.len() + 1, "rest", [0.0; 3], 1.0));
    Ok(steps)
}

/// The per-frame rows of the path on the commands' clock: (time from the path's first
/// command, tip), unflagged rows with a tip, from [`AROUND_S`] before the path to as long
/// after it (the rest on either side: the learning step reads the tip over the whole path).
fn path_rows(rep: &Path, outputs: &[String]) -> Result<(f64, Timed), PipelineError> {
    let log = rows(&rep.join("pressures.csv"))?;
    let path: Vec<f64> = log
        .iter()
        .filter(|r| r.get("phase").map(String::as_str) == Some("path"))
        .filter_map(|r| number(r, "time_s"))
        .collect();
    let (Some(&start), Some(&last)) = (path.first(), path.last()) else {
        return Err(request(format!("{}: no path step logged", rep.display())));
    };
    let seen = rows(&rep.join("rows.csv"))?
        .iter()
        .filter(|r| r["flag"].is_empty())
        .filter_map(|r| {
            let t = number(r, "time_s")?;
            let y = outputs
                .iter()
                .map(|o| number(r, o))
                .collect::<Option<Vec<f64>>>()?;
            (t >= start - AROUND_S && t <= last + AROUND_S).then_some((t - start, y))
        })
        .collect();
    Ok((start, seen))
}

/// How far before and after the path its rows are kept (s).
const AROUND_S: f64 = 0.5;

/// The lab's tip at each of this repetition's left frames, on the commands' clock (time from
/// `start`, the path's first command on the session's clock).
fn truth_rows(
    truth: &Path,
    rep: &Path,
    start: f64,
    outputs: &[String],
) -> Result<Timed, PipelineError> {
    let json = |path: &Path| -> Result<serde_json::Value, PipelineError> {
        let text = std::fs::read_to_string(path).map_err(io(path))?;
        serde_json::from_str(&text).map_err(|e| request(format!("{}: {e}", path.display())))
    };
    let lab = json(&truth.join("lab.json"))?;
    let session = json(&rep.join(crate::capture::CAPTURE_FILE))?;
    let (Some(epoch), Some(started)) = (
        lab["epoch_unix_s"].as_f64(),
        session["summary"]["start_unix_s"].as_f64(),
    ) else {
        return Err(request(format!(
            "{}: no epoch_unix_s (is it handcap lab's truth?)",
            truth.display()
        )));
    };
    // The session's clock on the lab's: lab time = session time + offset.
    let offset = started - epoch;
    // This session's client of the left camera: the first to connect once it started.
    let first = rows(&truth.join("clients.csv"))?
        .iter()
        .filter(|c| {
            c["camera"] == "left" && number(c, "connected_s").is_some_and(|t| t >= offset - 0.1)
        })
        .find_map(|c| number(c, "first_frame"))
        .ok_or_else(|| {
            request(format!(
                "{}: no client of the left camera during {}",
                truth.display(),
                rep.display()
            ))
        })? as u64;
    let exposures: HashMap<u64, HashMap<String, String>> = rows(&truth.join("frames.csv"))?
        .into_iter()
        .filter(|r| r["camera"] == "left")
        .filter_map(|r| Some((r["frame"].parse::<u64>().ok()?, r)))
        .collect();
    let axes = ["x_mm", "y_mm", "z_mm"];
    Ok(rows(&rep.join("frames/frames.csv"))?
        .iter()
        .filter(|r| r["camera"] == "left")
        .filter_map(|r| {
            let e = exposures.get(&(first + r["frame"].parse::<u64>().ok()?))?;
            let y = outputs
                .iter()
                .map(|o| axes.contains(&o.as_str()).then(|| number(e, o)).flatten())
                .collect::<Option<Vec<f64>>>()?;
            Some((number(e, "exposure_s")? - offset - start, y))
        })
        .collect())
}

/// Writes `(time, outputs)` rows under the target's header.
fn write_measured(
    path: &Path,
    target: &Target,
    seen: &[(f64, Vec<f64>)],
) -> Result<(), PipelineError> {
    let mut text = format!("{},{}\n", target.time, target.outputs.join(","));
    for (t, y) in seen {
        let y: Vec<String> = y.iter().map(|v| format!("{v:.6}")).collect();
        text += &format!("{t:.6},{}\n", y.join(","));
    }
    crate::fsio::write_bytes(path, text.as_bytes()).map_err(io(path))
}

/// The column of the refit's row weights.
const REFIT_WEIGHT: &str = "refit_weight";

/// `--refit`: the session the model was fitted on, read before the first repetition, to fit
/// the model again after each on it and the repetitions played ([`Refit::after`]).
struct Refit {
    model: ModelFile,
    data: PathBuf,
    header: Vec<String>,
    rows: Vec<csv::StringRecord>,
    /// The session's rows a fit reads (unflagged).
    read: usize,
    /// The repetitions' rows so far, in the session's columns.
    runs: Vec<Vec<String>>,
}

impl Refit {
    /// Reads the session `data`, which must hold every column the model was fitted with.
    fn read(f: &Follow, data: &Path) -> Result<Refit, PipelineError> {
        let model = ModelFile::load(f.model).map_err(|e| request(e.to_string()))?;
        let failed = |e: csv::Error| request(format!("{}: {e}", data.display()));
        let mut reader = csv::Reader::from_path(data).map_err(failed)?;
        let header: Vec<String> = (reader.headers().map_err(failed)?.iter())
            .map(String::from)
            .collect();
        let rows: Vec<csv::StringRecord> =
            reader.records().collect::<Result<_, _>>().map_err(failed)?;
        let flag = header.iter().position(|h| h == "flag");
        let read = rows
            .iter()
            .filter(|row| flag.is_none_or(|i| row.get(i).is_none_or(str::is_empty)))
            .count();
        let refit = Refit {
            model,
            data: data.to_path_buf(),
            header,
            rows,
            read,
            runs: Vec::new(),
        };
        let job = refit.job(f, 0);
        if job.time.is_some() && job.group.is_none() {
            return Err(request(format!(
                "{}: its history runs over one series (no --group-by), and --refit adds each repetition as a run of its own: fit it with --group-by",
                f.model.display()
            )));
        }
        let named = job.time.iter().chain(&job.group);
        let columns = job.inputs.iter().chain(&job.outputs).chain(named);
        if let Some(column) = columns.into_iter().find(|c| !refit.header.contains(c)) {
            return Err(request(format!(
                "{}: no column `{column}`, which {} was fitted with: give --refit the session the model was fitted on",
                data.display(),
                f.model.display()
            )));
        }
        Ok(refit)
    }

    /// The fit after repetition `r`: the model's own settings on `refit_R.csv` into
    /// `model_R.json`.
    fn job(&self, f: &Follow, r: usize) -> FitJob {
        let data = f.out.join(format!("refit_{r}.csv"));
        let out = f.out.join(format!("model_{r}.json"));
        FitJob::refit(&self.model, data, Some(REFIT_WEIGHT.into()), out)
    }

    /// Fits the model again after repetition `r` on `refit_R.csv`: the session's rows, and
    /// every repetition's unflagged rows so far (repetition `r`'s added to the others), each
    /// repetition a group of its own (`rep_K`), the repetitions' rows weighing together as much
    /// as the session's (appended once, the session's rows outweigh a run and the model hardly
    /// learns the finger it is on: `docs/motion.md`). Returns the model file written.
    fn after(
        &mut self,
        f: &Follow,
        r: usize,
        session: &Session,
        said: &dyn Fn(&str),
    ) -> Result<PathBuf, PipelineError> {
        let job = self.job(f, r);
        // Repetition r's rows in the session's columns: the time, its group, the commands in
        // force (as the session's inputs are: a streaming regulator's measured pressures, which
        // the rows carry, lag them) and the tip; the session's other columns left empty.
        let rep = f.out.join(format!("rep_{r}"));
        let log =
            read_pressure_log(&rep.join("pressures.csv")).map_err(|e| request(e.to_string()))?;
        for row in rows(&rep.join("rows.csv"))? {
            let t = number(&row, "time_s").filter(|_| row["flag"].is_empty());
            let Some(step) = t.and_then(|t| log.step_at(t)) else {
                continue;
            };
            let command = |name: &String| {
                let p = PRESSURE_COLUMNS.iter().position(|c| c == name)?;
                Some(log.steps[step].pressures_kpa[p].to_string())
            };
            // The row's own cell, when it holds a number.
            let kept = |key: &str| number(&row, key).map(|_| row[key].clone());
            let cell = |name: &String| match name {
                _ if Some(name) == job.time.as_ref() => kept("time_s"),
                _ if Some(name) == job.group.as_ref() => Some(format!("rep_{r}")),
                _ if job.inputs.contains(name) => command(name),
                _ if job.outputs.contains(name) => kept(name),
                _ => Some(String::new()),
            };
            if let Some(cells) = self.header.iter().map(cell).collect::<Option<Vec<_>>>() {
                self.runs.push(cells);
            }
        }
        let runs = &self.runs;
        let weight = self.read as f64 / runs.len().max(1) as f64;
        let mut writer = csv::Writer::from_writer(Vec::new());
        let mut write = |cells: Vec<&str>| writer.write_record(cells);
        let (header, weight_cell) = (self.header.iter().map(String::as_str), weight.to_string());
        let written = write(header.chain([REFIT_WEIGHT]).collect())
            .and_then(|()| {
                (self.rows.iter()).try_for_each(|row| write(row.iter().chain(["1"]).collect()))
            })
            .and_then(|()| {
                runs.iter().try_for_each(|row| {
                    let cells = row.iter().map(String::as_str);
                    write(cells.chain([weight_cell.as_str()]).collect())
                })
            });
        written.map_err(|e| request(format!("{}: {e}", job.data.display())))?;
        let bytes = writer.into_inner().map_err(|e| request(e.to_string()))?;
        crate::fsio::write_bytes(&job.data, &bytes).map_err(io(&job.data))?;
        // The fit's notes (its basis, its history, no intervals) repeat the model's: the loop
        // says what it refitted on instead.
        let quiet = |event: Event| {
            if !matches!(event, Event::Note(_)) {
                session.emit(event);
            }
        };
        let quiet = Session {
            command: session.command.clone(),
            interrupt: session.interrupt,
            events: &quiet,
        };
        fit::run(&job, &quiet)?;
        said(&format!(
            "refitted on {} rows of {} and {} rows of {} repetitions (each weighing {weight:.3}): {}",
            self.read,
            self.data.display(),
            runs.len(),
            r + 1,
            job.out.display()
        ));
        Ok(job.out)
    }
}

/// Runs the loop (see the module docs); `said` hears a line per stage.
///
/// # Errors
/// A plan or learning step that fails, a repetition whose session ends early (its files
/// kept), files that cannot be read or written.
pub fn run(
    f: &Follow,
    session: &Session,
    said: &dyn Fn(&str),
) -> Result<Vec<Repetition>, PipelineError> {
    if !f.bench.is_pair() {
        return Err(PipelineError::Request(
            "follow films a pair (--left, --right): its repetitions are triangulated by a pair's per-frame tip".into(),
        ));
    }
    std::fs::create_dir_all(f.out).map_err(io(f.out))?;
    let target = Target::read(f.target)?;
    let commands = |r: usize| f.out.join(format!("commands_{r}.csv"));
    trajectory::run(&Request {
        out: &commands(0),
        learn: None,
        ..f.plan
    })?;
    let mut refit = f.refit.map(|data| Refit::read(f, data)).transpose()?;
    let mut done = Vec::new();
    let mut table =
        String::from("repetition,rows,tracking_rms_triangulated_mm,tracking_rms_truth_mm\n");
    for r in 0..f.repetitions {
        if session.interrupted() {
            return Err(PipelineError::Interrupted(format!(
                "interrupted before repetition {r}: the repetitions before it are kept in {}",
                f.out.display()
            )));
        }
        let rep: PathBuf = f.out.join(format!("rep_{r}"));
        let steps = protocol_of(&commands(r), f.rest_s)?;
        let options = CaptureOptions {
            protocol: Some((steps, f.regulator.clone())),
            ..f.bench.clone()
        };
        said(&format!(
            "repetition {r}: playing {} commands",
            options.protocol.as_ref().map_or(0, |p| p.0.len())
        ));
        let summary = super::capture::run(&rep, &options, session, &|_| {})?;
        super::capture::ended(&summary, &rep)?;
        super::triangulate::run_per_frame(
            &rep.join("frames"),
            f.calib,
            &rep.join("pressures.csv"),
            &TriangulateOptions::default(),
            &rep.join("rows.csv"),
            session,
        )?;
        let (start, seen) = path_rows(&rep, &target.outputs)?;
        let measured = f.out.join(format!("measured_{r}.csv"));
        write_measured(&measured, &target, &seen)?;
        let truth_mm = match f.truth {
            Some(truth) => Some(target.rms(
                &truth_rows(truth, &rep, start, &target.outputs)?,
                f.lead_in_s,
            )),
            None => None,
        };
        let one = Repetition {
            repetition: r,
            rows: seen.len(),
            triangulated_mm: target.rms(&seen, f.lead_in_s),
            truth_mm,
        };
        table += &format!(
            "{r},{},{:.5},{}\n",
            one.rows,
            one.triangulated_mm,
            one.truth_mm.map_or(String::new(), |v| format!("{v:.5}"))
        );
        let path = f.out.join("follow.csv");
        crate::fsio::write_bytes(&path, table.as_bytes()).map_err(io(&path))?;
        said(&one.to_string());
        done.push(one);
        let refitted = match &mut refit {
            Some(refit) => Some(refit.after(f, r, session, said)?),
            None => None,
        };
        trajectory::run(&Request {
            model: refitted.as_deref().unwrap_or(f.model),
            out: &commands(r + 1),
            learn: Some((&commands(r), &measured)),
            ..f.plan
        })?;
    }
    Ok(done)
}

impl std::fmt::Display for Repetition {
    fn fmt(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        write!(
            f,
            "repetition {}: tracking RMS after the lead-in {:.4} mm from the triangulated frames ({} rows)",
            self.repetition, self.triangulated_mm, self.rows
        )?;
        if let Some(t) = self.truth_mm {
            write!(f, ", {t:.4} mm against the lab's truth")?;
        }
        Ok(())
    }
}
