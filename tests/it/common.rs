//! Helpers shared by the integration tests.

use handcap::synth::capture::Realism;
use handcap::synth::image_format::ImageFormat;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use handcap::data::{Columns, Dataset};

/// A fresh temporary directory, removed when dropped.
/// The machine, shared between tests that run in real time and tests that keep every core
/// busy: each of those runs alone among them (light tests run beside any of them).
static MACHINE: std::sync::Mutex<()> = std::sync::Mutex::new(());

/// Held by a test that runs in real time (a capture from paced videos or streams served by
/// the test itself, a signal at a moment): it runs beside light tests only, never beside
/// another real-time test or one that takes [`every_core`] (a starved real-time test misses
/// the frames and deadlines it asserts: two live sessions side by side on two busy cores saw
/// their virtual cameras stall).
pub fn real_time() -> std::sync::MutexGuard<'static, ()> {
    MACHINE
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
}

/// Held by a test that keeps every core busy for long (the demo end to end): it runs while no
/// [`real_time`] test does.
pub fn every_core() -> std::sync::MutexGuard<'static, ()> {
    MACHINE
        .lock()
        .unwrap_or_else(std::sync::PoisonError::into_inner)
}

pub fn tempdir() -> tempfile::TempDir {
    tempfile::tempdir().expect("temp dir")
}

/// Writes `text` to `dir/name` and returns the path.
pub fn write(dir: &Path, name: &str, text: &str) -> PathBuf {
    let path = dir.join(name);
    std::fs::write(&path, text).expect("write test file");
    path
}

/// Runs the `handcap` binary with `args` in `dir`.
pub fn handcap(dir: &Path, args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_handcap"))
        .args(args)
        .current_dir(dir)
        .output()
        .expect("run handcap")
}

/// Runs `handcap` in `dir` and sends it `signal` once its stdout has a line starting with
/// `ready` (at its end when none does): (its whole stdout, the process's end).
pub fn handcap_signalled(dir: &Path, args: &[&str], ready: &str, signal: i32) -> (String, Output) {
    use std::io::BufRead;
    let mut child = Command::new(env!("CARGO_BIN_EXE_handcap"))
        .args(args)
        .current_dir(dir)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("run handcap");
    let mut lines = std::io::BufReader::new(child.stdout.take().unwrap()).lines();
    let mut stdout = String::new();
    for line in lines.by_ref().map_while(Result::ok) {
        stdout += &line;
        stdout.push('\n');
        if line.starts_with(ready) {
            break;
        }
    }
    // SAFETY: a signal to our own child.
    unsafe {
        libc::kill(child.id() as i32, signal);
    }
    stdout.extend(lines.map_while(Result::ok).map(|l| l + "\n"));
    (stdout, child.wait_with_output().expect("handcap ends"))
}

