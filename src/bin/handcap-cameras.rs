//! Every `handcap` command, those that call OpenCV (capture, calibration, triangulation, the
//! virtual rig, the demo, boards) included: `handcap` hands these to this binary, so that the
//! modelling commands start without loading OpenCV. Run as `handcap`, never by name.

fn main() -> std::process::ExitCode {
    quiet_ffmpeg();
    handcap::cli::main(handcap::cli::run_cameras)
}

/// Keeps FFmpeg's own log lines (a corrupt JPEG, a stream's HTTP status) off stderr, where they
/// would bury handcap's one line; handcap says what failed. OpenCV reads this variable when it
/// first loads FFmpeg; one the user set is left as it is.
fn quiet_ffmpeg() {
    const LEVEL: &str = "OPENCV_FFMPEG_LOGLEVEL";
    if std::env::var_os(LEVEL).is_none() {
        // AV_LOG_QUIET. Set before any thread starts (nothing else reads the environment yet).
        std::env::set_var(LEVEL, "-8");
    }
}
