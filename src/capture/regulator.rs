//! The regulator: each protocol step's command run (timed out, stopped with the session),
//! logged with when it started and returned, then held; the log as `pressures.csv`.
//!
//! A command runs in its own process group: a terminal's Ctrl-C reaches handcap alone, which
//! gives a command still running [`STOP_GRACE_S`] to return (a regulator is not cut off
//! mid-message, and a step it was told is logged) and then kills the command's whole group.

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use super::{Clock, Ending, COMMAND_TIMEOUT_S};
use crate::session::pressures::Logged;
use crate::session::protocol;

/// How long a command still running when the session stops may take to return before it is
/// killed (s).
pub const STOP_GRACE_S: f64 = 1.0;

/// Runs the protocol: each step's command, logged, then held. Returns how it ended.
pub(super) fn drive(
    steps: &[protocol::Step],
    template: &str,
    clock: &Clock,
    log: &std::sync::Mutex<Vec<Commanded>>,
    stop: &AtomicBool,
) -> Option<Ending> {
    for step in steps {
        if stop.load(Ordering::SeqCst) {
            return None;
        }
        let command = protocol::command_for(template, step);
        let time_s = clock.now_s();
        let failed = match run_command(&command, stop, COMMAND_TIMEOUT_S) {
            Ok(CommandEnd::Done) => None,
            Ok(CommandEnd::Stopped) => return None,
            Ok(CommandEnd::Failed(why)) => Some(format!("`{command}` {why}")),
            Err(e) => Some(format!("`{command}` could not run: {e}")),
        };
        if let Some(message) = failed {
            return Some(Ending::CommandFailed {
                step: step.step,
                message,
            });
        }
        log.lock().expect("log").push(Commanded {
            time_s,
            end_s: clock.now_s(),
            step: step.clone(),
        });
        // Held, and let go as soon as the session stops.
        while clock.now_s() < time_s + step.hold_s && !stop.load(Ordering::SeqCst) {
            let left = time_s + step.hold_s - clock.now_s();
            std::thread::sleep(Duration::from_secs_f64(left.clamp(0.0, 0.05)));
        }
    }
    Some(Ending::ProtocolDone)
}

/// How a pressure command ended.
pub(super) enum CommandEnd {
    Done,
    /// The session stopped (Ctrl-C, a signal, a camera lost) and the command did not return
    /// in [`STOP_GRACE_S`] (it was killed) or returned failing.
    Stopped,
    /// Why it failed: its exit status and error output, or that it timed out.
    Failed(String),
}

/// Runs `command` with `sh -c` in its own process group, waiting at most `timeout_s`, and
/// [`STOP_GRACE_S`] more once the session stops.
pub(super) fn run_command(
    command: &str,
    stop: &AtomicBool,
    timeout_s: f64,
) -> std::io::Result<CommandEnd> {
    use std::os::unix::process::CommandExt;
    let mut child = std::process::Command::new("sh")
        .arg("-c")
        .arg(command)
        .process_group(0)
        .stdin(std::process::Stdio::null())
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()?;
    // The group: a command's own children (`sh -c 'python set.py'`) go with it.
    let group = -(child.id() as i32);
    let kill_group = || {
        // SAFETY: a signal to the process group this function created.
        unsafe {
            libc::kill(group, libc::SIGKILL);
        }
    };
    let start = Instant::now();
    let mut stopped_at = None;
    loop {
        if let Some(status) = child.try_wait()? {
            if status.success() {
                return Ok(CommandEnd::Done);
            }
            if stopped_at.is_some() {
                return Ok(CommandEnd::Stopped);
            }
            // Nothing it started holds its error output open.
            kill_group();
            let mut error = String::new();
            if let Some(mut stderr) = child.stderr.take() {
                use std::io::Read;
                let _ = stderr.read_to_string(&mut error);
            }
            return Ok(CommandEnd::Failed(format!(
                "exited with {status}: {}",
                error.trim()
            )));
        }
        if stopped_at.is_none() && stop.load(Ordering::SeqCst) {
            stopped_at = Some(Instant::now());
        }
        let graced = stopped_at.is_some_and(|t| t.elapsed().as_secs_f64() > STOP_GRACE_S);
        if graced || start.elapsed().as_secs_f64() > timeout_s {
            kill_group();
            let _ = child.wait();
            return Ok(if graced {
                CommandEnd::Stopped
            } else {
                CommandEnd::Failed(format!(
                    "did not finish in {timeout_s} s (killed): check that the regulator answers"
                ))
            });
        }
        std::thread::sleep(Duration::from_millis(5));
    }
}

/// A step the regulator was told: when its command started and when it returned.
#[derive(Clone, Debug)]
pub(super) struct Commanded {
    pub time_s: f64,
    pub end_s: f64,
    pub step: protocol::Step,
}

pub(super) fn pressures_csv(log: &[Commanded]) -> String {
    crate::session::pressures::pressures_csv(log.iter().map(|c| Logged {
        time_s: c.time_s,
        command_end_s: Some(c.end_s),
        pressures_kpa: c.step.pressures,
        step: c.step.step,
        phase: &c.step.phase,
    }))
}

#[cfg(test)]
mod tests {
    use super::{run_command, AtomicBool, CommandEnd};

    #[test]
    fn a_pressure_command_is_timed_out_or_stopped_and_its_error_said() {
        let running = AtomicBool::new(false);
        let said = |end: CommandEnd| match end {
            CommandEnd::Failed(why) => why,
            CommandEnd::Done => "done".into(),
            CommandEnd::Stopped => "stopped".into(),
        };
        assert_eq!(said(run_command("true", &running, 5.0).unwrap()), "done");
        let why = said(run_command("echo no >&2; exit 3", &running, 5.0).unwrap());
        assert_eq!(why, "exited with exit status: 3: no");
        let why = said(run_command("sleep 5", &running, 0.2).unwrap());
        assert!(why.starts_with("did not finish in 0.2 s (killed)"), "{why}");
        let stopping = AtomicBool::new(true);
        assert_eq!(
            said(run_command("sleep 5", &stopping, 5.0).unwrap()),
            "stopped"
        );
        // A command the session's end finds running may still return, and is done.
        let dir = tempfile::tempdir().unwrap();
        let told = dir.path().join("told");
        let command = format!("sleep 0.2; echo 1 > {}", told.display());
        assert_eq!(said(run_command(&command, &stopping, 5.0).unwrap()), "done");
        assert!(told.is_file());
        // A command killed takes what it started with it.
        let late = dir.path().join("late");
        let command = format!("(sleep 1.5; echo 1 > {}) & wait", late.display());
        let why = said(run_command(&command, &running, 0.2).unwrap());
        assert!(why.starts_with("did not finish in 0.2 s (killed)"), "{why}");
        std::thread::sleep(std::time::Duration::from_secs(2));
        assert!(!late.exists(), "the command's child outlived it");
        // So does a command that fails, its error said.
        let command = format!(
            "(sleep 1.5; echo 1 > {}) & echo no >&2; exit 3",
            late.display()
        );
        let why = said(run_command(&command, &running, 5.0).unwrap());
        assert_eq!(why, "exited with exit status: 3: no");
        std::thread::sleep(std::time::Duration::from_secs(2));
        assert!(!late.exists(), "the failed command's child outlived it");
    }
}
