//! The `handcap` command. Exit codes: 0 success, 1 error (one line on stderr), 2 usage error
//! (clap's, and options or outputs that do not go together), 130 interrupted by Ctrl-C, SIGTERM
//! or SIGHUP (what was finished is kept).
//!
//! The modelling commands run in this binary, which does not link OpenCV (it starts in
//! milliseconds); the others are handed to `handcap-cameras` beside it ([`handcap::cli::main`]).

fn main() -> std::process::ExitCode {
    handcap::cli::main(handcap::cli::hand_to_cameras)
}
