//! The regulator: each protocol step's command run (timed out, stopped with the session),
//! logged with when it started and returned, then held; or one regulator process kept running,
//! each step a line on its input at the step's time ([`drive_streaming`]); the log as
//! `pressures.csv`.
//!
//! A command runs in its own process group: a terminal's Ctrl-C reaches handcap alone, which
//! gives a command still running [`STOP_GRACE_S`] to return (a regulator is not cut off
//! mid-message, and a step it was told is logged) and then kills the command's whole group.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Mutex;
use std::time::{Duration, Instant};

use super::{Clock, Ending, COMMAND_TIMEOUT_S};
#[cfg(doc)]
use crate::hand::MAX_PRESSURE_KPA;
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
            scheduled_s: None,
            measured: None,
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
    let group = child.id();
    let kill_group = || kill_group(group);
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
    /// When a streamed command was due (s): `time_s` minus this is how late it went out.
    pub scheduled_s: Option<f64>,
    /// The last pressures a streaming regulator reported while this command was in force.
    pub measured: Option<[f64; 3]>,
    pub step: protocol::Step,
}

impl Commanded {
    /// The pressures a row in force under this command is given (kPa): what the regulator
    /// measured, where it did (as `triangulate` writes the rows), else the command.
    pub fn inputs(&self) -> [f64; 3] {
        self.measured.unwrap_or(self.step.pressures)
    }

    /// A streamed command written at `time_s`, due at `due_s`, not yet answered.
    pub fn streamed(time_s: f64, due_s: f64, step: &protocol::Step) -> Commanded {
        Commanded {
            time_s,
            end_s: time_s,
            scheduled_s: Some(due_s),
            measured: None,
            step: step.clone(),
        }
    }
}

pub(super) fn pressures_csv(log: &[Commanded]) -> String {
    let streamed = log.first().is_some_and(|c| c.scheduled_s.is_some());
    crate::session::pressures::pressures_csv(log.iter().map(|c| Logged {
        time_s: c.time_s,
        command_end_s: Some(c.end_s),
        hold_s: c.step.hold_s,
        pressures_kpa: c.step.pressures,
        step: c.step.step,
        phase: &c.step.phase,
        measured_kpa: streamed.then_some(c.measured),
    }))
}

/// How long a streaming regulator may leave its input unread before it has stalled (s).
pub const STREAM_STALL_S: f64 = 2.0;

/// The longest line a streaming regulator may print (bytes): a regulator that never ends its
/// line would otherwise grow handcap's memory without bound.
pub const MAX_LINE_BYTES: usize = 1024;

/// What a regulator can have measured (kPa): a gauge a little below 0 at rest, and at most a
/// tenth above the supply handcap ever commands ([`MAX_PRESSURE_KPA`]). Anything else is not a
/// pressure.
pub const MEASURED_KPA: std::ops::RangeInclusive<f64> = -20.0..=330.0;

/// The last bytes of a regulator's error output kept for its message.
const STDERR_TAIL_BYTES: usize = 2048;

