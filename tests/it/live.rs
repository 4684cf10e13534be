//! Live sessions against the truth: `handcap capture` films two virtual cameras, HTTP
//! Motion-JPEG servers that watch the virtual micro-hand follow the regulator's commands, and
//! drives the protocol; `handcap triangulate` makes the dataset, checked against the hand's
//! true tips. The cameras misbehave as real ones do: late, at different delays, dropping
//! frames, and sending a backlog at once after a hiccup.

use std::path::Path;
use std::process::Output;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use crate::common::{
    capture_with, csv_rows, handcap, handcap_ok, mjpeg_server, read_json, real_time, session,
    tempdir, tip_errors_against_truth, Part,
};

/// How long the protocol holds each step (s); the virtual hand's frames cover its first 0.3 s
/// (the step of `synth`), and the finger rests after.
const HOLD_S: f64 = 0.4;

/// The regulator's commands as the virtual hand received them: when, and which step.
type Commands = Arc<Mutex<Vec<(Instant, usize)>>>;

/// How one virtual camera misbehaves.
#[derive(Clone, Default)]
struct Faults {
    /// From exposure to sending (s).
    latency_s: f64,
    /// Frames (by number) that wait and go at once with the first after them.
    held: std::ops::Range<usize>,
    /// Every this many frames one is lost (0: none).
    drop_every: usize,
}

/// One camera's frames of each step of the virtual session (`synth` with whole steps filmed):
/// per step, (offset of the exposure into the step (s), JPEG bytes), in exposure order.
fn frames_by_step(dir: &Path, camera: &str, step_s: f64) -> Vec<Vec<(f64, Vec<u8>)>> {
    let mut steps: Vec<Vec<(f64, Vec<u8>)>> = Vec::new();
    for r in csv_rows(&dir.join("truth/frames.csv")) {
        if r["camera"] != camera {
            continue;
        }
        let step: usize = r["step"].parse().unwrap();
        let exposure: f64 = r["exposure_s"].parse().unwrap();
        let frame: usize = r["frame"].parse().unwrap();
        let bytes = std::fs::read(dir.join(format!("frames/{camera}_{frame:05}.jpg"))).unwrap();
        if steps.len() <= step {
            steps.resize(step + 1, Vec::new());
        }
        steps[step].push((exposure - step as f64 * step_s, bytes));
    }
    for s in &mut steps {
        s.sort_by(|a, b| a.0.total_cmp(&b.0));
    }
    steps
}

/// What the camera sees at `at`: the frame of the last commanded step as far into its motion
/// as `at` is; before a step's first frame, the step before's last (still at rest).
fn seen<'a>(
    steps: &'a [Vec<(f64, Vec<u8>)>],
    commands: &[(Instant, usize)],
    at: Instant,
) -> &'a [u8] {
    let last = |k: usize| &steps[k].last().unwrap().1;
    let Some(n) = commands.iter().rposition(|(t, _)| *t <= at) else {
        return last(0);
    };
    let (t, k) = commands[n];
    let into = at.duration_since(t).as_secs_f64();
    match steps[k].iter().rev().find(|(offset, _)| *offset <= into) {
        Some((_, bytes)) => bytes,
        None if n > 0 => last(commands[n - 1].1),
        None => last(0),
    }
}

/// A virtual camera ([`mjpeg_server`]): exposures every 1/30 s from when the client connects
/// (plus `phase_s`), each showing what [`seen`] says, sent as the `faults` say. Returns the
/// stream's URL.
fn virtual_camera(
    steps: Vec<Vec<(f64, Vec<u8>)>>,
    commands: Commands,
    light: Light,
    phase_s: f64,
    faults: Faults,
) -> String {
    let mut start = None;
    // The last frame shown with the light on, and as it was: the hand rests while it is on,
    // so the resting frame is lit ahead (lighting one takes a frame period or more).
    let rest = steps[0].last().unwrap().1.clone();
    let mut lit_memo = Some((rest.clone(), with_light(&rest)));
    mjpeg_server(move |n| {
        let start = *start.get_or_insert_with(Instant::now);
        let tick = |n: usize| start + Duration::from_secs_f64(phase_s + n as f64 / 30.0);
        let sent_with = if faults.held.contains(&n) {
            faults.held.end
        } else {
            n
        };
        let due = tick(sent_with) + Duration::from_secs_f64(faults.latency_s);
        std::thread::sleep(due.saturating_duration_since(Instant::now()));
        if faults.drop_every > 0 && n % faults.drop_every == faults.drop_every - 1 {
            return Part::Skip;
        }
        let frame = seen(&steps, &commands.lock().unwrap(), tick(n)).to_vec();
        let lit = light
            .lock()
            .unwrap()
            .is_some_and(|on| tick(n) >= on && tick(n) < on + Duration::from_secs_f64(LIT_S));
        if !lit {
            return Part::Frame(frame);
        }
        if lit_memo.as_ref().is_none_or(|(dark, _)| *dark != frame) {
            lit_memo = Some((frame.clone(), with_light(&frame)));
        }
        Part::Frame(lit_memo.as_ref().unwrap().1.clone())
    })
}

