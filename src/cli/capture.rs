//! `handcap capture`: two cameras → `DIR/frames/` + `frames.csv` (and `pressures.csv` when a
//! protocol drives the regulator), the layout `triangulate` reads (`crate::capture`).

use std::path::{Path, PathBuf};

use indicatif::{ProgressBar, ProgressStyle};

use crate::capture::{self, CaptureOptions, Stats};
use crate::pipeline::capture as stage;
use crate::session::protocol;

/// The cameras, as `capture` and `follow` take them.
#[derive(clap::Args)]
pub struct Cameras {
    /// Left camera: a device index (0), a device path (/dev/video0), a video file, or a URL or
    /// GStreamer pipeline OpenCV opens
    #[arg(long)]
    left: Option<String>,
    /// Right camera, as --left
    #[arg(long)]
    right: Option<String>,
    /// More than a pair, instead of --left and --right: one camera, named (lower-case letters
    /// and digits: cam1, cam2, …) and its source as --left's; repeated for each, two or more.
    /// Their frames are `<name>_NNNNN.jpg` in frames.csv, as `triangulate` reads them with the
    /// calibration of the same names. --calib, --flash, --sync-led and --view are a pair's
    #[arg(long, value_name = "NAME=SOURCE")]
    camera: Vec<String>,
    /// Frame size and rate asked of the cameras
    #[arg(long, default_value_t = 1280)]
    width: u32,
    #[arg(long, default_value_t = 720)]
    height: u32,
    #[arg(long, default_value_t = 30.0)]
    fps: f64,
    /// A camera or stream silent this long has stopped, and ends the session (s; a slow
    /// network or a busy machine may need more)
    #[arg(long, default_value_t = crate::capture::STALL_S, value_parser = super::finite)]
    stall_s: f64,
}

impl Cameras {
    /// A session filming these cameras, nothing else asked yet.
    pub fn options(&self) -> anyhow::Result<CaptureOptions> {
        let sources = capture::Source::list(&self.left, &self.right, &self.camera);
        Ok(CaptureOptions {
            sources: sources.map_err(super::Usage)?,
            width: self.width,
            height: self.height,
            fps: self.fps,
            protocol: None,
            duration_s: None,
            stall_s: self.stall_s,
            calibration: None,
            on_abort: None,
            flash: None,
            sync_led: false,
            view: None,
        })
    }
}

/// `--regulator`'s value: a board on a serial line (`serial:PATH[@BAUD]`, speaking `dialect`
/// when given) or a process kept running.
pub fn regulator(text: &str, dialect: Option<&Path>) -> anyhow::Result<capture::Regulator> {
    let dialect = dialect.map(capture::dialect::Dialect::read).transpose();
    Ok(match (capture::serial::parse(text), dialect) {
        (_, Err(why)) | (Some(Err(why)), _) => super::usage!("{why}"),
        (Some(Ok((device, baud))), Ok(dialect)) => {
            capture::Regulator::Serial(device, baud, dialect)
        }
        (None, Ok(Some(_))) => {
            super::usage!("--dialect is a serial board's: give --regulator serial:PATH[@BAUD]")
        }
        (None, Ok(None)) => capture::Regulator::Streaming(text.to_string()),
    })
}

