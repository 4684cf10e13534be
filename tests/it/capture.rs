//! `handcap capture` with two video files standing in for the cameras, and `handcap protocol`.

use std::collections::HashSet;
use std::path::{Path, PathBuf};

use crate::common::{
    board_videos, capture_with, csv_rows, handcap, handcap_err, handcap_ok, mjpeg_server,
    read_json, real_time, session, tempdir, Part,
};

/// Two Motion-JPEG videos of a small synthetic session (`synth --video`, `views` board pairs
/// beside them): 14 steps of 3 frames per camera (42 frames, 1.4 s at 30 fps), in
/// `dir/cams/frames/`.
fn cameras(dir: &Path, views: usize) {
    let synth = session(5, [250.0, 125.0]);
    let config = handcap::synth::capture::CaptureConfig {
        views,
        video: true,
        realism: handcap::synth::capture::Realism::CLEAN,
        ..handcap::synth::capture::CaptureConfig::default()
    };
    capture_with(&dir.join("cams"), &synth, &config);
}

/// Two Motion-JPEG videos of 126 frames (4.2 s at 30 fps): the session of [`cameras`] filmed
/// whole, every frame of its 14 steps.
fn long_cameras(dir: &Path) {
    let synth = session(5, [250.0, 125.0]);
    let config = handcap::synth::capture::CaptureConfig {
        views: 3,
        window_s: [0.0, 0.3],
        video: true,
        realism: handcap::synth::capture::Realism::CLEAN,
        ..handcap::synth::capture::CaptureConfig::default()
    };
    capture_with(&dir.join("cams"), &synth, &config);
}

/// `handcap protocol` into `out`: 12 steps (a 250 kPa grid and sweeps), each held `hold_s`;
/// returns its output.
fn protocol(d: &Path, out: &str, hold_s: &str) -> String {
    let args = [
        "protocol",
        "--out",
        out,
        "--grid-step-kpa",
        "250",
        "--sweep-step-kpa",
        "250",
        "--hold-s",
        hold_s,
    ];
    handcap_ok(d, &args)
}

/// `capture` from the two videos into `out`, driving `protocol` through `command`.
fn session_args<'a>(out: &'a str, protocol: &'a str, command: &'a str) -> [&'a str; 11] {
    [
        "capture",
        "--left",
        "cams/frames/left.avi",
        "--right",
        "cams/frames/right.avi",
        "--out",
        out,
        "--protocol",
        protocol,
        "--set-pressure",
        command,
    ]
}

/// A `--set-pressure` script that records what it was told, one line per call, and returns
/// `ack_s` later, as a regulator acknowledges.
fn recorder(dir: &Path, ack_s: f64) -> String {
    let script = dir.join("regulator.sh");
    std::fs::write(
        &script,
        format!("#!/bin/sh\necho \"$@\" >> \"$(dirname \"$0\")/told.txt\"\nsleep {ack_s}\n"),
    )
    .unwrap();
    format!("sh {} {{p1}} {{p2}} {{p3}} {{step}}", script.display())
}

/// Every frame listed is there, every image is listed, times rise with the frame number; the
/// frames of the left and right cameras.
fn assert_consistent(session: &Path) -> [usize; 2] {
    let count = assert_consistent_for(session, &["left", "right"]);
    [count[0], count[1]]
}

/// As [`assert_consistent`], the frames of each camera of `names`.
fn assert_consistent_for(session: &Path, names: &[&str]) -> Vec<usize> {
    let rows = csv_rows(&session.join("frames/frames.csv"));
    let mut listed = HashSet::new();
    let mut count = vec![0; names.len()];
    for (k, camera) in names.iter().enumerate() {
        let mine: Vec<_> = rows.iter().filter(|r| &r["camera"] == camera).collect();
        count[k] = mine.len();
        for (i, r) in mine.iter().enumerate() {
            assert_eq!(
                r["frame"].parse::<usize>().unwrap(),
                i,
                "{camera} frames numbered in order"
            );
            let name = format!("{camera}_{:05}.jpg", i);
            assert!(
                session.join("frames").join(&name).is_file(),
                "{name} listed, missing"
            );
            listed.insert(name);
        }
        let times: Vec<f64> = mine.iter().map(|r| r["time_s"].parse().unwrap()).collect();
        assert!(
            times.windows(2).all(|w| w[1] > w[0]),
            "{camera} times not rising"
        );
    }
    for entry in std::fs::read_dir(session.join("frames")).unwrap() {
        let name = entry.unwrap().file_name().to_string_lossy().to_string();
        assert!(
            name == "frames.csv" || listed.contains(&name),
            "{name} written, not listed"
        );
    }
    count
}

#[test]
fn capture_films_both_cameras_and_drives_the_protocol_on_one_clock() {
    let _cores = real_time();
    let dir = tempdir();
    let d = dir.path();
    // 4.2 s of video: the protocol (12 × 0.15 s) ends first even on a busy machine, and each
    // command (a shell started per step) returns well within its hold.
    long_cameras(d);
    let out = protocol(d, "p.csv", "0.15");
    assert!(out.contains("12 steps"), "{out}");
    let command = recorder(d, 0.0);
    let mut args = session_args("s", "p.csv", &command).to_vec();
    args.extend(["--on-abort", "touch vented.txt"]);
    let out = handcap_ok(d, &args);
    assert!(
        !d.join("vented.txt").exists(),
        "--on-abort runs only when the protocol does not finish"
    );
    assert!(out.contains("step 12/12"), "{out}");
    // The cameras' JPEG quality, said at the end, as the frames' tables give it.
    assert!(
        out.contains("colour: JPEG, left 4:2:0 at quality 85, right 4:2:0 at quality 85"),
        "{out}"
    );
    let s = d.join("s");
    let [l, r] = assert_consistent(&s);
    assert!(l >= 10 && r >= 10, "{l} left, {r} right frames");
    // The frames are the videos' JPEGs, not re-encoded.
    let first = std::fs::read(s.join("frames/left_00000.jpg")).unwrap();
    let video = std::fs::read(d.join("cams/frames/left.avi")).unwrap();
    assert!(video.windows(first.len()).any(|w| w == first.as_slice()));
    // The command ran once per step, with the protocol's pressures, in order, logged with
    // rising times on the frames' clock.
    let protocol = csv_rows(&d.join("p.csv"));
    let told = std::fs::read_to_string(d.join("told.txt")).unwrap();
    let log = csv_rows(&s.join("pressures.csv"));
    assert_eq!(told.lines().count(), 12);
    assert_eq!(log.len(), 12);
    for ((p, t), l) in protocol.iter().zip(told.lines()).zip(&log) {
        let want = format!(
            "{} {} {} {}",
            p["P1_kpa"], p["P2_kpa"], p["P3_kpa"], p["step"]
        );
        assert_eq!(t, want);
        for k in ["P1_kpa", "P2_kpa", "P3_kpa", "step", "phase"] {
            assert_eq!(l[k], p[k], "{k}");
        }
    }
    let times: Vec<f64> = log.iter().map(|r| r["time_s"].parse().unwrap()).collect();
    assert!(times.windows(2).all(|w| w[1] - w[0] >= 0.145), "{times:?}");
    // Each command's end is logged: after its start, before the next command.
    let ends: Vec<f64> = log
        .iter()
        .map(|r| r["command_end_s"].parse().unwrap())
        .collect();
    for (k, end) in ends.iter().enumerate() {
        assert!(*end >= times[k], "{ends:?}");
        assert!(times.get(k + 1).is_none_or(|next| end <= next), "{ends:?}");
    }
    let json: serde_json::Value = read_json(&s.join("capture.json"));
    assert_eq!(json["summary"]["ending"], "protocol_done");
    assert!(json["summary"]["start_monotonic_s"].as_f64().unwrap() > 0.0);
    // The session is kept: a second capture into it is refused.
    let msg = handcap_err(d, &args);
    assert!(msg.contains("already holds a capture"), "{msg}");
}