/// Runs the protocol through one regulator process, `command` (`sh -c`, its own process
/// group): each step is the line `time_s P1_kpa P2_kpa P3_kpa` on its input, written when the
/// step is due (the protocol's holds added up from the session's start) and logged when it
/// was written; a line it prints back in the same form is the pressure it measured at
/// `time_s` (on the session's clock: the time of the command it answers, echoed, will do),
/// logged beside the command in force then, however late the line comes (a regulator whose
/// output is buffered). It ends the session, everything recorded kept, when it exits, leaves
/// its input unread for [`STREAM_STALL_S`], or prints anything else (a pressure outside
/// [`MEASURED_KPA`], a line longer than [`MAX_LINE_BYTES`]). What it says on its error output
/// is drained as it comes (a regulator that logs never fills the pipe), its end kept for the
/// message.
pub(super) fn drive_streaming(
    steps: &[protocol::Step],
    command: &str,
    clock: &Clock,
    log: &Mutex<Vec<Commanded>>,
    stop: &AtomicBool,
) -> Option<Ending> {
    let failed = |k: usize, message: String| {
        Some(Ending::CommandFailed {
            step: steps.get(k).map_or(0, |s| s.step),
            message,
        })
    };
    let said = Said::default();
    let (mut regulator, output, stderr) = match Streamed::spawn(command, &said) {
        Ok(started) => started,
        Err(why) => return failed(0, why),
    };
    // What it prints: measured pressures, or the first line that is not one.
    let garbage: Mutex<Option<String>> = Mutex::new(None);
    std::thread::scope(|scope| {
        scope.spawn(|| read_measured(output, command, log, &garbage));
        scope.spawn(|| said.drain(stderr));
        let mut told = || -> Option<Ending> {
            let mut due = 0.0;
            // When its input was last seen read to the end.
            let mut drained_s = clock.now_s();
            for (k, step) in steps.iter().enumerate() {
                // Due at its time; checked meanwhile for a stop, a death, garbage or a stall.
                loop {
                    if stop.load(Ordering::SeqCst) {
                        return None;
                    }
                    if let Some(why) = garbage.lock().expect("garbage").take() {
                        return failed(k.saturating_sub(1), why);
                    }
                    if let Some(why) = regulator.exited() {
                        return failed(k, why);
                    }
                    if unread(&regulator.input) == 0 {
                        drained_s = clock.now_s();
                    } else if clock.now_s() - drained_s > STREAM_STALL_S {
                        return failed(k.saturating_sub(1), regulator.stalled());
                    }
                    let left = due - clock.now_s();
                    if left <= 0.0 {
                        break;
                    }
                    std::thread::sleep(Duration::from_secs_f64(left.min(0.005)));
                }
                let [p1, p2, p3] = step.pressures.map(crate::data::format_number);
                let time_s = clock.now_s();
                // Logged before it is written: a regulator that answers at once must find the
                // command in force.
                log.lock()
                    .expect("log")
                    .push(Commanded::streamed(time_s, due, step));
                let written =
                    regulator.write(&format!("{time_s:.6} {p1} {p2} {p3}\n"), clock, stop);
                let mut logged = log.lock().expect("log");
                match written {
                    Ok(()) => {
                        if let Some(last) = logged.last_mut() {
                            last.end_s = clock.now_s();
                        }
                    }
                    Err(why) => {
                        logged.pop();
                        return why.and_then(|why| failed(k, why));
                    }
                }
                due += step.hold_s;
            }
            // The last step held for its time.
            while clock.now_s() < due && !stop.load(Ordering::SeqCst) {
                std::thread::sleep(Duration::from_secs_f64(
                    (due - clock.now_s()).clamp(0.0, 0.05),
                ));
            }
            Some(Ending::ProtocolDone)
        };
        let ending = told();
        regulator.close();
        ending
    })
}

/// What a streaming regulator says on its error output: the last [`STDERR_TAIL_BYTES`], and
/// whether it has ended.
#[derive(Default)]
struct Said {
    tail: Mutex<Vec<u8>>,
    ended: AtomicBool,
}

impl Said {
    /// Reads `stderr` to its end, keeping its tail.
    fn drain(&self, mut stderr: std::process::ChildStderr) {
        let mut buf = [0u8; 4096];
        while let Ok(n @ 1..) = std::io::Read::read(&mut stderr, &mut buf) {
            let mut tail = self.tail.lock().expect("tail");
            tail.extend_from_slice(&buf[..n]);
            let over = tail.len().saturating_sub(STDERR_TAIL_BYTES);
            tail.drain(..over);
        }
        self.ended.store(true, Ordering::SeqCst);
    }