/// When the flash's light came on, once it has.
type Light = Arc<Mutex<Option<Instant>>>;

/// How long the virtual light stays on (s).
const LIT_S: f64 = 0.6;

/// `jpeg` with the light on: a white 40 × 40 pixel LED near its top-left corner.
fn with_light(jpeg: &[u8]) -> Vec<u8> {
    let mut image = image::load_from_memory(jpeg).unwrap().to_rgb8();
    for y in 60..100 {
        for x in 60..100 {
            image.put_pixel(x, y, image::Rgb([255, 255, 255]));
        }
    }
    let mut out = Vec::new();
    image::codecs::jpeg::JpegEncoder::new_with_quality(&mut out, 90)
        .encode_image(&image)
        .unwrap();
    out
}

/// Watches for `flag` (the flash script's file) and records when it appeared in `light`, until
/// `done`.
fn light_watch(flag: std::path::PathBuf, light: Light, done: Arc<Mutex<bool>>) {
    std::thread::spawn(move || {
        while !*done.lock().unwrap() && !flag.exists() {
            std::thread::sleep(Duration::from_millis(1));
        }
        if flag.exists() {
            *light.lock().unwrap() = Some(Instant::now());
        }
    });
}

/// Watches `told` (the regulator script's log, one line per command ending in the step) and
/// records each command as it lands, until the session's files say it ended.
fn regulator_watch(told: std::path::PathBuf, commands: Commands, done: Arc<Mutex<bool>>) {
    std::thread::spawn(move || {
        let mut seen = 0;
        while !*done.lock().unwrap() {
            let text = std::fs::read_to_string(&told).unwrap_or_default();
            // The lines written whole: up to the last newline.
            let whole: Vec<&str> = text
                .rfind('\n')
                .map_or(Vec::new(), |end| text[..end].lines().collect());
            for line in whole.iter().skip(seen) {
                let step = line.split_whitespace().last().unwrap().parse().unwrap();
                commands.lock().unwrap().push((Instant::now(), step));
            }
            seen = seen.max(whole.len());
            std::thread::sleep(Duration::from_millis(1));
        }
    });
}