/// `--camera NAME=SOURCE` for each of three cameras: every camera filmed on the one clock,
/// its frames named and listed by its name, as `triangulate` reads more cameras' sessions.
#[test]
fn capture_films_more_cameras_named_on_one_clock() {
    let _cores = real_time();
    let dir = tempdir();
    let d = dir.path();
    long_cameras(d);
    std::fs::copy(
        d.join("cams/frames/left.avi"),
        d.join("cams/frames/third.avi"),
    )
    .unwrap();
    protocol(d, "p.csv", "0.15");
    let command = recorder(d, 0.0);
    let cameras = [
        "--camera",
        "cam1=cams/frames/left.avi",
        "--camera",
        "cam2=cams/frames/right.avi",
        "--camera",
        "cam3=cams/frames/third.avi",
    ];
    let rest = [
        "--out",
        "s",
        "--protocol",
        "p.csv",
        "--set-pressure",
        &command,
    ];
    let out = handcap_ok(d, &[&["capture"][..], &cameras, &rest].concat());
    assert!(out.contains("step 12/12"), "{out}");
    let s = d.join("s");
    let count = assert_consistent_for(&s, &["cam1", "cam2", "cam3"]);
    assert!(count.iter().all(|&n| n >= 30), "{count:?}: {out}");
    assert!(
        out.contains(&format!(
            "({} cam1, {} cam2, {} cam3 frames)",
            count[0], count[1], count[2]
        )),
        "{out}"
    );
    let json = read_json(&s.join("capture.json"));
    assert_eq!(json["cameras"], serde_json::json!(["cam1", "cam2", "cam3"]));
    assert_eq!(json["summary"]["stats"]["frames"], serde_json::json!(count));
    // One clock: the three videos start together, their first frames within a frame.
    let rows = csv_rows(&s.join("frames/frames.csv"));
    let first: Vec<f64> = ["cam1", "cam2", "cam3"]
        .iter()
        .map(|c| {
            let r = rows.iter().find(|r| &r["camera"] == c).unwrap();
            r["time_s"].parse().unwrap()
        })
        .collect();
    let spread = first.iter().copied().fold(f64::MIN, f64::max)
        - first.iter().copied().fold(f64::MAX, f64::min);
    assert!(spread < 1.0 / 30.0, "{first:?}");
    assert_eq!(crate::common::csv_rows(&s.join("pressures.csv")).len(), 12);
    // Bad cameras: one line each, nothing filmed.
    for (args, said) in [
        (vec!["--camera", "cam1=a.avi"], "--camera names one camera"),
        (
            vec!["--camera", "Cam1=a.avi", "--camera", "cam2=b.avi"],
            "--camera Cam1=a.avi: give NAME=SOURCE",
        ),
        (
            vec!["--camera", "cam1=a.avi", "--camera", "cam1=b.avi"],
            "--camera cam1 is named twice",
        ),
        (
            vec![
                "--camera",
                "cam1=a.avi",
                "--camera",
                "cam2=b.avi",
                "--left",
                "c.avi",
            ],
            "leave out --left and --right",
        ),
        (
            vec!["--left", "a.avi"],
            "give --left and --right (a pair), or --camera",
        ),
        (
            [&cameras[..2], &cameras[2..4], &["--flash", "true"]].concat(),
            "--flash is built for a pair",
        ),
        // Refused before the page's server starts.
        (
            [&cameras[..2], &cameras[2..4], &["--view"]].concat(),
            "cannot be used with '--view'",
        ),
    ] {
        let err =
            crate::common::handcap_usage(d, &[&["capture"][..], &args, &["--out", "x"]].concat());
        assert!(err.contains(said), "{args:?}: {err}");
        assert!(!d.join("x/frames").exists());
    }
}