#[derive(clap::Args)]
pub struct Args {
    #[command(flatten)]
    cameras: Cameras,
    /// Session directory to create (frames/, frames.csv, pressures.csv, capture.json)
    #[arg(long)]
    out: PathBuf,
    /// Pressure protocol to drive (step,phase,P1_kpa,P2_kpa,P3_kpa,hold_s; `handcap protocol`
    /// writes the paper's, or a dynamic one); needs --set-pressure or --regulator
    #[arg(long)]
    protocol: Option<PathBuf>,
    /// A regulator process started once and kept running: each protocol row is one line
    /// `time_s P1_kpa P2_kpa P3_kpa` on its input, sent at the row's time (for dynamic
    /// protocols, tens of commands a second); a line it prints back in the same form is the
    /// pressure it measured at that time_s (echo the command's), logged beside the command in
    /// force then (P1_measured_kpa, …), however late it comes. If it exits, stops reading for
    /// 2 s or prints anything else (a pressure outside -20 to 330 kPa, a line over 1024 bytes),
    /// the session ends, everything kept. Or `serial:PATH[@BAUD]` (e.g.
    /// serial:/dev/ttyACM0@115200): a board on a serial line speaking handcap's line protocol
    /// (docs/regulator.md: SET, READ, LED, VENT), each row a SET at its time, the measured
    /// pressures read back and logged, the board told VENT however the session ends
    #[arg(long, requires = "protocol", conflicts_with = "set_pressure")]
    regulator: Option<String>,
    /// With --regulator serial:PATH: a board whose firmware is not handcap's line protocol,
    /// its commands and measurements as templates in a TOML file (docs/regulator.md)
    #[arg(long, requires = "regulator")]
    dialect: Option<PathBuf>,
    /// Command run at each step, {p1} {p2} {p3} (kPa) and {step} filled in, e.g.
    /// 'python3 regulator.py {p1} {p2} {p3}'; pressures above 300 kPa are refused first
    #[arg(long, requires = "protocol")]
    set_pressure: Option<String>,
    /// Command run once if the protocol's session ends early (Ctrl-C, a signal, a camera lost,
    /// a failing command), e.g. 'python3 regulator.py 0 0 0' to vent the muscles; its result
    /// goes to capture.json
    #[arg(long, requires = "protocol")]
    on_abort: Option<String>,
    /// Command that switches on a light both cameras see (an LED, a lamp on a relay) and
    /// returns once it is on, e.g. 'gpioset gpiochip0 17=1'; run 1 s into the session, before
    /// the protocol: each camera's latency is measured from it, written to capture.json and
    /// used by triangulate
    #[arg(long, conflicts_with = "calib")]
    flash: Option<String>,
    /// With --regulator serial:PATH: blink the board's LED (in view of both cameras) at the
    /// session's start and end; each camera's delay is measured from the frames that saw it,
    /// to a millisecond or two (a frame lit for part of its exposure is part-bright), written to
    /// capture.json (sync_led) and used by triangulate instead of the motion
    #[arg(long, conflicts_with_all = ["calib", "flash"])]
    sync_led: bool,
    /// Serve a page to watch the session on (127.0.0.1, a random token in its URL, printed as
    /// `view URL`): each camera's latest frame and the bead in it, the pressures commanded and
    /// measured, the progress and flags; with --view-calib the tip's track live
    #[arg(long, conflicts_with = "camera")]
    view: bool,
    /// With --view: the port (default: any free one)
    #[arg(long, default_value_t = 0, requires = "view")]
    view_port: u16,
    /// With --view: a calibration (calibrate's calib.yml) to triangulate the tip's track with,
    /// frame by frame as triangulate --per-frame does, in the hand frame from the tip at rest
    #[arg(long, requires = "view")]
    view_calib: Option<PathBuf>,
    /// With --view-calib: a model (`handcap model`'s, with intervals, of triangulate's rows) to
    /// watch the tip against as it runs, as `handcap monitor` does: the error, the online band
    /// and the alarms on the page, each alarm said as it fires, and OUT/monitor/ at the end
    #[arg(long, requires = "view_calib")]
    model: Option<PathBuf>,
    #[command(flatten)]
    monitor: super::MonitorArgs,
    /// Stop after this many seconds (default: the protocol's end, or Ctrl-C)
    #[arg(long, value_parser = super::finite)]
    duration_s: Option<f64>,
    /// Board pairs for `calibrate` instead of the finger's frames: a pair is taken when the
    /// board is seen in both cameras (a chessboard whole, a ChArUco board at least in part),
    /// still, somewhere new (OUT/calib/left_NN.jpg, …)
    #[arg(long, conflicts_with_all = ["protocol", "set_pressure"])]
    calib: bool,
    /// With --calib: how many pairs
    #[arg(long, default_value_t = 20, requires = "calib")]
    pairs: usize,
    /// With --calib: one still pair of the board standing at the finger's base, as
    /// OUT/calib/left_ref, right_ref (run after the pairs)
    #[arg(long, requires = "calib")]
    reference: bool,
    /// With --calib: the board (default: calib/board.yml's)
    #[command(flatten)]
    board: super::board::BoardArgs,
}

