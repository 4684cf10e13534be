//! `capture --view` as a user watches it: a session on `handcap lab` opened in a real headless
//! browser (Chromium, as `scripts/setup.sh` installs it), the page's cameras and tip track
//! read from what it shows and scored against the lab's truth; requests without the token.

use std::io::{BufRead, Read, Write};
use std::net::TcpStream;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use crate::common::{cameras_alarmed, csv_rows, handcap_ok, read_json, real_time, tempdir};
use crate::lab::{dynamic_protocol, Lab, Truth};

/// The browser the page is tested in.
const CHROMIUM: &str = "/usr/bin/chromium";

/// `GET url`: the status code and the body.
fn get(url: &str) -> (u16, Vec<u8>) {
    let rest = url.strip_prefix("http://").expect("an http URL");
    let (host, path) = rest.split_at(rest.find('/').unwrap_or(rest.len()));
    let mut stream = TcpStream::connect(host).expect("connect");
    write!(stream, "GET {path} HTTP/1.0\r\nHost: {host}\r\n\r\n").unwrap();
    let mut answer = Vec::new();
    stream.read_to_end(&mut answer).unwrap();
    let head_end = answer.windows(4).position(|w| w == b"\r\n\r\n").unwrap();
    let head = String::from_utf8_lossy(&answer[..head_end]).to_string();
    let status = head.split_whitespace().nth(1).unwrap().parse().unwrap();
    (status, answer[head_end + 4..].to_vec())
}

/// The page at `url` as a headless Chromium shows it after `budget_ms` of its (virtual) time:
/// the document, its scripts run.
fn browse(url: &str, budget_ms: u32, profile: &std::path::Path) -> String {
    assert!(
        std::path::Path::new(CHROMIUM).exists(),
        "{CHROMIUM} not found: run bash scripts/setup.sh (it installs Debian's chromium)"
    );
    let out = Command::new(CHROMIUM)
        .args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-quic",
            "--no-first-run",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            &format!("--user-data-dir={}", profile.display()),
            &format!("--virtual-time-budget={budget_ms}"),
            "--dump-dom",
            url,
        ])
        .stderr(Stdio::null())
        .output()
        .expect("run chromium");
    assert!(out.status.success(), "chromium failed on {url}");
    String::from_utf8(out.stdout).unwrap()
}

/// The value of the attribute `name` of the element whose opening tag holds `marker`.
fn attribute<'a>(dom: &'a str, marker: &str, name: &str) -> Option<&'a str> {
    let at = dom.find(marker)?;
    let tag = &dom[dom[..at].rfind('<')?..at + dom[at..].find('>')?];
    let start = tag.find(&format!(" {name}=\""))? + name.len() + 3;
    Some(&tag[start..start + tag[start..].find('"')?])
}

/// A `capture --view` of `lab`'s protocol `dyn.csv` into `live`, with `extra` flags: the
/// process, the page's URL, and what it prints on each stream (read to the end as it runs).
struct Viewed {
    capture: Child,
    url: String,
    printed: std::thread::JoinHandle<Vec<String>>,
    said: std::thread::JoinHandle<String>,
}

fn capture_viewed(d: &std::path::Path, lab: &Lab, extra: &[&str]) -> Viewed {
    let mut capture = Command::new(env!("CARGO_BIN_EXE_handcap"))
        .current_dir(d)
        .arg("capture")
        .args(lab.camera_args())
        .args(["--out", "live", "--protocol", "dyn.csv"])
        .args(["--regulator", &format!("serial:{}", lab.regulator)])
        .args(["--view", "--view-calib", "lab/truth/rig.yml"])
        .args(extra)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("run capture");
    let mut lines = std::io::BufReader::new(capture.stdout.take().unwrap()).lines();
    let first = lines.next().unwrap().unwrap();
    let url = first
        .strip_prefix("view ")
        .expect("a `view URL` line first")
        .to_string();
    let printed = std::thread::spawn(move || lines.map_while(Result::ok).collect());
    let mut stderr = capture.stderr.take().unwrap();
    let said = std::thread::spawn(move || {
        let mut text = String::new();
        let _ = stderr.read_to_string(&mut text);
        text
    });
    Viewed {
        capture,
        url,
        printed,
        said,
    }
}