#[test]
fn capture_refuses_bad_protocols_and_cameras_and_keeps_what_a_stopped_camera_gave() {
    let _cores = real_time();
    let dir = tempdir();
    let d = dir.path();
    cameras(d, 3);
    let command = recorder(d, 0.0);
    let run = |out: &str, protocol: &str| handcap(d, &session_args(out, protocol, &command));
    std::fs::write(
        d.join("high.csv"),
        "step,phase,P1_kpa,P2_kpa,P3_kpa,hold_s\n0,train,0,0,0,0.1\n1,train,100,320,0,0.1\n",
    )
    .unwrap();
    let out = run("high", "high.csv");
    assert_eq!(out.status.code(), Some(1));
    let msg = String::from_utf8_lossy(&out.stderr);
    assert!(
        msg.contains("high.csv line 3: P2_kpa 320 is outside 0-300 kPa")
            && msg.lines().count() == 1,
        "{msg}"
    );
    assert!(!d.join("high").exists() && !d.join("told.txt").exists());

    // A camera that does not open: named, and the devices listed.
    let msg = handcap_err(
        d,
        &[
            "capture",
            "--left",
            "cams/frames/left.avi",
            "--right",
            "nowhere.avi",
            "--out",
            "x",
            "--duration-s",
            "1",
        ],
    );
    assert!(
        msg.contains("cannot open the right camera \"nowhere.avi\"")
            && msg.contains("give a device index"),
        "{msg}"
    );
    assert!(!d.join("x").exists());
    // A stream that does not open: its password never said, the stream to check.
    let out = handcap(
        d,
        &[
            "capture",
            "--left",
            "cams/frames/left.avi",
            "--right",
            "http://lab:s3cret@127.0.0.1:9/stream.mjpg",
            "--out",
            "x",
            "--duration-s",
            "1",
        ],
    );
    let msg = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{msg}");
    assert!(
        msg.contains("http://lab:***@127.0.0.1:9/stream.mjpg") && !msg.contains("s3cret"),
        "{msg}"
    );
    assert!(!d.join("x").exists());
    // A flash command that fails ends the session before the protocol, said, the frames kept.
    std::fs::write(
        d.join("two.csv"),
        "step,phase,P1_kpa,P2_kpa,P3_kpa,hold_s\n0,train,0,0,0,0.1\n1,train,100,0,0,0.1\n",
    )
    .unwrap();
    let out = handcap(
        d,
        &[
            &session_args("dark", "two.csv", &command)[..],
            &["--flash", "echo no light >&2; exit 3"],
        ]
        .concat(),
    );
    let msg = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{msg}");
    assert!(
        msg.contains("the flash command failed")
            && msg.contains("no light")
            && msg.lines().count() == 1,
        "{msg}"
    );
    let json = read_json(&d.join("dark/capture.json"));
    assert!(
        json["summary"]["ending"]["flash_failed"].is_object(),
        "{json}"
    );
    assert_eq!(json["summary"]["stats"]["steps_done"], 0, "{json}");
    // The same source twice, or a duration that is not one: usage errors.
    for (right, duration) in [
        ("cams/frames/left.avi", "1"),
        ("cams/frames/right.avi", "0"),
    ] {
        let out = handcap(
            d,
            &[
                "capture",
                "--left",
                "cams/frames/left.avi",
                "--right",
                right,
                "--out",
                "x",
                "--duration-s",
                duration,
            ],
        );
        assert_eq!(out.status.code(), Some(2), "{right} {duration}");
    }
    // A hold of 1e300 s is refused where written and where read.
    assert_eq!(
        handcap(d, &["protocol", "--out", "long.csv", "--hold-s", "1e300"])
            .status
            .code(),
        Some(2)
    );
    std::fs::write(
        d.join("long.csv"),
        "step,phase,P1_kpa,P2_kpa,P3_kpa,hold_s\n0,train,0,0,0,1e300\n",
    )
    .unwrap();
    let out = run("long", "long.csv");
    let msg = String::from_utf8_lossy(&out.stderr);
    assert!(
        msg.contains("long.csv line 2: hold_s 1e300 must be more than 0 and at most 3600"),
        "{msg}"
    );
    assert!(!d.join("long").exists());

    // The videos end (1.4 s) long before the protocol (12 × 0.5 s): said, and kept.
    protocol(d, "slow.csv", "0.5");
    let out = run("stopped", "slow.csv");
    assert_eq!(out.status.code(), Some(1));
    let msg = String::from_utf8_lossy(&out.stderr);
    assert!(
        msg.contains("camera stopped delivering at 1.") && msg.contains("kept and listed"),
        "{msg}"
    );
    let s = d.join("stopped");
    assert_eq!(assert_consistent(&s), [42, 42]);
    let steps = csv_rows(&s.join("pressures.csv")).len();
    assert!((2..12).contains(&steps), "{steps} steps logged");
}

/// Ctrl-C, SIGTERM and SIGHUP (a closed terminal, `timeout`, a stopped service) each end a
/// session as an interruption: exit 130, every frame kept and listed, the steps commanded so far
/// logged, a command the signal finds running included once it returns. A session killed
/// outright still has its files as of the last second, said to be still filming.
#[test]
fn signals_end_a_capture_with_every_frame_kept_and_listed() {
    let _cores = real_time();
    let dir = tempdir();
    let d = dir.path();
    // 126 frames (4.2 s): a signal sent a second in, late on a busy machine, still ends the
    // session before the videos do.
    long_cameras(d);
    protocol(d, "p.csv", "1");
    let command = recorder(d, 0.2);
    let spawn = |out: &str| {
        std::process::Command::new(env!("CARGO_BIN_EXE_handcap"))
            .args(session_args(out, "p.csv", &command))
            .current_dir(d)
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap()
    };
    let send = |child: &std::process::Child, signal: i32| {
        // SAFETY: sending a signal to our own child process.
        unsafe {
            libc::kill(child.id() as i32, signal);
        }
    };
    for (signal, name) in [
        (libc::SIGINT, "int"),
        (libc::SIGTERM, "term"),
        (libc::SIGHUP, "hup"),
    ] {
        let _ = std::fs::remove_file(d.join("told.txt"));
        let child = spawn(name);
        wait_until_listed(&d.join(name));
        if signal == libc::SIGHUP {
            // Mid-command: the regulator was told step 1 and has not yet returned.
            wait_until_told(d, 2);
        }
        send(&child, signal);
        let out = child.wait_with_output().unwrap();
        assert_eq!(
            out.status.code(),
            Some(130),
            "{name}: {}",
            String::from_utf8_lossy(&out.stderr)
        );
        let s = d.join(name);
        let [l, r] = assert_consistent(&s);
        assert!(
            (10..126).contains(&l) && (10..126).contains(&r),
            "{name}: {l} left, {r} right frames"
        );
        let json: serde_json::Value = read_json(&s.join("capture.json"));
        assert_eq!(json["summary"]["ending"], "interrupted", "{name}");
        // The steps commanded so far are logged, no more.
        let logged = csv_rows(&s.join("pressures.csv")).len();
        let told = std::fs::read_to_string(d.join("told.txt"))
            .unwrap()
            .lines()
            .count();
        assert_eq!(logged, told, "{name}");
        assert!((1..12).contains(&logged), "{name}: {logged}");
    }
    // SIGKILL: nothing runs at the end, and the files of the last second are there.
    let child = spawn("kill");
    let s = d.join("kill");
    wait_until_listed(&s);
    send(&child, libc::SIGKILL);
    child.wait_with_output().unwrap();
    let json: serde_json::Value = read_json(&s.join("capture.json"));
    assert_eq!(json["summary"]["ending"], "filming");
    assert!(!csv_rows(&s.join("frames/frames.csv")).is_empty());
    assert!(!csv_rows(&s.join("pressures.csv")).is_empty());
}

