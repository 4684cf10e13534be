//! The `handcap` command. Exit codes: 0 success, 1 error (one line on stderr), 2 usage error
//! (clap's, and options or outputs that do not go together), 130 interrupted by Ctrl-C, SIGTERM
//! or SIGHUP (what was finished is kept).
//!
//! The modelling commands run in this binary, which does not link OpenCV (it starts in
//! milliseconds); the others are handed to `handcap-cameras` beside it ([`handcap::cli::main`]).

use handcap::cli::Command;

fn main() -> std::process::ExitCode {
    handcap::cli::main(hand_to_cameras)
}

/// Replaces this process with `handcap-cameras` (the same directory, the same arguments): the
/// commands that call OpenCV are built into that binary only.
///
/// # Errors
/// When `handcap-cameras` cannot be started (not installed beside `handcap`).
fn hand_to_cameras(_: Command) -> anyhow::Result<()> {
    let exe = std::env::current_exe()?;
    let cameras = exe.with_file_name(format!("handcap-cameras{}", std::env::consts::EXE_SUFFIX));
    let mut command = std::process::Command::new(&cameras);
    command.args(std::env::args_os().skip(1));
    #[cfg(unix)]
    let error = {
        use std::os::unix::process::CommandExt;
        command.arg0("handcap").exec()
    };
    #[cfg(not(unix))]
    let error = match command.status() {
        Ok(status) => std::process::exit(status.code().unwrap_or(1)),
        Err(e) => e,
    };
    Err(anyhow::anyhow!(
        "cannot start {} ({error}): the camera commands are built into that binary, which installs beside handcap (cargo install --path . installs both)",
        cameras.display()
    ))
}
