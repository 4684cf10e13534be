//! The `handcap` command. Exit codes: 0 success, 1 error (one line on stderr), 2 usage error
//! (clap's, and options or outputs that do not go together), 130 interrupted by Ctrl-C, SIGTERM
//! or SIGHUP (what was finished is kept).
//!
//! The modelling commands run in this binary, which is built from `handcap_model` alone and
//! links no OpenCV library (it starts in milliseconds, on a machine without OpenCV too); every
//! other command line (the camera commands, `--help`, `--version`) is handed to
//! `handcap-cameras` beside it, whose command line has them all. Without it, `--help` and
//! `--version` are this binary's own (the modelling commands), after a line saying why.

use handcap_model::cli;

/// This build's identity (`build.rs`): the `handcap-cameras` handed a command must share it.
const BUILD_ID: &str = env!("HANDCAP_BUILD_ID");

fn main() -> std::process::ExitCode {
    let light = || cli::main(|c: cli::Light| c.command.run());
    let first = std::env::args_os().nth(1);
    match &first {
        Some(first) if cli::is_light(first) => light(),
        _ => match hand_to_cameras() {
            Err(e) if asks_about_itself(first.as_deref()) => {
                eprintln!(
                    "handcap: {}; the modelling commands follow",
                    cli::one_line(&e)
                );
                light()
            }
            handed => cli::finish(handed),
        },
    }
}

/// Whether the command line asks for the help or the version, which need no camera.
fn asks_about_itself(first: Option<&std::ffi::OsStr>) -> bool {
    first
        .and_then(std::ffi::OsStr::to_str)
        .is_some_and(|a| matches!(a, "--help" | "-h" | "help" | "--version" | "-V"))
}

/// Replaces this process with `handcap-cameras` (the same directory, the same arguments): the
/// commands that call OpenCV are built into that binary only. It is told this build's identity
/// ([`handcap_model::BUILD_ID_VAR`]) and refuses to run for another build.
///
/// # Errors
/// When `handcap-cameras` cannot be started (not installed beside `handcap`), is `handcap`
/// itself (a link or a copy: it would hand the command to itself for ever), or is truncated.
fn hand_to_cameras() -> anyhow::Result<()> {
    let exe = std::env::current_exe()?;
    let cameras = exe.with_file_name(format!("handcap-cameras{}", std::env::consts::EXE_SUFFIX));
    let rebuild = "cargo build --release builds both; cargo install --path . installs both";
    if std::env::var_os(handcap_model::BUILD_ID_VAR).is_some() || same_file(&exe, &cameras) {
        anyhow::bail!(
            "{} is handcap itself (a link or a copy), not the camera binary: {rebuild}",
            cameras.display()
        );
    }
    if let Some(why) = truncated(&cameras) {
        anyhow::bail!("{} is {why}: {rebuild}", cameras.display());
    }
    let mut command = std::process::Command::new(&cameras);
    command
        .args(std::env::args_os().skip(1))
        .env(handcap_model::BUILD_ID_VAR, BUILD_ID);
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
        "cannot start {} ({error}): the camera commands are built into that binary, which installs beside handcap ({rebuild})",
        cameras.display()
    ))
}

/// Whether `a` and `b` are one file (a hard or symbolic link of the other).
#[cfg(unix)]
fn same_file(a: &std::path::Path, b: &std::path::Path) -> bool {
    use std::os::unix::fs::MetadataExt;
    match (std::fs::metadata(a), std::fs::metadata(b)) {
        (Ok(a), Ok(b)) => (a.dev(), a.ino()) == (b.dev(), b.ino()),
        _ => false,
    }
}

/// Whether `a` and `b` are one file (a symbolic link of the other).
#[cfg(not(unix))]
fn same_file(a: &std::path::Path, b: &std::path::Path) -> bool {
    matches!((std::fs::canonicalize(a), std::fs::canonicalize(b)), (Ok(a), Ok(b)) if a == b)
}

/// Why an ELF executable at `path` is cut short (its section headers, which linkers write last,
/// beyond its end), or `None` (complete, not ELF, or unreadable: exec says what is wrong then).
fn truncated(path: &std::path::Path) -> Option<String> {
    use std::io::Read;
    let mut header = [0u8; 64];
    let mut file = std::fs::File::open(path).ok()?;
    file.read_exact(&mut header).ok()?;
    // 64-bit little-endian ELF only (what handcap builds for on Linux).
    if header[..4] != *b"\x7fELF" || header[4] != 2 || header[5] != 1 {
        return None;
    }
    let u16_at = |i: usize| u64::from(u16::from_le_bytes([header[i], header[i + 1]]));
    let sections = u64::from_le_bytes(header[0x28..0x30].try_into().ok()?);
    let end = sections.checked_add(u16_at(0x3A) * u16_at(0x3C))?;
    let size = file.metadata().ok()?.len();
    (end > size).then(|| format!("cut short ({size} bytes of at least {end})"))
}