/// Issue 44, item 1: a file that cannot be written mid-protocol (here the frames' folder
/// vanishes, as a lost mount or a full disk makes writes fail) ends the session as a failing
/// command does: `--on-abort` vents the regulator, `capture.json` says how it ended, every step
/// the regulator was told is logged, and the exit status says it failed.
#[test]
fn a_write_failure_ends_the_session_vented_with_every_step_logged() {
    let _cores = real_time();
    let dir = tempdir();
    let d = dir.path();
    long_cameras(d);
    protocol(d, "p.csv", "1");
    let command = recorder(d, 0.05);
    let mut args = session_args("s", "p.csv", &command).to_vec();
    args.extend(["--on-abort", "touch vented"]);
    let child = std::process::Command::new(env!("CARGO_BIN_EXE_handcap"))
        .args(&args)
        .current_dir(d)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    wait_until_listed(&d.join("s"));
    // Moved away at once (removing it would race the frames still being written).
    std::fs::rename(d.join("s/frames"), d.join("gone")).unwrap();
    let out = child.wait_with_output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(
        err.contains("frames") && err.contains("the abort command ran"),
        "{err}"
    );
    assert!(d.join("vented").is_file(), "the regulator was not vented");
    let json: serde_json::Value = read_json(&d.join("s/capture.json"));
    assert!(
        json["summary"]["ending"]["write_failed"].is_object(),
        "{json}"
    );
    let logged = csv_rows(&d.join("s/pressures.csv")).len();
    let told = std::fs::read_to_string(d.join("told.txt"))
        .unwrap()
        .lines()
        .count();
    assert_eq!(logged, told);
    assert!(logged >= 1);
}

/// Issue 44, item 8: a regulator slower than every step's hold leaves no settled frame: the
/// live line, `capture.json` and the exit status say so, and the session is kept.
#[test]
fn commands_slower_than_their_hold_are_said_and_fail_the_session() {
    let _cores = real_time();
    let dir = tempdir();
    let d = dir.path();
    long_cameras(d);
    protocol(d, "p.csv", "0.1");
    let command = recorder(d, 0.15);
    let out = handcap(d, &session_args("s", "p.csv", &command));
    let said =
        String::from_utf8_lossy(&out.stdout).to_string() + &String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{said}");
    assert!(
        said.contains(
            "12 of 12 steps: the regulator's command returned only after the step's hold"
        ),
        "{said}"
    );
    assert!(said.contains("12 of them unsettled"), "{said}");
    let json: serde_json::Value = read_json(&d.join("s/capture.json"));
    assert_eq!(json["summary"]["ending"], "protocol_done");
    assert_eq!(json["summary"]["stats"]["over_hold"], 12);
    assert_eq!(csv_rows(&d.join("s/pressures.csv")).len(), 12);
}

/// Waits (at most 30 s) until the recorder of [`recorder`] was told `steps` steps.
fn wait_until_told(dir: &Path, steps: usize) {
    let told = || std::fs::read_to_string(dir.join("told.txt")).map_or(0, |t| t.lines().count());
    wait_for(&format!("{steps} steps told"), || told() >= steps);
}

/// Waits (at most 30 s) until the session in `dir` lists a frame and a step: its files are
/// rewritten every second while it films, so the first listing is its readiness.
fn wait_until_listed(dir: &Path) {
    let listed = |file: &str| dir.join(file).is_file() && !csv_rows(&dir.join(file)).is_empty();
    wait_for(
        &format!("{} listing a frame and a step", dir.display()),
        || listed("frames/frames.csv") && listed("pressures.csv"),
    );
}

/// Polls `ready` every 5 ms, failing the test after 30 s without it.
fn wait_for(what: &str, ready: impl Fn() -> bool) {
    let start = std::time::Instant::now();
    while !ready() {
        assert!(start.elapsed().as_secs() < 30, "30 s without {what}");
        std::thread::sleep(std::time::Duration::from_millis(5));
    }
}

/// A regulator command that hangs does not hold the session: when the cameras stop, the
/// command is killed and the session ends, saying why, with nothing logged for it.
#[test]
fn a_hung_pressure_command_does_not_hold_the_session() {
    let _cores = real_time();
    let dir = tempdir();
    let d = dir.path();
    cameras(d, 3);
    protocol(d, "p.csv", "0.2");
    // The session ends early, so --on-abort runs once, after the cameras and the command.
    let mut args = session_args("s", "p.csv", "sleep 60").to_vec();
    args.extend(["--on-abort", "echo vented >> vented.txt"]);
    let out = handcap(d, &args);
    assert_eq!(out.status.code(), Some(1));
    let msg = String::from_utf8_lossy(&out.stderr);
    assert!(msg.contains("camera stopped delivering"), "{msg}");
    assert!(msg.contains("ran --on-abort: done"), "{msg}");
    assert!(csv_rows(&d.join("s/pressures.csv")).is_empty());
    assert_eq!(
        std::fs::read_to_string(d.join("vented.txt")).unwrap(),
        "vented\n"
    );
    let json: serde_json::Value = read_json(&d.join("s/capture.json"));
    assert_eq!(json["summary"]["on_abort"], "done");
}

/// `capture --calib` from the two board videos of [`board_videos`] as cameras, into `s`.
const VIDEO_CAMERAS: [&str; 7] = [
    "--left",
    "vids/left.avi",
    "--right",
    "vids/right.avi",
    "--out",
    "s",
    "--calib",
];

#[test]
fn a_calibration_capture_takes_still_new_board_pairs_then_the_reference() {
    let _cores = real_time();
    // The two board videos as cameras: ten boards, each held still for 1.2 s (slack for a busy
    // machine, whose judge looks less often).
    let dir = tempdir();
    let d = dir.path();
    board_videos(d, 36, handcap::calib::file::default_board(), 0);
    let cams = VIDEO_CAMERAS;
    let mut args = vec!["capture"];
    args.extend(cams);
    args.extend(["--pairs", "6"]);
    let out = handcap_ok(d, &args);
    assert!(out.contains("board pairs 6/6"), "{out}");
    for k in 0..6 {
        for side in ["left", "right"] {
            let jpeg = std::fs::read(d.join(format!("s/calib/{side}_{k:02}.jpg"))).unwrap();
            assert!(jpeg.starts_with(&[0xff, 0xd8]), "{side} {k}");
        }
    }
    assert!(!d.join("s/calib/left_06.jpg").exists() && !d.join("s/frames").exists());
    // The reference pair: the first still pair.
    let mut args = vec!["capture"];
    args.extend(cams);
    args.push("--reference");
    handcap_ok(d, &args);
    assert!(d.join("s/calib/left_ref.jpg").is_file() && d.join("s/calib/right_ref.jpg").is_file());
    // What was taken calibrates, with the hand axes.
    let out = handcap_ok(d, &["calibrate", "s/calib", "--out", "cal.yml"]);
    assert!(
        out.contains("6 pairs used") && out.contains("hand axes: from the reference pair"),
        "{out}"
    );
    // Taken pairs are never overwritten.
    let mut args = vec!["capture"];
    args.extend(cams);
    let msg = handcap_err(d, &args);
    assert!(msg.contains("already holds calibration pairs"), "{msg}");
}

