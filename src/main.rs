//! The `handcap` command. Exit codes: 0 success, 1 error (one line on stderr), 2 usage error.

mod cli;

use std::process::ExitCode;

use clap::Parser;

fn main() -> ExitCode {
    let args = cli::Cli::parse();
    match cli::run(args) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("handcap: {e:#}");
            ExitCode::from(1)
        }
    }
}