pub fn run(a: Args) -> anyhow::Result<()> {
    let mut options = options(&a)?;
    if a.view {
        let model = a.model.as_deref().map(|m| {
            capture::view::Watching::read(m, a.monitor.settings()).map_err(|e| anyhow::anyhow!(e))
        });
        let view = capture::view::View::start(&capture::view::ViewOptions {
            port: a.view_port,
            calib: a.view_calib.clone(),
            model: model.transpose()?,
        })
        .map_err(|e| anyhow::anyhow!(e))?;
        println!("view {}", view.url());
        std::io::Write::flush(&mut std::io::stdout())?;
        options.view = Some(view);
    }
    if options.protocol.is_none() && a.duration_s.is_none() && !a.calib {
        println!("filming until Ctrl-C (no --protocol, no --duration-s); log the regulator on the clock capture.json describes");
    }
    let bar = ProgressBar::new_spinner()
        .with_style(ProgressStyle::with_template("{spinner} {elapsed} {msg}").expect("template"));
    let live = |s: &Stats| {
        bar.set_message(stage::live_line(s, &options));
        for line in options.view.iter().flat_map(|v| v.said()) {
            bar.suspend(|| eprintln!("{line}"));
        }
        bar.tick();
    };
    let summary = super::with_session(|session| stage::run(&a.out, &options, session, &live))?;
    bar.finish_and_clear();
    print!("{}", stage::Filmed::new(&summary, &a.out, &options));
    if let Some(result) = &summary.on_abort {
        eprintln!("ran --on-abort: {result}");
    }
    if let Some((trust, skipped)) = options.view.as_ref().and_then(|v| v.finish()) {
        let out = a.out.join("monitor");
        let watched =
            super::with_session(|s| trust.write(&out, &a.out, skipped, s.provenance(None)))?;
        println!("{watched}");
    }
    Ok(stage::ended(&summary, &a.out)?)
}

/// The session's settings from the flags: the protocol read with how the regulator is told it,
/// the calibration board.
fn options(a: &Args) -> anyhow::Result<CaptureOptions> {
    let protocol = match (&a.protocol, &a.set_pressure, &a.regulator) {
        (Some(path), Some(command), _) => Some((
            protocol::read(path)?,
            capture::Regulator::PerStep(command.clone()),
        )),
        (Some(path), None, Some(command)) => Some((
            protocol::read(path)?,
            regulator(command, a.dialect.as_deref())?,
        )),
        (Some(_), None, None) => {
            super::usage!("--protocol needs --set-pressure (a command per step) or --regulator (one process, a line per step)")
        }
        _ => None,
    };
    if a.board.any() && !a.calib {
        super::usage!("--board, --square-mm, --marker-mm and --dictionary describe the calibration board: add --calib");
    }
    let calibration = match a.board.flags().over(&crate::calib::file::default_board()) {
        Ok(board) => a.calib.then_some(capture::BoardPairs {
            board,
            pairs: a.pairs,
            reference: a.reference,
        }),
        Err(e) => super::usage!("{e}"),
    };
    Ok(CaptureOptions {
        protocol,
        duration_s: a.duration_s,
        calibration,
        on_abort: a.on_abort.clone(),
        flash: a.flash.clone(),
        sync_led: a.sync_led,
        ..a.cameras.options()?
    })
}