/// The right camera half a second behind the left (its video starts 15 frames later), boards
/// held 2 s: the delay is measured from the board's motion, and a pair is taken only once
/// the board has stood still in both cameras longer than the delays differ, so every pair
/// shows one place in both (taken at once, the left's new place would join the right's old
/// one) and calibrates.
#[test]
fn a_calibration_capture_waits_out_the_cameras_delay() {
    let _cores = real_time();
    let dir = tempdir();
    let d = dir.path();
    board_videos(d, 60, handcap::calib::file::default_board(), 15);
    let mut args = vec!["capture"];
    args.extend(VIDEO_CAMERAS);
    args.extend(["--pairs", "6"]);
    let out = handcap_ok(d, &args);
    println!("{out}");
    assert!(out.contains("board pairs 6/6"), "{out}");
    let json: serde_json::Value = read_json(&d.join("s/capture.json"));
    let ms = json["summary"]["stats"]["board_delay_ms"].as_f64().unwrap();
    assert!((ms - 500.0).abs() < 50.0, "{ms} ms");
    let out = handcap_ok(d, &["calibrate", "s/calib", "--out", "cal.yml"]);
    println!("{out}");
    assert!(out.contains("6 pairs used"), "{out}");
    let truth = crate::common::read_rig(&d.join("truth/rig.yml"));
    let calibrated = crate::common::read_rig(&d.join("cal.yml"));
    let (b, t) = (calibrated.t.norm(), truth.t.norm());
    println!("baseline {b:.3} mm, truth {t:.3} mm");
    assert!((b - t).abs() < 0.01 * t, "baseline {b} mm, truth {t} mm");
}

/// A ChArUco board is taken in part (every other board of these videos is partly out of view),
/// and the pairs taken, or picked from the videos by `calibrate`, calibrate.
#[test]
fn a_charuco_board_is_taken_in_part_from_cameras_and_videos() {
    let _cores = real_time();
    let dir = tempdir();
    let d = dir.path();
    let board = crate::common::charuco_board();
    board_videos(d, 36, board, 0);
    let mut args = vec!["capture"];
    args.extend(VIDEO_CAMERAS);
    let board_flags = "--board charuco:10x7 --square-mm 10 --marker-mm 7.5";
    args.extend(["--pairs", "6"]);
    args.extend(board_flags.split(' '));
    let out = handcap_ok(d, &args);
    assert!(out.contains("board pairs 6/6"), "{out}");
    let described = handcap::calib::file::read_board(&d.join("s/calib/board.yml")).unwrap();
    assert_eq!(described, board);
    let out = handcap_ok(d, &["calibrate", "s/calib", "--out", "cal.yml"]);
    assert!(out.contains("6 pairs used"), "{out}");
    assert!(out.contains("of 54 corners in both images"), "{out}");
    // From the videos themselves.
    let out = handcap_ok(d, &["calibrate", "vids", "--out", "videos.yml"]);
    assert!(
        out.contains("pairs used") && out.contains("of 54 corners in both images"),
        "{out}"
    );
}

/// Serves `frames` (JPEG files' bytes) at 30 fps ([`mjpeg_server`]); the frames numbered in
/// `held` wait and go with the first after them, at once (a network or server that fell
/// behind); after the last frame the stream closes, or with `stall` stays open and silent for a
/// minute (a camera or server that hangs). Returns the stream's URL.
fn served(frames: Vec<Vec<u8>>, held: std::ops::Range<usize>, stall: bool) -> String {
    let mut start = None;
    mjpeg_server(move |n| {
        let start = *start.get_or_insert_with(std::time::Instant::now);
        let Some(jpeg) = frames.get(n) else {
            if stall {
                std::thread::sleep(std::time::Duration::from_secs(60));
            }
            return Part::End;
        };
        let due = if held.contains(&n) { held.end } else { n };
        let due = std::time::Duration::from_secs_f64(due as f64 / 30.0);
        std::thread::sleep(due.saturating_sub(start.elapsed()));
        Part::Frame(jpeg.clone())
    })
}

/// A camera URL that does not open says what its server answered: a wrong path (404), wrong
/// credentials (401: the password never shown), a web page instead of a stream, nothing
/// listening.
#[test]
fn url_failures_say_what_the_server_answers() {
    let _cores = real_time();
    use std::io::{Read, Write};
    let dir = tempdir();
    let d = dir.path();
    // Answers every request with `head` and closes.
    let answering = |head: &'static str| {
        let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
        let address = listener.local_addr().unwrap();
        std::thread::spawn(move || {
            for mut client in listener.incoming().flatten() {
                let mut request = [0u8; 2048];
                let _ = client.read(&mut request);
                let _ = client.write_all(head.as_bytes());
            }
        });
        address
    };
    let live = served(moving_square(300), 0..0, false);
    let refused = |left: &str| {
        let out = handcap(
            d,
            &[
                "capture",
                "--left",
                left,
                "--right",
                &live,
                "--duration-s",
                "1",
                "--out",
                "s",
            ],
        );
        assert_eq!(out.status.code(), Some(1));
        String::from_utf8_lossy(&out.stderr).to_string()
    };
    let missing = answering("HTTP/1.0 404 Not Found\r\nContent-Type: text/html\r\n\r\nno");
    let said = refused(&format!("http://{missing}/video"));
    assert!(
        said.contains("the server answers 404 Not Found (text/html)"),
        "{said}"
    );
    let locked = answering("HTTP/1.0 401 Unauthorized\r\nWWW-Authenticate: Basic\r\n\r\n");
    let said = refused(&format!("http://lab:s3cret@{locked}/video"));
    assert!(
        said.contains("the server answers 401 Unauthorized"),
        "{said}"
    );
    assert!(
        !said.contains("s3cret") && said.contains("lab:***@"),
        "{said}"
    );
    let page = answering("HTTP/1.0 200 OK\r\nContent-Type: text/html\r\n\r\n<html></html>");
    let said = refused(&format!("http://{page}/"));
    assert!(
        said.contains("the server answers 200 OK (text/html)"),
        "{said}"
    );
    let closed = std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap();
    let said = refused(&format!("http://{closed}/video"));
    assert!(said.contains("connection refused"), "{said}");
}