    /// What was said, once the output has ended (or after half a second: what came by then).
    fn text(&self) -> String {
        let waited = Instant::now();
        while !self.ended.load(Ordering::SeqCst) && waited.elapsed().as_secs_f64() < 0.5 {
            std::thread::sleep(Duration::from_millis(5));
        }
        let tail = self.tail.lock().expect("tail");
        String::from_utf8_lossy(&tail).trim().to_string()
    }
}

/// The regulator process of [`drive_streaming`], its input written without blocking.
struct Streamed<'a> {
    command: &'a str,
    child: std::process::Child,
    input: std::process::ChildStdin,
    said: &'a Said,
}

impl<'a> Streamed<'a> {
    /// Starts `command` in its own process group, its input non-blocking; its output and error
    /// output are returned for their readers, the latter to drain into `said`.
    fn spawn(
        command: &'a str,
        said: &'a Said,
    ) -> Result<(Self, std::process::ChildStdout, std::process::ChildStderr), String> {
        use std::os::unix::process::CommandExt;
        use std::process::Stdio;
        let mut child = std::process::Command::new("sh")
            .arg("-c")
            .arg(command)
            .process_group(0)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::piped())
            .spawn()
            .map_err(|e| format!("`{command}` could not run: {e}"))?;
        let input = child.stdin.take().expect("piped");
        // SAFETY: the descriptor is the child's input, ours alone; non-blocking so that a
        // regulator that stops reading is seen, not waited on forever.
        unsafe {
            let fd = std::os::fd::AsRawFd::as_raw_fd(&input);
            let flags = libc::fcntl(fd, libc::F_GETFL);
            libc::fcntl(fd, libc::F_SETFL, flags | libc::O_NONBLOCK);
        }
        let output = child.stdout.take().expect("piped");
        let stderr = child.stderr.take().expect("piped");
        Ok((
            Streamed {
                command,
                child,
                input,
                said,
            },
            output,
            stderr,
        ))
    }

    /// Why it ended, once it has: its exit status and what it said on stderr. What it started
    /// goes with it (a child still holding its error output would keep that open for ever).
    fn exited(&mut self) -> Option<String> {
        let status = self.child.try_wait().ok().flatten()?;
        kill_group(self.child.id());
        Some(format!(
            "`{}` exited with {status}: {}",
            self.command,
            self.said.text()
        ))
    }

    fn stalled(&self) -> String {
        format!(
            "`{}` has not read its input for {STREAM_STALL_S} s (stalled)",
            self.command
        )
    }

    /// Writes `line` whole; `Err(None)` on the session's stop, `Err(Some(why))` when the
    /// regulator stalls or stops reading.
    fn write(
        &mut self,
        line: &str,
        clock: &Clock,
        stop: &AtomicBool,
    ) -> Result<(), Option<String>> {
        use std::io::Write;
        let started = clock.now_s();
        let bytes = line.as_bytes();
        let mut written = 0;
        while written < bytes.len() {
            match self.input.write(&bytes[written..]) {
                Ok(n) => written += n,
                Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {
                    if clock.now_s() - started > STREAM_STALL_S {
                        return Err(Some(self.stalled()));
                    }
                    if stop.load(Ordering::SeqCst) {
                        return Err(None);
                    }
                    std::thread::sleep(Duration::from_millis(1));
                }
                Err(e) => {
                    let why = self
                        .exited()
                        .unwrap_or_else(|| format!("`{}` stopped reading: {e}", self.command));
                    return Err(Some(why));
                }
            }
        }
        Ok(())
    }

    /// Its input closed (end of file), then a grace to exit, then its group killed: its output
    /// ends, and the reader with it.
    fn close(self) {
        let Streamed {
            mut child, input, ..
        } = self;
        drop(input);
        let waited = Instant::now();
        while child.try_wait().ok().flatten().is_none()
            && waited.elapsed().as_secs_f64() < STOP_GRACE_S
        {
            std::thread::sleep(Duration::from_millis(10));
        }
        kill_group(child.id());
        let _ = child.wait();
    }
}

