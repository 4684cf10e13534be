//! The `handcap` command. Exit codes: 0 success, 1 error (one line on stderr), 2 usage error
//! (clap's, and options or outputs that do not go together), 130 interrupted by Ctrl-C, SIGTERM
//! or SIGHUP (what was finished is kept).

mod cli;

use std::process::ExitCode;

use clap::Parser;

fn main() -> ExitCode {
    restore_sigpipe();
    quiet_ffmpeg();
    let args = match cli::Cli::try_parse() {
        Ok(args) => args,
        // clap's refusal on one line, as every handcap error: its message, without the usage
        // and the pointer to --help that follow it.
        Err(e) if e.use_stderr() => {
            let text = e.render().to_string();
            let message: Vec<&str> = text
                .lines()
                .take_while(|l| !l.trim().is_empty() && !l.starts_with("Usage:"))
                .map(str::trim)
                .collect();
            eprintln!(
                "handcap: {}; see --help",
                message.join(" ").trim_start_matches("error: ")
            );
            return ExitCode::from(2);
        }
        Err(e) => e.exit(),
    };
    match cli::run(args) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("handcap: {}", cli::one_line(&e));
            ExitCode::from(cli::exit_code(&e))
        }
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

/// Lets a closed pipe end the process quietly (`handcap triangulate … | head`), as other
/// command-line tools do, instead of the Rust default (ignore SIGPIPE, then panic on the write).
fn restore_sigpipe() {
    #[cfg(unix)]
    // SAFETY: called first thing in `main`, before any thread starts; SIG_DFL is a valid
    // disposition for SIGPIPE.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
}
