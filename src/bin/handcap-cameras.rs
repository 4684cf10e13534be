//! Every `handcap` command, those that call OpenCV (capture, calibration, triangulation, the
//! virtual rig, the demo, boards) included: `handcap` hands these to this binary, so that the
//! modelling commands start without loading OpenCV. Run as `handcap`, never by name.

fn main() -> std::process::ExitCode {
    if let Err(e) = same_build() {
        eprintln!("handcap: {e}");
        return std::process::ExitCode::FAILURE;
    }
    quiet_ffmpeg();
    handcap::cli::main()
}

/// This binary and the `handcap` that handed it the command are of one build (the same
/// sources): `handcap` says its [`handcap::BUILD_ID`] in the environment. Taken out of the
/// environment, so that a `handcap` this process starts is not taken for a copy of itself.
fn same_build() -> Result<(), String> {
    let Some(given) = std::env::var_os(handcap::BUILD_ID_VAR) else {
        return Ok(());
    };
    // Before any thread starts (nothing else reads the environment yet).
    std::env::remove_var(handcap::BUILD_ID_VAR);
    match given.to_str() == Some(handcap::BUILD_ID) {
        true => Ok(()),
        false => Err(format!(
            "handcap-cameras ({}) is of another build than the handcap beside it ({}): rebuild both (cargo build --release, or cargo install --path .)",
            handcap::BUILD_ID,
            given.to_string_lossy()
        )),
    }
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