/// The virtual session of `seed` filmed whole (every frame of each step) in `dir/hand`, served
/// live by two virtual cameras with `faults`, captured into `dir/live` driving the same
/// protocol; with `term_after_steps`, the capture gets SIGTERM once the regulator has been told
/// that many steps (a minute at most: then the capture is killed and the test fails); with
/// `flash`, capture switches on a light both cameras see before the protocol (`--flash`).
fn live_session(
    dir: &Path,
    faults: [Faults; 2],
    term_after_steps: Option<usize>,
    flash: bool,
) -> Output {
    let config = handcap::synth::capture::CaptureConfig {
        views: 3,
        window_s: [0.0, 0.3],
        ..handcap::synth::capture::CaptureConfig::default()
    };
    capture_with(&dir.join("hand"), &session(9, [125.0, 62.5]), &config);
    handcap_ok(
        dir,
        &[
            "protocol",
            "--out",
            "protocol.csv",
            "--grid-step-kpa",
            "125",
            "--sweep-step-kpa",
            "62.5",
            "--hold-s",
            &HOLD_S.to_string(),
        ],
    );
    let script = dir.join("regulator.sh");
    std::fs::write(
        &script,
        "#!/bin/sh\necho \"$@\" >> \"$(dirname \"$0\")/told.txt\"\n",
    )
    .unwrap();
    let commands: Commands = Arc::default();
    let done = Arc::new(Mutex::new(false));
    regulator_watch(dir.join("told.txt"), commands.clone(), done.clone());
    let light: Light = Arc::default();
    light_watch(dir.join("flash.txt"), light.clone(), done.clone());
    let [left, right] = faults;
    let urls = [("left", 0.0, left), ("right", 0.011, right)].map(|(camera, phase, f)| {
        virtual_camera(
            frames_by_step(&dir.join("hand"), camera, config.step_s),
            commands.clone(),
            light.clone(),
            phase,
            f,
        )
    });
    let command = format!("sh {} {{p1}} {{p2}} {{p3}} {{step}}", script.display());
    let mut args = vec![
        "capture",
        "--left",
        &urls[0],
        "--right",
        &urls[1],
        "--out",
        "live",
        "--protocol",
        "protocol.csv",
        "--set-pressure",
        &command,
        // The virtual cameras are threads of this test, which a busy machine may pause for
        // seconds (a backlog's held frames then come later still): a stall is not what these
        // sessions test (`a_silent_or_stalled_stream_ends_the_session` does, at the default).
        "--stall-s",
        "10",
    ];
    let switch_on = format!("touch {}", dir.join("flash.txt").display());
    if flash {
        args.extend(["--flash", &switch_on]);
    }
    let child = std::process::Command::new(env!("CARGO_BIN_EXE_handcap"))
        .args(args)
        .current_dir(dir)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    if let Some(steps) = term_after_steps {
        let deadline = Instant::now() + Duration::from_secs(60);
        while commands.lock().unwrap().len() < steps && Instant::now() < deadline {
            std::thread::sleep(Duration::from_millis(5));
        }
        let told = commands.lock().unwrap().len();
        // SAFETY: sending a signal to our own child process.
        unsafe {
            libc::kill(
                child.id() as i32,
                if told < steps {
                    libc::SIGKILL
                } else {
                    libc::SIGTERM
                },
            );
        }
        assert!(
            told >= steps,
            "the regulator was told {told} of {steps} steps in a minute"
        );
    }
    let out = child.wait_with_output().unwrap();
    *done.lock().unwrap() = true;
    println!("{}", String::from_utf8_lossy(&out.stdout));
    out
}

/// `handcap triangulate` of the live session into `dir/live/<name>/dataset.csv`, with the truth's
/// rig and `extra` arguments; its output printed.
fn triangulate(dir: &Path, name: &str, extra: &[&str]) -> Output {
    let out = format!("live/{name}/dataset.csv");
    let mut args = vec![
        "triangulate",
        "live/frames",
        "--calib",
        "hand/truth/rig.yml",
        "--out",
        &out,
    ];
    args.extend(extra);
    let done = handcap(dir, &args);
    println!("{}", String::from_utf8_lossy(&done.stdout));
    done
}

/// [`triangulate`] with no more arguments, which must succeed.
fn triangulated(dir: &Path) {
    let done = triangulate(dir, "out", &[]);
    assert!(
        done.status.success(),
        "{}",
        String::from_utf8_lossy(&done.stderr)
    );
}

/// The rows of `dir/live/<name>/dataset.csv` against the truth: (rows, each unflagged row's
/// error in mm, sorted), printed.
fn against_truth(dir: &Path, name: &str) -> (usize, Vec<f64>) {
    let (dataset, truth) = (
        dir.join(format!("live/{name}/dataset.csv")),
        dir.join("hand/truth/tips.csv"),
    );
    let rows = csv_rows(&dataset).len();
    let mut errors: Vec<f64> = tip_errors_against_truth(&dataset, &truth, |r| r["flag"].is_empty())
        .into_iter()
        .map(|e| e.1)
        .collect();
    errors.sort_by(f64::total_cmp);
    println!(
        "{name}: {rows} rows ({} unflagged) of {} steps; unflagged tip error median {:.3} mm, largest {:.3} mm, {} beyond 0.5 mm",
        errors.len(),
        csv_rows(&truth).len(),
        errors.get(errors.len() / 2).unwrap_or(&f64::NAN),
        errors.last().unwrap_or(&f64::NAN),
        errors.iter().filter(|e| **e > 0.5).count()
    );
    (rows, errors)
}

fn summary(dir: &Path, name: &str) -> serde_json::Value {
    let path = dir.join(format!("live/{name}/dataset_summary.json"));
    read_json(&path)["summary"].clone()
}