/// `n` distinct JPEG frames: a bright square moving across a grey 320×240 image.
fn moving_square(n: i32) -> Vec<Vec<u8>> {
    (0..n)
        .map(|k| {
            let mut image = opencv::core::Mat::new_rows_cols_with_default(
                240,
                320,
                opencv::core::CV_8UC3,
                opencv::core::Scalar::all(90.0),
            )
            .unwrap();
            opencv::imgproc::rectangle(
                &mut image,
                opencv::core::Rect::new(k % 280, 100, 30, 30),
                opencv::core::Scalar::new(40.0, 40.0, 220.0, 0.0),
                -1,
                opencv::imgproc::LINE_8,
                0,
            )
            .unwrap();
            let mut jpeg = opencv::core::Vector::<u8>::new();
            opencv::imgcodecs::imencode(".jpg", &image, &mut jpeg, &opencv::core::Vector::new())
                .unwrap();
            opencv::prelude::VectorToVec::to_vec(&jpeg)
        })
        .collect()
}

/// Two HTTP Motion-JPEG streams filmed: every frame is kept as the bytes the server sent (no
/// decoding and re-encoding on the grab thread), numbered in order. The left server falls
/// behind for half a second and then sends what it held at once: those frames are said to be
/// stamped late, live and in `capture.json`.
#[test]
fn network_mjpeg_frames_are_kept_as_they_came() {
    let _cores = real_time();
    let dir = tempdir();
    let d = dir.path();
    let frames = moving_square(60);
    let (left, right) = (
        served(frames.clone(), 15..30, false),
        served(frames.clone(), 0..0, false),
    );
    let out = handcap_ok(
        d,
        &[
            "capture",
            "--left",
            &left,
            "--right",
            &right,
            "--duration-s",
            "1.5",
            "--out",
            "s",
        ],
    );
    assert!(!out.contains("refused"), "{out}");
    let [l, r] = assert_consistent(&d.join("s"));
    assert!(l >= 35 && r >= 35, "{l} left, {r} right frames");
    // Frames 15-29 waited 500 ms down to 33 ms: each is late by over half a period.
    let json: serde_json::Value = read_json(&d.join("s/capture.json"));
    let stats = &json["summary"]["stats"];
    let late = stats["late"][0].as_u64().unwrap();
    // (A busy test machine may queue a few more of either camera's frames.)
    assert!((15..=25).contains(&late), "{stats}");
    assert!(stats["late_max_ms"][0].as_f64().unwrap() > 350.0, "{stats}");
    assert!(out.contains(&format!("stamped late {late}/")), "{out}");
    for (side, count) in [("left", l), ("right", r)] {
        for (k, served) in frames.iter().take(count).enumerate() {
            let kept = std::fs::read(d.join(format!("s/frames/{side}_{k:05}.jpg"))).unwrap();
            assert!(&kept == served, "{side} frame {k} is not the JPEG served");
        }
    }
}

/// A server that answers with headers and never a frame is refused within the open timeout;
/// one that stops sending mid-session ends the session as a stopped camera, every frame kept,
/// instead of waiting on FFmpeg's own 30 s.
#[test]
fn a_silent_or_stalled_stream_ends_the_session() {
    let _cores = real_time();
    let dir = tempdir();
    let d = dir.path();
    let args = |left: &str, right: &str| -> Vec<String> {
        [
            "capture",
            "--left",
            left,
            "--right",
            right,
            "--duration-s",
            "30",
            "--out",
            "s",
        ]
        .map(String::from)
        .to_vec()
    };
    let run = |a: &[String]| {
        let start = std::time::Instant::now();
        let out = handcap(d, &a.iter().map(String::as_str).collect::<Vec<_>>());
        (out, start.elapsed().as_secs_f64())
    };
    let (silent, live) = (
        served(Vec::new(), 0..0, true),
        served(moving_square(30), 0..0, false),
    );
    let (out, took) = run(&args(&silent, &live));
    let said = String::from_utf8_lossy(&out.stderr).to_string();
    assert_eq!(out.status.code(), Some(1), "{said}");
    assert!(
        said.contains("cannot open the left camera")
            && said.contains("did not open and send a frame within 5 s"),
        "{said}"
    );
    println!("silent server refused after {took:.1} s");
    // Within the open timeout (and the process's start and the other camera's opening), far
    // from FFmpeg's own 30 s.
    let open = handcap::capture::STREAM_OPEN_S;
    assert!(
        (open - 0.5..open + 5.0).contains(&took),
        "refused after {took:.1} s, the open timeout is {open} s"
    );
    let (stalling, live) = (
        served(moving_square(30), 0..0, true),
        served(moving_square(600), 0..0, false),
    );
    let (out, took) = run(&args(&stalling, &live));
    let said =
        String::from_utf8_lossy(&out.stdout).to_string() + &String::from_utf8_lossy(&out.stderr);
    let json: serde_json::Value = read_json(&d.join("s/capture.json"));
    let ending = &json["summary"]["ending"];
    assert_eq!(
        ending["camera_stopped"]["camera"], "left",
        "{ending} {said}"
    );
    let [l, r] = assert_consistent(&d.join("s"));
    assert!(l >= 20 && r > l, "{l} left, {r} right frames");
    println!("a stream stalled after 1 s: session ended after {took:.1} s, {l} left and {r} right frames kept");
    // The stall is seen `STALL_S` after the last frame, not at `--duration-s 30` or FFmpeg's
    // 30 s.
    let stall = handcap::capture::STALL_S;
    assert!(
        (1.0 + stall..1.0 + stall + 8.0).contains(&took),
        "ended after {took:.1} s, the stall bound is {stall} s after the last frame at 1 s"
    );
}

/// A dynamic protocol of 3 s at 20 commands a second: 2 s of rest, then 1 s of one trial.
fn dynamic_protocol(d: &Path) {
    handcap_ok(
        d,
        &[
            "protocol",
            "--dynamic",
            "--duration-s",
            "1",
            "--rate-hz",
            "20",
            "--trials",
            "1",
            "--out",
            "p.csv",
        ],
    );
}

/// `capture` of [`long_cameras`]' videos into `out` for 3.5 s, [`dynamic_protocol`]'s
/// commands streamed to `regulator`.
fn streaming_session<'a>(out: &'a str, regulator: &'a str) -> [&'a str; 13] {
    [
        "capture",
        "--left",
        "cams/frames/left.avi",
        "--right",
        "cams/frames/right.avi",
        "--out",
        out,
        "--protocol",
        "p.csv",
        "--regulator",
        regulator,
        "--duration-s",
        "3.5",
    ]
}