#[test]
fn the_view_page_shows_both_cameras_and_a_tip_track_that_matches_the_lab_truth() {
    let _machine = real_time();
    let dir = tempdir();
    let d = dir.path();
    dynamic_protocol(d, 12);
    let lab = Lab::start(d, &[]);
    let Viewed {
        mut capture,
        url,
        said,
        ..
    } = capture_viewed(d, &lab, &[]);
    let origin = &url[..url[7..].find('/').unwrap() + 7];

    // Without the token, or with another, nothing is served.
    assert_eq!(get(&format!("{origin}/")).0, 404);
    assert_eq!(get(&format!("{origin}/state.json")).0, 404);
    assert_eq!(
        get(&format!(
            "{origin}/00000000000000000000000000000000/state.json"
        ))
        .0,
        404
    );

    // The page once the finger has moved for a few seconds.
    let started = Instant::now();
    let mut state = serde_json::Value::Null;
    loop {
        if let Ok(Some(end)) = capture.try_wait() {
            panic!("capture ended ({end}) before the page showed 200 tips: {state}");
        }
        let (status, body) = get(&format!("{url}state.json"));
        assert_eq!(status, 200);
        state = serde_json::from_slice(&body).unwrap();
        if state["track"]["points"]
            .as_array()
            .is_some_and(|p| p.len() >= 200)
        {
            break;
        }
        std::thread::sleep(Duration::from_millis(250));
    }
    eprintln!(
        "view: a track after {:.1} s",
        started.elapsed().as_secs_f64()
    );
    let dom = browse(&url, 3000, &d.join("chromium"));

    // It refreshed five times a second (its clock virtual: 3 s of it).
    let refreshed: u32 = attribute(&dom, "data-refreshed", "data-refreshed")
        .unwrap()
        .parse()
        .unwrap();
    assert!(refreshed >= 14, "refreshed {refreshed} times in 3 s");
    // Both cameras' latest frames, loaded whole, each with the bead found.
    for camera in ["left", "right"] {
        let width = attribute(&dom, &format!("alt=\"{camera} camera\""), "data-width");
        assert_eq!(width, Some("1280"), "{camera}'s frame not shown");
        let bead = attribute(&dom, &format!("id=\"cam-{camera}\""), "data-bead").unwrap();
        assert_eq!(bead.split(',').count(), 2, "{camera}: no bead ({bead:?})");
    }
    // The track it shows is the lab's tip at each left frame's exposure.
    let tips = attribute(&dom, "id=\"track\"", "data-tips").expect("a track");
    let capture_end = capture.wait().unwrap();
    assert!(lab.stop().success());
    assert!(capture_end.success(), "{}", said.join().unwrap());
    let truth = Truth::read(&d.join("lab/truth"));
    let squared: Vec<f64> = tips
        .split(';')
        .map(|point| {
            let (frame, xyz) = point.split_once(':').unwrap();
            let got: Vec<f64> = xyz.split(',').map(|v| v.parse().unwrap()).collect();
            let want = truth.tip("left", frame.parse().unwrap());
            (0..3).map(|k| (got[k] - want[k]).powi(2)).sum::<f64>()
        })
        .collect();
    let rms = (squared.iter().sum::<f64>() / squared.len() as f64).sqrt();
    eprintln!(
        "view: {} tips shown, {rms:.4} mm RMS against the lab's truth",
        squared.len()
    );
    assert!(squared.len() >= 200, "{} tips", squared.len());
    assert!(
        rms <= 0.1,
        "the page's track {rms:.4} mm RMS from the lab's truth"
    );
    // The browser's visit changed nothing: the session filmed every step.
    assert_eq!(
        csv_rows(&d.join("live/pressures.csv")).len(),
        csv_rows(&d.join("dyn.csv")).len()
    );
}