/// The cameras of a real lab: the left 40 ms late, the right 190 ms; the left's server falls
/// behind for 400 ms once and sends what it held at once; the right loses one frame in 25.
/// Captured live, the dataset has a row for nearly every step, none unflagged more than 0.5 mm
/// from the truth; the delays are measured, the backlog found and left out. Taken as stamped,
/// fewer rows hold.
#[test]
fn a_live_session_with_late_cameras_a_backlog_and_drops_matches_the_truth() {
    let _cores = real_time();
    let dir = tempdir();
    let d = dir.path();
    let faults = [
        Faults {
            latency_s: 0.040,
            held: 150..162,
            ..Faults::default()
        },
        Faults {
            latency_s: 0.190,
            drop_every: 25,
            ..Faults::default()
        },
    ];
    let out = live_session(d, faults, None, false);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let json: serde_json::Value = read_json(&d.join("live/capture.json"));
    let stats = &json["summary"]["stats"];
    assert!(stats["late"][0].as_u64().unwrap() >= 10, "{stats}");
    triangulated(d);
    let s = summary(d, "out");
    assert_eq!(s["latency"]["corrected"], true, "{}", s["latency"]);
    let ms = |cam: usize| s["latency"]["cameras"][cam]["delay_ms"].as_f64().unwrap();
    // Each delay is the camera's, plus the tip's 14 ms to half-way, the regulator script's
    // few ms, and a frame period's quantisation of the virtual camera's frames (and of the
    // cut): the right's 150 ms more within two periods.
    assert!((ms(1) - ms(0) - 150.0).abs() < 67.0, "{}", s["latency"]);
    assert!(
        s["frames"]["stamped_late"][0].as_u64().unwrap() >= 10,
        "{}",
        s["frames"]
    );
    let (rows, errors) = against_truth(d, "out");
    assert!(
        rows + 3 >= 37 && errors.len() + 5 >= 37,
        "{rows} rows, {} unflagged",
        errors.len()
    );
    assert!(errors.last().unwrap() < &0.5, "{errors:?}");
    // The same frames as stamped pair moments 150 ms apart.
    // Issue 61: this accepted either outcome (refused, or fewer rows). Taken as stamped the
    // session is triangulated all the same, and fewer of its rows hold.
    let stamped = triangulate(d, "stamped", &["--latency-ms", "0"]);
    assert!(
        stamped.status.success(),
        "{}",
        String::from_utf8_lossy(&stamped.stderr)
    );
    let (_, kept) = against_truth(d, "stamped");
    assert!(
        kept.len() < errors.len(),
        "{} unflagged as stamped",
        kept.len()
    );
}

/// The right camera 300 ms late (more than half a step), its latency and the left's measured
/// from a flash before the protocol (`capture --flash`; triangulate takes them from
/// capture.json), and the session ended by SIGTERM half-way: the files kept give a row for each
/// step filmed, each within 0.5 mm of the truth.
#[test]
fn a_live_session_ended_by_sigterm_with_a_camera_300_ms_late_seen_by_a_flash_matches_the_truth() {
    let _cores = real_time();
    let dir = tempdir();
    let d = dir.path();
    let faults = [
        Faults {
            latency_s: 0.030,
            ..Faults::default()
        },
        Faults {
            latency_s: 0.300,
            ..Faults::default()
        },
    ];
    // Half-way through the protocol's 37 steps.
    let out = live_session(d, faults, Some(18), true);
    assert_eq!(
        out.status.code(),
        Some(130),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let logged = csv_rows(&d.join("live/pressures.csv")).len();
    assert!((18..37).contains(&logged), "{logged} steps logged");
    // Each camera's latency from the flash: the light shows in a frame exposed within a
    // period after it came on, and is placed half-way between that frame and the one before.
    let flash = &read_json(&d.join("live/capture.json"))["summary"]["flash"];
    for (cam, truth_ms) in [(0, 30.0), (1, 300.0)] {
        let ms = flash["latency_ms"][cam].as_f64().unwrap();
        assert!((ms - truth_ms).abs() < 25.0, "{flash}");
    }
    triangulated(d);
    let s = summary(d, "out");
    assert_eq!(s["latency"]["corrected"], true, "{}", s["latency"]);
    assert_eq!(s["latency"]["given"], true, "{}", s["latency"]);
    assert!(
        s["latency"]["from"].as_str().unwrap().contains("flash"),
        "{}",
        s["latency"]
    );
    let (rows, errors) = against_truth(d, "out");
    assert!(
        rows + 3 >= logged && errors.len() + 4 >= logged,
        "{rows} rows of {logged} steps"
    );
    assert!(errors.last().unwrap() < &0.5, "{errors:?}");
}