/// `--regulator`: one process told every command on its input at the command's time; what it
/// prints back is logged as measured beside the command in force.
#[test]
fn a_streaming_regulator_is_told_each_command_on_time_and_its_measurements_logged() {
    let _cores = real_time();
    let dir = tempdir();
    let d = dir.path();
    long_cameras(d);
    dynamic_protocol(d);
    let protocol = csv_rows(&d.join("p.csv"));
    assert_eq!(protocol.len(), 22, "rest, 20 commands, rest");
    // It records what it reads, and answers each line with half the pressures as measured.
    let regulator = "while read t a b c; do echo \"$t $a $b $c\" >> told.txt; echo \"$t $(echo \"$a/2\" | bc -l) $b $c\"; done";
    let out = handcap_ok(d, &streaming_session("s", regulator));
    assert!(out.contains("regulator: 22 lines written"), "{out}");
    let told: Vec<String> = std::fs::read_to_string(d.join("told.txt"))
        .unwrap()
        .lines()
        .map(String::from)
        .collect();
    let log = csv_rows(&d.join("s/pressures.csv"));
    assert_eq!(told.len(), 22);
    assert_eq!(log.len(), 22);
    let mut due = 0.0;
    for ((p, t), l) in protocol.iter().zip(&told).zip(&log) {
        // The line carries the logged time and the protocol's pressures.
        let fields: Vec<&str> = t.split(' ').collect();
        assert_eq!(fields[0], l["time_s"]);
        assert_eq!(
            fields[1..],
            [&p["P1_kpa"], &p["P2_kpa"], &p["P3_kpa"]].map(String::as_str)
        );
        // Sent when due (the holds added up from the session's start), within the scheduler's
        // slack.
        let time: f64 = l["time_s"].parse().unwrap();
        assert!(time >= due && time <= due + 0.05, "{time} due {due}");
        due += p["hold_s"].parse::<f64>().unwrap();
    }
    // Measured: logged beside the commands (all but, perhaps, the last few of the trial).
    let measured: Vec<&_> = log
        .iter()
        .filter(|l| !l["P1_measured_kpa"].is_empty())
        .collect();
    assert!(measured.len() >= 18, "{} rows measured", measured.len());
    for l in measured {
        let (m, c): (f64, f64) = (
            l["P1_measured_kpa"].parse().unwrap(),
            l["P1_kpa"].parse().unwrap(),
        );
        assert!((m - c / 2.0).abs() < 1e-6, "{m} measured for {c}");
    }
}

/// Hostile probes 3 and 5 (issue 61): a regulator whose output is block-buffered (Python
/// without a flush) had 1 of 183 rows measured, its lines all landing on the last command; one
/// that logs on its error output filled the pipe and was aborted as stalled after 64 KB.
#[test]
fn hostile_a_buffered_and_chatty_regulator_is_measured_whole() {
    let _cores = real_time();
    let dir = tempdir();
    let d = dir.path();
    long_cameras(d);
    dynamic_protocol(d);
    // Answers each line with its time and half the first pressure, on an output buffered
    // until it exits, and logs 4 KB to its error output per line (88 KB in all).
    let script = "import sys\n\
        out = open(1, 'w', buffering=65536, closefd=False)\n\
        for line in sys.stdin:\n\
        \x20   t, a, b, c = line.split()\n\
        \x20   sys.stderr.write('set ' * 1024)\n\
        \x20   print(t, float(a) / 2, b, c, file=out)\n\
        out.flush()\n";
    crate::common::write(d, "regulator.py", script);
    let out = handcap_ok(d, &streaming_session("s", "python3 regulator.py"));
    assert!(out.contains("regulator: 22 lines written"), "{out}");
    let log = csv_rows(&d.join("s/pressures.csv"));
    assert_eq!(log.len(), 22);
    for l in &log {
        let (m, c): (f64, f64) = (
            l["P1_measured_kpa"].parse().unwrap(),
            l["P1_kpa"].parse().unwrap(),
        );
        assert!((m - c / 2.0).abs() < 1e-6, "{m} measured for {c}");
    }
}

/// A streaming regulator that prints garbage, dies or stops reading ends the session with one
/// line naming what it did, the commands before it logged.
#[test]
fn a_streaming_regulator_that_fails_ends_the_session_with_everything_kept() {
    let _cores = real_time();
    let dir = tempdir();
    let d = dir.path();
    long_cameras(d);
    dynamic_protocol(d);
    let cases = [
        (
            "garbage",
            "read l; echo pressure is fine; sleep 10",
            "printed line 1: \"pressure is fine\", not `time_s P1_kpa P2_kpa P3_kpa`",
        ),
        (
            "dies",
            "read l; read l; echo valve fault >&2; exit 4",
            "exited with exit status: 4: valve fault",
        ),
        (
            "stalls",
            "sleep 30",
            "has not read its input for 2 s (stalled)",
        ),
        // Hostile probe 3 (issue 61): any value a regulator printed was logged.
        (
            "not_a_pressure",
            "read t a b c; echo \"$t 99999 0 0\"; sleep 10",
            "99999 kPa is not a pressure a regulator measures (-20 to 330 kPa)",
        ),
        // Hostile probe 5: a line without a newline grew memory without bound; a regulator
        // that exited while a child held its error output blocked the session until the child
        // ended.
        (
            "endless_line",
            "read l; head -c 3000000 /dev/zero | tr '\\0' a; sleep 10",
            "printed line 1: a line longer than 1024 bytes",
        ),
        (
            "child_holds_stderr",
            "read l; sleep 1000 & echo valve fault >&2; exit 4",
            "exited with exit status: 4: valve fault",
        ),
    ];
    for (name, regulator, says) in cases {
        let args = [
            "capture",
            "--left",
            "cams/frames/left.avi",
            "--right",
            "cams/frames/right.avi",
            "--out",
            name,
            "--protocol",
            "p.csv",
            "--regulator",
            regulator,
        ];
        let msg = handcap_err(d, &args);
        assert!(msg.contains(says), "{name}: {msg}");
        assert_eq!(
            msg.trim()
                .lines()
                .filter(|l| l.starts_with("handcap:"))
                .count(),
            1,
            "{msg}"
        );
        let log = csv_rows(&d.join(name).join("pressures.csv"));
        assert!(
            !log.is_empty() || name == "stalls",
            "{name}: nothing logged"
        );
        let json: serde_json::Value = read_json(&d.join(name).join("capture.json"));
        assert!(
            json["summary"]["ending"]["command_failed"].is_object(),
            "{name}: {json}"
        );
    }
}