/// Reads what the regulator prints: each measured pressure goes beside the command in force at
/// its time (none before the first); the first line that is not one is kept in `garbage`, and
/// reading stops.
fn read_measured(
    output: std::process::ChildStdout,
    command: &str,
    log: &Mutex<Vec<Commanded>>,
    garbage: &Mutex<Option<String>>,
) {
    use std::io::{BufRead, Read};
    let mut reader = std::io::BufReader::new(output);
    let mut bytes = Vec::new();
    for n in 1.. {
        bytes.clear();
        let limit = MAX_LINE_BYTES as u64 + 1;
        match (&mut reader).take(limit).read_until(b'\n', &mut bytes) {
            Ok(0) | Err(_) => break,
            Ok(_) => {}
        }
        let line = String::from_utf8_lossy(&bytes);
        if line.trim().is_empty() {
            continue;
        }
        let why = match parse_measured(&line) {
            _ if bytes.len() > MAX_LINE_BYTES => {
                Err(format!("a line longer than {MAX_LINE_BYTES} bytes"))
            }
            Some((t, p)) => match p.iter().find(|v| !MEASURED_KPA.contains(v)) {
                None => Ok((t, p)),
                Some(v) => Err(format!(
                    "{:?}: {v} kPa is not a pressure a regulator measures ({} to {} kPa)",
                    line.trim(),
                    MEASURED_KPA.start(),
                    MEASURED_KPA.end()
                )),
            },
            None => Err(format!(
                "{:?}, not `time_s P1_kpa P2_kpa P3_kpa` (a measured pressure)",
                line.trim().chars().take(80).collect::<String>()
            )),
        };
        let (t, p) = match why {
            Ok(measured) => measured,
            Err(why) => {
                *garbage.lock().expect("garbage") =
                    Some(format!("`{command}` printed line {n}: {why}"));
                break;
            }
        };
        // The command in force at `t` (its time as written: to the microsecond).
        let mut log = log.lock().expect("log");
        let in_force = log.partition_point(|c| c.time_s <= t + 1e-6);
        if let Some(c) = in_force.checked_sub(1).and_then(|k| log.get_mut(k)) {
            c.measured = Some(p);
        }
    }
}

/// Kills the process group led by `leader`, a child started with `process_group(0)`: the
/// command and whatever it started.
fn kill_group(leader: u32) {
    // SAFETY: a signal to a process group this module created.
    unsafe {
        libc::kill(-(leader as i32), libc::SIGKILL);
    }
}

/// The bytes written to a pipe and not yet read from it (Linux answers `FIONREAD` on either
/// end); 0 when it cannot tell.
fn unread(pipe: &std::process::ChildStdin) -> i32 {
    let mut n: libc::c_int = 0;
    // SAFETY: FIONREAD writes one int through the pointer, on a descriptor we own.
    let ok = unsafe {
        libc::ioctl(
            std::os::fd::AsRawFd::as_raw_fd(pipe),
            libc::FIONREAD,
            &mut n,
        )
    };
    if ok == 0 {
        n
    } else {
        0
    }
}

/// `time_s P1_kpa P2_kpa P3_kpa` (whitespace or commas between): the time and the three
/// pressures.
fn parse_measured(line: &str) -> Option<(f64, [f64; 3])> {
    let numbers: Vec<f64> = line
        .split(|c: char| c.is_whitespace() || c == ',')
        .filter(|t| !t.is_empty())
        .map(|t| t.parse::<f64>().ok().filter(|v| v.is_finite()))
        .collect::<Option<_>>()?;
    match numbers[..] {
        [t, p1, p2, p3] => Some((t, [p1, p2, p3])),
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::{run_command, AtomicBool, CommandEnd, MEASURED_KPA};

    #[test]
    fn the_measured_range_reaches_a_tenth_above_the_supply() {
        let told = 1.1 * crate::hand::MAX_PRESSURE_KPA;
        assert!((MEASURED_KPA.end() - told).abs() < 1e-9);
    }

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