#[test]
fn a_view_port_in_use_or_a_missing_calibration_is_one_line_and_nothing_filmed() {
    let dir = tempdir();
    let d = dir.path();
    let taken = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let port = taken.local_addr().unwrap().port().to_string();
    let cameras = [
        "capture", "--left", "0", "--right", "1", "--out", "s", "--view",
    ];
    for (extra, says) in [
        (
            vec!["--view-port", port.as_str()],
            format!("127.0.0.1:{port}"),
        ),
        (
            vec!["--view-calib", "nothing.yml"],
            "nothing.yml".to_string(),
        ),
        (
            vec!["--view-calib", "nothing.yml", "--model", "none.json"],
            "none.json".to_string(),
        ),
    ] {
        let out = crate::common::handcap(d, &[&cameras[..], &extra[..]].concat());
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success());
        assert_eq!(stderr.trim().lines().count(), 1, "{stderr}");
        assert!(stderr.contains(&says), "{stderr}");
        assert!(!d.join("s").exists());
    }
}

/// `capture --model`: the monitor live, on a lab whose right camera is knocked 0.5° at 16 s of
/// its clock. The camera alarm is raised after the knock and not before, said as it fires and
/// shown on the page; `OUT/monitor/` is what `handcap monitor` writes of the same session
/// triangulated afterwards: the same predictions, the same camera alarm within a look or two.
/// (The model is fitted on `synth`'s data-level finger of the lab's seed, on commanded
/// pressures; the lab's rows carry its board's measured ones, so its finger channel is not
/// scored here: `tests/it/monitor.rs` scores it.)
#[test]
fn a_camera_knocked_during_a_live_session_raises_the_live_monitors_camera_alarm_as_the_offline_ones(
) {
    let _machine = real_time();
    let dir = tempdir();
    let d = dir.path();
    crate::monitor::fit(d);
    dynamic_protocol(d, 24);
    let lab = Lab::start(d, &["--seed", "1", "--fault", "camera@16=0.5"]);
    // The baseline spans the finger's motion, not only the rest hold the protocol starts with:
    // the bead's residual is larger in motion (the two exposures interpolated to one instant),
    // and with a 6 s baseline (2 s of rest) the offline monitor took the motion for a moved
    // camera 2 s before the knock in one run of seven, and came within 0.6 of it in another.
    // With 10 s, the statistic's highest before the knock in six runs was 2.0 (the alarm 5.9).
    let settings = ["--baseline-s", "10", "--false-alarm-hours", "0.1"];
    let Viewed {
        mut capture,
        url,
        printed,
        said,
    } = capture_viewed(
        d,
        &lab,
        &[&["--model", "model.json"][..], &settings].concat(),
    );
    // The page once it shows an alarm.
    let mut state = serde_json::Value::Null;
    while state["trust"]["alarms"]
        .as_array()
        .is_none_or(Vec::is_empty)
    {
        if let Ok(Some(end)) = capture.try_wait() {
            panic!("capture ended ({end}) before the page showed an alarm: {state}");
        }
        std::thread::sleep(Duration::from_millis(250));
        state = serde_json::from_slice(&get(&format!("{url}state.json")).1).unwrap();
    }
    let dom = browse(&url, 1000, &d.join("chromium"));
    let shown = attribute(&dom, "id=\"trust\"", "data-alarms").expect("the monitor's panel");
    assert!(shown.contains("@"), "{shown:?}");
    // The still scene's figure: the knocked right camera's view moved by pixels, the left's
    // by a fraction of one.
    let scene = attribute(&dom, "id=\"trust\"", "data-scene").expect("the still scene");
    eprintln!("live: the page's newest still-scene shifts (left;right px) {scene}");
    let shifts: Vec<f64> = scene.split(';').map(|v| v.parse().unwrap()).collect();
    assert!(shifts[0] < 1.0 && shifts[1] > 3.0, "{scene:?}");
    // Drawn: both figures' lines have points, and the scene's its label.
    for figure in ["id=\"trust-plot\"", "id=\"trust-scene\""] {
        let drawn = &dom[dom.find(figure).expect(figure)..];
        let drawn = &drawn[..drawn.find("</svg>").unwrap()];
        assert!(
            drawn.contains(" points=\"") && !drawn.contains(" points=\"\""),
            "{drawn}"
        );
    }
    assert!(dom.contains("still scene moved (px): left blue, right red, 0 to"));
    // The finger's response test's statistic beside the alarms' (a CUSUM: never negative).
    let response = attribute(&dom, "id=\"trust\"", "data-response").expect("the response test");
    assert!(
        response.parse::<f64>().is_ok_and(|s| s >= 0.0),
        "{response:?}"
    );
    assert!(capture.wait().unwrap().success());
    assert!(lab.stop().success());
    let (said, printed) = (said.join().unwrap(), printed.join().unwrap());

    // The knock on capture's clock.
    let offset = read_json(&d.join("live/capture.json"))["summary"]["start_unix_s"]
        .as_f64()
        .unwrap()
        - read_json(&d.join("lab/truth/lab.json"))["epoch_unix_s"]
            .as_f64()
            .unwrap();
    let knock_s = 16.0 - offset;
    let camera = |watched: &serde_json::Value| -> (f64, f64) {
        let alarms = watched["alarms"].as_array().unwrap();
        let a = alarms
            .iter()
            .find(|a| a["channel"] == "camera")
            .unwrap_or_else(|| panic!("no camera alarm: {alarms:?}"));
        (
            a["time_s"].as_f64().unwrap(),
            a["change_s"].as_f64().unwrap(),
        )
    };
    let live = read_json(&d.join("live/monitor/monitor.json"));
    let (raised, began) = camera(&live);
    eprintln!("live: knocked at {knock_s:.2} s, camera alarm at {raised:.2} s, dated {began:.2} s");
    assert!(
        raised > knock_s && raised < knock_s + 8.0,
        "knocked at {knock_s:.2} s, alarm at {raised:.2} s"
    );
    assert!(said.contains("alarm: camera"), "{said}");
    assert!(
        printed.iter().any(|l| l.starts_with("alarm: camera")),
        "{printed:?}"
    );
    // The right camera's view of the still scene moved: the live monitor names it, and only it.
    let named = cameras_alarmed(&live);
    assert_eq!(named, ["right"], "{said}");
    // The frames the examiner skipped while the browser took the cores, counted: a left
    // frame's row needs the right camera's frames around it too, so either camera's count.
    let skipped: usize = (0..2)
        .map(|k| live["skipped"][k].as_u64().expect("skipped frames counted") as usize)
        .sum();

    // The same session triangulated and watched afterwards.
    let per_frame = ["--per-frame", "--out", "rows.csv"];
    handcap_ok(
        d,
        &[
            &["triangulate", "live/frames", "--calib", "lab/truth/rig.yml"][..],
            &per_frame[..],
        ]
        .concat(),
    );
    let offline = [
        "monitor",
        "rows.csv",
        "--model",
        "model.json",
        "--out",
        "off",
    ];
    handcap_ok(d, &[&offline[..], &settings[..]].concat());
    // Both after the knock and within seconds of it; the live one later when its examiner,
    // behind on a busy machine, skipped seconds of frames (and so of looks).
    let (raised_off, _) = camera(&read_json(&d.join("off/monitor.json")));
    eprintln!("live: the offline camera alarm at {raised_off:.2} s");
    assert!(
        raised_off > knock_s && raised_off < knock_s + 8.0 && raised >= raised_off - 2.0,
        "knocked at {knock_s:.2} s: live {raised:.2} s, offline {raised_off:.2} s"
    );
    // Each row keyed by its time in microseconds. A row's time is its left frame's on the
    // camera's clock, a line fitted to the frames' stamps: live over the seconds in view,
    // afterwards over the whole session, so the two differ by a fraction of a millisecond.
    // Its predictions, and the right camera's still scene where measured (NaN elsewhere).
    let rows = |path: &str| -> std::collections::BTreeMap<i64, [f64; 4]> {
        csv_rows(&d.join(path))
            .iter()
            .map(|r| {
                let t: f64 = r["time_s"].parse().unwrap();
                let p = ["x_mm", "y_mm", "z_mm"].map(|k| format!("predicted_{k}"));
                let p = [&p[0], &p[1], &p[2]].map(|k| r[k].parse().unwrap());
                let scene = r["scene_right_px"].parse().unwrap_or(f64::NAN);
                let p = [p[0], p[1], p[2], scene];
                ((t * 1e6).round() as i64, p)
            })
            .collect()
    };
    let (live_rows, offline_rows) = (rows("live/monitor/monitor.csv"), rows("off/monitor.csv"));
    // Each offline row's live row: the nearest in time, within a tenth of a frame (3.3 ms).
    let nearest = |t: i64| {
        let before = live_rows.range(..=t).next_back();
        let after = live_rows.range(t..).next();
        [before, after]
            .into_iter()
            .flatten()
            .min_by_key(|(s, _)| (**s - t).abs())
            .filter(|(s, _)| (**s - t).abs() <= 3_333)
    };
    let mut gaps_us: Vec<i64> = Vec::new();
    let mut scenes: Vec<[f64; 2]> = Vec::new();
    let mut apart: Vec<f64> = offline_rows
        .iter()
        .filter_map(|(t, q)| {
            let (s, p) = nearest(*t)?;
            gaps_us.push((s - t).abs());
            if !(p[3].is_nan() && q[3].is_nan()) {
                scenes.push([p[3], q[3]]);
            }
            Some((0..3).map(|k| (p[k] - q[k]).abs()).fold(0.0, f64::max))
        })
        .collect();
    assert!(!apart.is_empty(), "no offline row has a live row");
    apart.sort_by(f64::total_cmp);
    gaps_us.sort_unstable();
    eprintln!(
        "live: {} rows, {} offline, {} matched within 3.3 ms (times apart {} us median, {} us at most); predictions apart {:.4} mm median",
        live_rows.len(),
        offline_rows.len(),
        apart.len(),
        gaps_us[gaps_us.len() / 2],
        gaps_us[gaps_us.len() - 1],
        apart[apart.len() / 2]
    );
    // Every offline row has its live row, but for the frames the examiner skipped on a busy
    // machine: 468 of 468 and 467 of 467 in two runs, 0.8 ms apart at most. (Keyed by time
    // rounded to 10 ms, as this test was before, 0, 66, 70 and 73 rows in four runs fell either
    // side of a rounding: no row was lost.) A skipped right frame can cost a left row or two,
    // hence the margin.
    assert!(
        apart.len() + skipped >= offline_rows.len() * 95 / 100,
        "{} of {} ({skipped} skipped)",
        apart.len(),
        offline_rows.len()
    );
    // The still scene on the same rows, measured in the same frames, live as afterwards (one
    // row in six; the offline file writes it to 0.001 px): 76 rows, every one equal. A frame
    // the examiner skipped has the next one measured stand in for it live.
    assert!(scenes.len() * 8 >= offline_rows.len(), "{scenes:?}");
    let equal = |[l, o]: &&[f64; 2]| (l - o).abs() <= 0.0006;
    let unequal = scenes.iter().filter(|s| !equal(s));
    assert!(unequal.count() <= skipped, "live, offline: {scenes:?}");
    // 0.004 mm on an idle machine; under a parallel test run the board's measurements reach
    // the live monitor later than its rows (it then takes the command itself): 0.036 mm, a
    // thirtieth of the band.
    assert!(
        apart[apart.len() / 2] < 0.05,
        "{:?}",
        &apart[apart.len() / 2..]
    );
}