/// `protocol --dynamic` outside its rules is refused in one line, nothing written; the step
/// protocol's flags do not go with it.
#[test]
fn a_dynamic_protocol_outside_its_rules_is_one_line() {
    let dir = tempdir();
    let d = dir.path();
    for (flags, says) in [
        (
            ["--rate-hz", "300"],
            "--rate-hz 300: the command rate must be at least one an hour",
        ),
        // Hostile probe 11 (issue 61): holds capture then refused were written.
        (
            ["--rate-hz", "1e-9"],
            "the command rate must be at least one an hour (each command is held one period, at most 3600 s) and at most 200 Hz",
        ),
        (
            ["--duration-s", "0"],
            "--duration-s 0: each trial must last more than 0 s",
        ),
        (
            ["--max-kpa", "350"],
            "--max-kpa 350: the pressure box must lie inside 0-300 kPa",
        ),
    ] {
        let mut args = vec!["protocol", "--dynamic", "--out", "p.csv"];
        args.extend(flags);
        let msg = handcap_err(d, &args);
        assert!(msg.contains(says), "{msg}");
        assert!(!d.join("p.csv").exists());
    }
    let msg = crate::common::handcap_usage(
        d,
        &["protocol", "--dynamic", "--hold-s", "1", "--out", "p.csv"],
    );
    assert!(msg.contains("--hold-s"), "{msg}");
    let out = handcap_ok(
        d,
        &[
            "protocol",
            "--dynamic",
            "--trials",
            "2",
            "--duration-s",
            "5",
            "--out",
            "p.csv",
        ],
    );
    assert!(
        out.contains("303 commands at 30 Hz in 2 trials, 16 s with the rest holds; seed 2020"),
        "{out}"
    );
}

/// A dynamic protocol at 20 commands a second through `--regulator`, filmed from two HTTP
/// Motion-JPEG streams while two threads keep both cores busy: every command goes out when due
/// and is logged when it did (the lateness reported), the frames all kept.
#[test]
fn a_streaming_regulator_keeps_its_times_beside_two_streams_and_a_busy_machine() {
    let _cores = real_time();
    let dir = tempdir();
    let d = dir.path();
    handcap_ok(
        d,
        &[
            "protocol",
            "--dynamic",
            "--duration-s",
            "3",
            "--rate-hz",
            "20",
            "--trials",
            "1",
            "--out",
            "p.csv",
        ],
    );
    let (left, right) = (
        served(moving_square(300), 0..0, false),
        served(moving_square(300), 0..0, false),
    );
    let busy = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(true));
    let hogs: Vec<_> = (0..2)
        .map(|_| {
            let busy = busy.clone();
            std::thread::spawn(move || {
                let mut x = 0u64;
                while busy.load(std::sync::atomic::Ordering::Relaxed) {
                    x = std::hint::black_box(x.wrapping_mul(6364136223846793005).wrapping_add(1));
                }
            })
        })
        .collect();
    let out = handcap_ok(
        d,
        &[
            "capture",
            "--left",
            &left,
            "--right",
            &right,
            "--width",
            "320",
            "--height",
            "240",
            "--out",
            "s",
            "--protocol",
            "p.csv",
            "--regulator",
            "cat > told.txt",
        ],
    );
    busy.store(false, std::sync::atomic::Ordering::Relaxed);
    for h in hogs {
        h.join().unwrap();
    }
    let protocol = csv_rows(&d.join("p.csv"));
    let log = csv_rows(&d.join("s/pressures.csv"));
    assert_eq!(log.len(), protocol.len(), "{out}");
    assert_eq!(
        std::fs::read_to_string(d.join("told.txt"))
            .unwrap()
            .lines()
            .count(),
        protocol.len()
    );
    let json: serde_json::Value = read_json(&d.join("s/capture.json"));
    let late = &json["summary"]["stats"]["command_late_ms"];
    let (median, latest) = (late[0].as_f64().unwrap(), late[1].as_f64().unwrap());
    assert!(
        median < 5.0 && latest < 50.0,
        "lines late by {median} ms (median), {latest} ms at most"
    );
    assert!(out.contains("regulator: 62 lines written"), "{out}");
    let [l, r] = assert_consistent(&d.join("s"));
    assert!(l >= 100 && r >= 100, "{l} left, {r} right frames");
}

/// A tmpfs of `bytes` mounted at `dir` for the life of the guard, when this process may mount
/// one (root); `None` otherwise.
struct Tmpfs(PathBuf);

impl Tmpfs {
    fn mount(dir: &Path, bytes: usize) -> Option<Tmpfs> {
        std::fs::create_dir_all(dir).unwrap();
        let size = format!("size={bytes}");
        let mounted = std::process::Command::new("mount")
            .args(["-t", "tmpfs", "-o", &size, "tmpfs"])
            .arg(dir)
            .stderr(std::process::Stdio::null())
            .status()
            .is_ok_and(|s| s.success());
        mounted.then(|| Tmpfs(dir.to_path_buf()))
    }
}

impl Drop for Tmpfs {
    fn drop(&mut self) {
        let _ = std::process::Command::new("umount").arg(&self.0).status();
    }
}

/// Hostile probe 8 (issue 61): a disk that fills mid-capture (a real one: a 3 MB tmpfs) left 23
/// of 25 commands out of `pressures.csv`, 45 frames on disk unlisted and `capture.json` saying
/// "filming", while the message said every frame was kept and listed. Space for the lists is
/// kept from the start: every command told is logged, every image on disk listed and every
/// listed one there, the regulator vented, the ending said. Runs only where a tmpfs can be
/// mounted (root); says so otherwise.
#[test]
fn hostile_a_disk_full_mid_capture_leaves_the_lists_true() {
    let _cores = real_time();
    let dir = tempdir();
    let d = dir.path();
    let Some(_disk) = Tmpfs::mount(&d.join("disk"), 3 << 20) else {
        println!("did not run: mounting a tmpfs needs root");
        return;
    };
    long_cameras(d);
    protocol(d, "p.csv", "1");
    let command = recorder(d, 0.05);
    let mut args = session_args("disk/s", "p.csv", &command).to_vec();
    args.extend(["--on-abort", "touch vented"]);
    let out = handcap(d, &args);
    let err = String::from_utf8_lossy(&out.stderr);
    println!("{err}");
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(d.join("vented").is_file(), "the regulator was not vented");
    let s = d.join("disk/s");
    let json: serde_json::Value = read_json(&s.join("capture.json"));
    assert!(
        json["summary"]["ending"]["write_failed"].is_object(),
        "{json}"
    );
    let told = std::fs::read_to_string(d.join("told.txt")).unwrap();
    assert_eq!(
        csv_rows(&s.join("pressures.csv")).len(),
        told.lines().count()
    );
    let listed = assert_consistent(&s);
    assert!(listed[0] > 5, "{listed:?}");
    let left: Vec<String> = std::fs::read_dir(&s)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert!(
        left.iter()
            .all(|n| ["frames", "capture.json", "pressures.csv"].contains(&n.as_str())),
        "{left:?}"
    );
}
