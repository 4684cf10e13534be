//! The regulator: each protocol step's command run (timed out, stopped with the session),
//! logged with when it started and returned, then held; the log as `pressures.csv`.

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use super::{Clock, Ending, COMMAND_TIMEOUT_S};
use crate::session::pressures::Logged;
use crate::session::protocol;

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
        let wait = time_s + step.hold_s - clock.now_s();
        if wait > 0.0 {
            std::thread::sleep(Duration::from_secs_f64(wait));
        }
    }
    Some(Ending::ProtocolDone)
}

/// How a pressure command ended.
pub(super) enum CommandEnd {
    Done,
    /// The session is stopping (Ctrl-C, a signal, a camera lost): the command was killed.
    Stopped,
    /// Why it failed: its exit status and error output, or that it timed out.
    Failed(String),
}

/// Runs `command` with `sh -c`, waiting at most `timeout_s` and no longer than the session
/// runs.
pub(super) fn run_command(
    command: &str,
    stop: &AtomicBool,
    timeout_s: f64,
) -> std::io::Result<CommandEnd> {
    let mut child = std::process::Command::new("sh")
        .arg("-c")
        .arg(command)
        .stdin(std::process::Stdio::null())
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::piped())
        .spawn()?;
    let start = Instant::now();
    loop {
        if let Some(status) = child.try_wait()? {
            if status.success() {
                return Ok(CommandEnd::Done);
            }
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
        let stopping = stop.load(Ordering::SeqCst);
        if stopping || start.elapsed().as_secs_f64() > timeout_s {
            let _ = child.kill();
            let _ = child.wait();
            return Ok(if stopping {
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
    }
}