/// Runs `handcap` and asserts it succeeded; returns stdout.
pub fn handcap_ok(dir: &Path, args: &[&str]) -> String {
    let out = handcap(dir, args);
    assert!(
        out.status.success(),
        "handcap {args:?} failed: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8(out.stdout).expect("utf-8 stdout")
}

/// Runs `handcap`, asserts exit code 1 and a one-line error; returns that line.
pub fn handcap_err(dir: &Path, args: &[&str]) -> String {
    handcap_fails(dir, args, 1)
}

/// Runs `handcap`, asserts exit code 2 (a usage error: flags, or outputs, that do not go
/// together) and a one-line error; returns that line.
pub fn handcap_usage(dir: &Path, args: &[&str]) -> String {
    handcap_fails(dir, args, 2)
}

/// Runs `handcap`, asserts exit code `code` and a one-line error; returns that line.
pub fn handcap_fails(dir: &Path, args: &[&str], code: i32) -> String {
    let out = handcap(dir, args);
    assert_eq!(
        out.status.code(),
        Some(code),
        "handcap {args:?} should fail with {code}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let stderr = String::from_utf8(out.stderr).expect("utf-8 stderr");
    assert_eq!(stderr.lines().count(), 1, "error is not one line: {stderr}");
    assert!(stderr.starts_with("handcap: "), "{stderr}");
    stderr.trim_end().to_string()
}

/// A dataset from row-major inputs and outputs with generated names.
pub fn dataset(d: usize, x: Vec<f64>, q: usize, y: Vec<f64>) -> Dataset {
    Dataset {
        source: "generated".into(),
        inputs: Columns::new((0..d).map(|j| format!("x{j}")).collect(), x),
        outputs: Columns::new((0..q).map(|j| format!("y{j}")).collect(), y),
        weights: None,
    }
}

/// A small deterministic pseudo-random stream in [0, 1) (no seed plumbing in tests).
pub struct Lcg(pub u64);

impl Lcg {
    pub fn next(&mut self) -> f64 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }

    pub fn vec(&mut self, n: usize) -> Vec<f64> {
        (0..n).map(|_| self.next()).collect()
    }
}

/// A small rendered capture of ideal frames (PNG, `handcap synth --clean`) in `dir`: `views`
/// board pairs + the reference, 14 pressure steps.
pub fn small_capture(dir: &Path, seed: u64, views: usize) {
    capture(dir, seed, views, 250.0, 125.0);
}

/// Renders only what calibrating needs, ideal PNG frames: `views` pairs of `board` and the
/// reference, with as few finger frames as a capture can have (one per step, 14 steps).
pub fn board_capture(dir: &Path, seed: u64, views: usize, board: handcap::calib::BoardSpec) {
    let synth = session(seed, [250.0, 125.0]);
    let config = handcap::synth::capture::CaptureConfig {
        views,
        board,
        window_s: [0.10, 0.12],
        format: handcap::synth::image_format::ImageFormat::Png,
        realism: handcap::synth::capture::Realism::CLEAN,
        ..handcap::synth::capture::CaptureConfig::default()
    };
    capture_with(dir, &synth, &config);
}

/// A rendered capture of ideal frames in `dir`: `views` board pairs + the reference, the
/// training grid and the two sweeps at the given pressure steps.
pub fn capture(dir: &Path, seed: u64, views: usize, grid_step_kpa: f64, sweep_step_kpa: f64) {
    let clean = (ImageFormat::Png, Realism::CLEAN);
    capture_as(dir, seed, views, [grid_step_kpa, sweep_step_kpa], clean);
}

/// [`capture`] with the frames' format and realism (`handcap synth`'s default: a webcam's MJPEG
/// in a lab).
pub fn capture_as(
    dir: &Path,
    seed: u64,
    views: usize,
    [grid_step_kpa, sweep_step_kpa]: [f64; 2],
    look: (ImageFormat, Realism),
) {
    let config = config_as(views, look);
    capture_with(
        dir,
        &session(seed, [grid_step_kpa, sweep_step_kpa]),
        &config,
    );
}

/// The capture settings of [`capture_as`].
pub fn config_as(
    views: usize,
    (format, realism): (ImageFormat, Realism),
) -> handcap::synth::capture::CaptureConfig {
    handcap::synth::capture::CaptureConfig {
        views,
        format,
        realism,
        ..handcap::synth::capture::CaptureConfig::default()
    }
}

/// The virtual session of `seed`: the training grid and both sweeps at the given steps (kPa).
pub fn session(
    seed: u64,
    [grid_step_kpa, sweep_step_kpa]: [f64; 2],
) -> handcap::synth::SynthConfig {
    handcap::synth::SynthConfig {
        seed,
        grid_step_kpa,
        sweep_step_kpa,
        ..handcap::synth::SynthConfig::default()
    }
}

/// The capture `synth` and `config` describe, whole, in `dir`: a copy of this test run's render
/// of that configuration, made on first use (renders are the slow part of most tests; tests
/// that share a configuration share one render).
pub fn capture_with(
    dir: &Path,
    synth: &handcap::synth::SynthConfig,
    config: &handcap::synth::capture::CaptureConfig,
) {
    use std::collections::HashMap;
    use std::sync::{Arc, Mutex, OnceLock};
    type Renders = Mutex<HashMap<String, Arc<OnceLock<PathBuf>>>>;
    static RENDERS: OnceLock<Renders> = OnceLock::new();
    let key = format!("{synth:?} {config:?}");
    let slot = RENDERS
        .get_or_init(Renders::default)
        .lock()
        .unwrap()
        .entry(key)
        .or_default()
        .clone();
    let rendered = slot.get_or_init(|| {
        static MADE: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
        let n = MADE.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
        let path = render_cache().join(format!("{n:03}"));
        render_capture(&path, synth, config);
        path
    });
    copy_tree(rendered, dir);
}

/// This test process's render cache (`target/tmp/renders/PID`); those of processes that have
/// ended are removed on first use.
fn render_cache() -> PathBuf {
    static CACHE: std::sync::OnceLock<PathBuf> = std::sync::OnceLock::new();
    CACHE
        .get_or_init(|| {
            let all = Path::new(env!("CARGO_TARGET_TMPDIR")).join("renders");
            for entry in std::fs::read_dir(&all).into_iter().flatten().flatten() {
                let pid = entry.file_name();
                if !Path::new("/proc").join(&pid).exists() {
                    let _ = std::fs::remove_dir_all(entry.path());
                }
            }
            let mine = all.join(std::process::id().to_string());
            std::fs::create_dir_all(&mine).unwrap();
            mine
        })
        .clone()
}

fn copy_tree(from: &Path, to: &Path) {
    std::fs::create_dir_all(to).unwrap();
    for entry in std::fs::read_dir(from).unwrap() {
        let entry = entry.unwrap();
        let target = to.join(entry.file_name());
        if entry.file_type().unwrap().is_dir() {
            copy_tree(&entry.path(), &target);
        } else {
            std::fs::copy(entry.path(), target).unwrap();
        }
    }
}

/// Renders the capture `synth` and `config` describe in `dir` afresh ([`capture_with`] copies
/// an earlier render of the same configuration).
pub fn render_capture(
    dir: &Path,
    synth: &handcap::synth::SynthConfig,
    config: &handcap::synth::capture::CaptureConfig,
) {
    let provenance = handcap::provenance::Provenance::new(vec!["test".into()], Some(synth.seed));
    let summary = handcap::synth::capture::write_capture(
        dir,
        synth,
        config,
        &provenance,
        &|_, _| {},
        &std::sync::atomic::AtomicBool::new(false),
    )
    .expect("capture");
    assert_eq!(summary.boards, config.views);
    assert!(!summary.interrupted);
}

/// A JSON file, parsed.
pub fn read_json(path: &Path) -> serde_json::Value {
    serde_json::from_slice(&std::fs::read(path).unwrap()).unwrap()
}

/// Of a model file's tried (or screened) entries, the one of lowest `fitness`.
pub fn lowest_fitness(entries: &serde_json::Value) -> &serde_json::Value {
    let fitness = |e: &serde_json::Value| e["fitness"].as_f64().unwrap();
    entries
        .as_array()
        .unwrap()
        .iter()
        .min_by(|a, b| fitness(a).total_cmp(&fitness(b)))
        .unwrap()
}

/// The cameras a monitor's alarms name (`monitor.json`), in the alarms' order.
pub fn cameras_alarmed(watched: &serde_json::Value) -> Vec<&str> {
    watched["alarms"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(|a| a["camera"].as_str())
        .collect()
}

/// The rows of a CSV file as maps from column name to cell.
pub fn csv_rows(path: &Path) -> Vec<std::collections::HashMap<String, String>> {
    let mut reader = csv::Reader::from_path(path).expect("readable CSV");
    let header = reader.headers().expect("header").clone();
    reader
        .records()
        .map(|r| {
            let r = r.expect("record");
            header
                .iter()
                .zip(r.iter())
                .map(|(h, v)| (h.to_string(), v.to_string()))
                .collect()
        })
        .collect()
}

/// The tips (`x_mm,y_mm,z_mm`) of a dataset or of `truth/tips.csv`, by their `step` column.
pub fn tips_by_step(path: &Path) -> std::collections::HashMap<String, [f64; 3]> {
    csv_rows(path)
        .into_iter()
        .map(|r| {
            let v = |k: &str| r[k].parse::<f64>().unwrap();
            (r["step"].clone(), [v("x_mm"), v("y_mm"), v("z_mm")])
        })
        .collect()
}

/// Each kept row's step and Euclidean distance (mm) from the truth's tip (`truth/tips.csv`),
/// matched by the `step` column; rows `keep` rejects are left out.
pub fn tip_errors_against_truth(
    dataset: &Path,
    truth: &Path,
    keep: impl Fn(&std::collections::HashMap<String, String>) -> bool,
) -> Vec<(String, f64)> {
    let truth = tips_by_step(truth);
    csv_rows(dataset)
        .iter()
        .filter(|r| keep(r))
        .map(|row| {
            let t = truth[&row["step"]];
            let v = |k: &str| row[k].parse::<f64>().unwrap();
            let error = ((v("x_mm") - t[0]).powi(2)
                + (v("y_mm") - t[1]).powi(2)
                + (v("z_mm") - t[2]).powi(2))
            .sqrt();
            (row["step"].clone(), error)
        })
        .collect()
}

/// RMS of [`tip_errors_against_truth`] (mm), and the rows.
pub fn tip_rms_against_truth(
    dataset: &Path,
    truth: &Path,
    keep: impl Fn(&std::collections::HashMap<String, String>) -> bool,
) -> (f64, usize) {
    let errors = tip_errors_against_truth(dataset, truth, keep);
    let sum: f64 = errors.iter().map(|(_, e)| e * e).sum();
    ((sum / errors.len() as f64).sqrt(), errors.len())
}

/// A stereo rig read back from OpenCV YAML by OpenCV's own FileStorage.
pub struct YamlRig {
    pub k1: opencv::core::Mat,
    pub d1: opencv::core::Mat,
    pub k2: opencv::core::Mat,
    pub d2: opencv::core::Mat,
    /// Left → right.
    pub r: nalgebra::Rotation3<f64>,
    pub t: nalgebra::Vector3<f64>,
    pub r_hand: Option<nalgebra::Rotation3<f64>>,
}

pub fn read_rig(path: &Path) -> YamlRig {
    use opencv::prelude::*;
    let fs = opencv::core::FileStorage::new(
        path.to_str().unwrap(),
        opencv::core::FileStorage_Mode::READ as i32,
        "",
    )
    .unwrap();
    assert!(
        fs.is_opened().unwrap(),
        "OpenCV cannot open {}",
        path.display()
    );
    let get = |key: &str| fs.get(key).unwrap().mat().unwrap();
    let values = |m: &opencv::core::Mat| -> Vec<f64> {
        (0..m.rows())
            .flat_map(|r| (0..m.cols()).map(move |c| (r, c)))
            .map(|(r, c)| *m.at_2d::<f64>(r, c).unwrap())
            .collect()
    };
    let rotation = |m: &opencv::core::Mat| {
        nalgebra::Rotation3::from_matrix_unchecked(nalgebra::Matrix3::from_row_slice(&values(m)))
    };
    let hand = get("R_hand");
    YamlRig {
        k1: get("K1"),
        d1: get("D1"),
        k2: get("K2"),
        d2: get("D2"),
        r: rotation(&get("R")),
        t: nalgebra::Vector3::from_row_slice(&values(&get("T"))),
        r_hand: (!hand.empty()).then(|| rotation(&hand)),
    }
}

/// The ChArUco board the tests render: 10 × 7 squares of 10 mm (the default chessboard's
/// 9 × 6 inner corners), 7.5 mm markers of the default dictionary.
pub fn charuco_board() -> handcap::calib::BoardSpec {
    handcap::calib::BoardSpec {
        cols: 9,
        rows: 6,
        square_mm: 10.0,
        pattern: handcap::calib::Pattern::Charuco(handcap::calib::Charuco {
            marker_mm: 7.5,
            dictionary: handcap::calib::Dictionary::DEFAULT,
        }),
    }
}

/// `board_capture(dir, 21, 10, board)` and its ten boards as two videos in `dir/vids`
/// (`left.avi`, `right.avi`, `frames.csv`, with `board.yml` and the reference pair beside them),
/// each board held still for `hold` frames (at 30 fps) and up to 12 more, as a hand holds it,
/// and then moved on; the right video starts `right_late` frames of the first board later (a
/// camera that far behind).
pub fn board_videos(dir: &Path, hold: usize, board: handcap::calib::BoardSpec, right_late: usize) {
    board_capture(dir, 21, 10, board);
    let vids = dir.join("vids");
    std::fs::create_dir(&vids).unwrap();
    let mut index = String::from("frame,camera,time_s\n");
    for (side, late) in [("left", 0), ("right", right_late)] {
        let path = vids.join(format!("{side}.avi"));
        let mut video = handcap::video::MjpegWriter::create(&path, 30.0, [1280, 720], 95).unwrap();
        let mut written = 0;
        for k in 0..10 {
            let image =
                handcap::image::decode(&dir.join(format!("calib/{side}_{k:02}.png"))).unwrap();
            let frames = hold + [0, 9, 3, 12, 6][k % 5] + if k == 0 { late } else { 0 };
            for _ in 0..frames {
                video.write(&image.data).unwrap();
            }
            written += frames;
        }
        video.finish().unwrap();
        for f in 0..written {
            index += &format!("{f},{side},{:.6}\n", f as f64 / 30.0);
        }
    }
    std::fs::write(vids.join("frames.csv"), index).unwrap();
    for file in ["board.yml", "left_ref.png", "right_ref.png"] {
        std::fs::copy(dir.join("calib").join(file), vids.join(file)).unwrap();
    }
}

/// What an in-test Motion-JPEG server sends next.
pub enum Part {
    Frame(Vec<u8>),
    /// Nothing for this number (a frame lost).
    Skip,
    /// The stream closes.
    End,
}

/// Serves an HTTP multipart Motion-JPEG stream, as IP cameras and mjpg-streamer do, on a free
/// port of 127.0.0.1 to one client: part n is what `next(n)` gives when it returns (it waits
/// as the camera would), until it says [`Part::End`] or the client goes. Returns the stream's
/// URL.
pub fn mjpeg_server(mut next: impl FnMut(usize) -> Part + Send + 'static) -> String {
    use std::io::{Read, Write};
    let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let url = format!("http://{}/stream", listener.local_addr().unwrap());
    std::thread::spawn(move || {
        let Ok((mut client, _)) = listener.accept() else {
            return;
        };
        let mut request = [0u8; 1024];
        let _ = client.read(&mut request);
        let head =
            "HTTP/1.0 200 OK\r\nContent-Type: multipart/x-mixed-replace; boundary=frame\r\n\r\n";
        if client.write_all(head.as_bytes()).is_err() {
            return;
        }
        for n in 0.. {
            let jpeg = match next(n) {
                Part::Frame(jpeg) => jpeg,
                Part::Skip => continue,
                Part::End => return,
            };
            let part = format!(
                "--frame\r\nContent-Type: image/jpeg\r\nContent-Length: {}\r\n\r\n",
                jpeg.len()
            );
            let sent = client
                .write_all(part.as_bytes())
                .and_then(|()| client.write_all(&jpeg))
                .and_then(|()| client.write_all(b"\r\n"));
            if sent.is_err() {
                return;
            }
        }
    });
    url
}
