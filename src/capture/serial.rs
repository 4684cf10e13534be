//! The regulator on a serial line (`--regulator serial:PATH[@BAUD]`): handcap speaks its line
//! protocol ([`super::line`]) to the board itself. The line is opened raw at the baud rate
//! given (115200 unless said; a USB CDC board ignores it) and held exclusively; the board must
//! answer `HELLO` as handcap's protocol. Each protocol step is `SET p1 p2 p3` at its time,
//! logged when written; while a step is held the pressures are read every
//! [`line::KEEPALIVE_S`] (the board's watchdog sees the host alive), and every `P` reply is
//! the measured pressure logged beside the command in force when it came. However the
//! session ends (its end, a signal, a camera lost, a full disk, the line gone) the board is
//! told `VENT` if it can still hear.

use std::fs::File;
use std::io::{BufRead, Read, Write};
use std::os::fd::AsRawFd;
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Mutex;
use std::time::Duration;

use super::dialect::Dialect;
use super::line::{self, Reply, Request};
use super::regulator::Commanded;
use super::sync_led::BLINKS;
use super::{Clock, Ending};
use crate::session::protocol;

/// When the LED first blinks (s into the session): the cameras' first second is its dark
/// reference.
const BLINK_AT_S: f64 = 1.0;

/// How long the board may take to answer a line (s) before the link is taken for gone.
const ANSWER_S: f64 = 2.0;

/// `serial:PATH[@BAUD]` → the path and the baud rate (115200 unless given); `None` when the
/// source is not a serial one.
pub fn parse(source: &str) -> Option<Result<(String, u32), String>> {
    let rest = source.strip_prefix("serial:")?;
    let (path, baud) = match rest.rsplit_once('@') {
        Some((path, baud)) => match baud.parse::<u32>() {
            Ok(b) if speed(b).is_some() => (path, b),
            _ => {
                return Some(Err(format!(
                    "--regulator {source}: baud rate {baud:?} is not one of {}",
                    BAUDS.map(|(b, _)| b.to_string()).join(", ")
                )))
            }
        },
        None => (rest, 115_200),
    };
    if path.is_empty() {
        return Some(Err(format!(
            "--regulator {source}: give the serial device, e.g. serial:/dev/ttyACM0@115200"
        )));
    }
    Some(Ok((path.to_string(), baud)))
}

const BAUDS: [(u32, libc::speed_t); 8] = [
    (9600, libc::B9600),
    (19200, libc::B19200),
    (38400, libc::B38400),
    (57600, libc::B57600),
    (115_200, libc::B115200),
    (230_400, libc::B230400),
    (460_800, libc::B460800),
    (921_600, libc::B921600),
];

fn speed(baud: u32) -> Option<libc::speed_t> {
    BAUDS.iter().find(|(b, _)| *b == baud).map(|&(_, s)| s)
}

/// The serial line, open, raw, exclusive, at `baud`.
fn open(path: &str, baud: u32) -> Result<File, String> {
    use std::os::unix::fs::OpenOptionsExt;
    let name = |why: String| format!("the regulator's serial line {path}: {why}");
    let file = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .custom_flags(libc::O_NOCTTY)
        .open(Path::new(path))
        .map_err(|e| name(e.to_string()))?;
    let fd = file.as_raw_fd();
    // SAFETY: flock, tcgetattr/cfmakeraw/cfset*speed/tcsetattr and TIOCEXCL on a descriptor
    // this function owns; termios is plain data tcgetattr fills.
    unsafe {
        if libc::flock(fd, libc::LOCK_EX | libc::LOCK_NB) != 0 {
            return Err(name(
                "busy (another program holds it: close it, or name another device)".into(),
            ));
        }
        let mut t: libc::termios = std::mem::zeroed();
        if libc::tcgetattr(fd, &mut t) != 0 {
            return Err(name(format!(
                "not a serial device ({})",
                std::io::Error::last_os_error()
            )));
        }
        libc::cfmakeraw(&mut t);
        let s = speed(baud).expect("checked by parse");
        libc::cfsetispeed(&mut t, s);
        libc::cfsetospeed(&mut t, s);
        t.c_cflag |= libc::CLOCAL | libc::CREAD;
        if libc::tcsetattr(fd, libc::TCSANOW, &t) != 0 {
            return Err(name(std::io::Error::last_os_error().to_string()));
        }
        libc::ioctl(fd, libc::TIOCEXCL);
        libc::tcflush(fd, libc::TCIOFLUSH);
    }
    Ok(file)
}

/// What the reader has heard: the time of the last reply, the board's `HELLO` answer, and
/// what ended the link if something did.
#[derive(Default)]
struct Heard {
    last_s: Mutex<Option<f64>>,
    hello: Mutex<Option<Reply>>,
    broken: Mutex<Option<String>>,
    /// Each request written and not yet answered: when it went (session clock, s) and whether
    /// it switched the LED. The board answers every line, in order.
    asked: Mutex<std::collections::VecDeque<(f64, bool)>>,
    /// The board's clock against the session's: each answer's round trip and the board's time
    /// less the round trip's middle (s).
    clocks: Mutex<Vec<(f64, f64)>>,
    /// The board's time of each LED switch (s, its clock).
    switched: Mutex<Vec<f64>>,
}

impl Heard {
    /// The board's clock less the session's (s): the median over the answers of the fastest
    /// fifth of round trips (the middle of a short one is when the board answered, to within
    /// half of it).
    fn board_offset(&self) -> Option<f64> {
        let mut samples = self.clocks.lock().expect("heard").clone();
        samples.sort_by(|a, b| a.0.total_cmp(&b.0));
        let fastest = &samples[..samples.len().div_ceil(5)];
        let mut offsets: Vec<f64> = fastest.iter().map(|s| s.1).collect();
        offsets.sort_by(f64::total_cmp);
        offsets.get(offsets.len() / 2).copied()
    }
}

/// The host's side of the line: what it says, and how it waits (reading meanwhile).
struct Host<'a> {
    link: File,
    path: &'a str,
    clock: &'a Clock,
    stop: &'a AtomicBool,
    heard: &'a Heard,
    /// Another firmware's commands, when the board does not speak handcap's protocol.
    dialect: Option<&'a Dialect>,
    /// The last `SET` line written: a dialect's keepalive when it has none of its own.
    last_set: Option<String>,
}

impl Host<'_> {
    fn say(&mut self, request: Request) -> Result<(), String> {
        let now = self.clock.now_s();
        let text = match self.dialect {
            None => {
                let led = matches!(request, Request::Led(_));
                (self.heard.asked.lock().expect("heard")).push_back((now, led));
                request.to_string()
            }
            Some(dialect) => match (dialect.line(request, 1e3 * now), request) {
                (Some(line), _) => line,
                (None, Request::Read) => match &self.last_set {
                    Some(set) => set.clone(),
                    None => return Ok(()),
                },
                (None, _) => return Ok(()),
            },
        };
        if let Request::Set(_) = request {
            self.last_set = Some(text.clone());
        }
        self.link
            .write_all(format!("{text}\n").as_bytes())
            .map_err(|e| format!("the serial line {} is gone ({e})", self.path))
    }

    fn stopped(&self) -> bool {
        self.stop.load(Ordering::SeqCst)
    }

    /// `HELLO`, and the board's answer as handcap's protocol; a dialect's `hello` line, its
    /// answer not awaited.
    fn hello(&mut self) -> Result<(), String> {
        if self.dialect.is_some() {
            return self.say(Request::Hello);
        }
        let (path, sent_s) = (self.path, self.clock.now_s());
        *self.heard.last_s.lock().expect("heard") = Some(sent_s);
        self.say(Request::Hello)?;
        loop {
            if let Some(why) = self.heard.broken.lock().expect("heard").clone() {
                return Err(why);
            }
            match self.heard.hello.lock().expect("heard").clone() {
                Some(Reply::Hello { version, .. }) if version == line::VERSION => return Ok(()),
                Some(other) => return Err(format!(
                    "the serial line {path} answered HELLO with {:?}, not handcap's line protocol {} (HANDCAP {} 3; docs/regulator.md)",
                    other.to_string(), line::VERSION, line::VERSION
                )),
                None => {}
            }
            if self.clock.now_s() - sent_s > ANSWER_S || self.stopped() {
                return Err(format!(
                    "the serial line {path} did not answer HELLO within {ANSWER_S} s: is the board handcap's line protocol (docs/regulator.md), at this baud rate?"
                ));
            }
            std::thread::sleep(Duration::from_millis(2));
        }
    }

    /// Waits until `due` (session clock, s), reading the pressures every
    /// [`line::KEEPALIVE_S`]: `Ok(false)` when the session stops first, `Err` when the link
    /// fails or the board falls silent.
    fn hold_until(&mut self, due: f64) -> Result<bool, String> {
        let mut read_s = self.clock.now_s();
        loop {
            if self.stopped() {
                return Ok(false);
            }
            if let Some(why) = self.heard.broken.lock().expect("heard").clone() {
                return Err(why);
            }
            let now = self.clock.now_s();
            let last = self.heard.last_s.lock().expect("heard").unwrap_or(now);
            if now - last > ANSWER_S {
                return Err(format!(
                    "the serial line {} has not answered for {ANSWER_S} s (the board is gone or hung)",
                    self.path
                ));
            }
            if now >= due {
                return Ok(true);
            }
            if now - read_s >= line::KEEPALIVE_S {
                read_s = now;
                self.say(Request::Read)?;
            }
            std::thread::sleep(Duration::from_secs_f64((due - now).min(0.002)));
        }
    }

    /// Blinks the board's LED through [`BLINKS`], each switch's time (when its line was
    /// written) kept in `led`, then holds it off a while (the last switch seen by the cameras
    /// before anything moves); `Ok(false)` when the session stops meanwhile.
    fn blink(&mut self, led: &Mutex<Vec<f64>>) -> Result<bool, String> {
        for (k, hold) in BLINKS.iter().enumerate() {
            let at = self.clock.now_s();
            self.say(Request::Led(k % 2 == 0))?;
            led.lock().expect("led").push(at);
            if !self.hold_until(at + hold)? {
                return Ok(false);
            }
        }
        self.hold_until(self.clock.now_s() + 0.3)
    }

    /// The protocol: the LED's first blinks (after a second of dark frames), each step a `SET`
    /// at its time, logged, the last held, the LED's last blinks.
    fn drive(
        &mut self,
        steps: &[protocol::Step],
        log: &Mutex<Vec<Commanded>>,
        led: Option<&Mutex<Vec<f64>>>,
    ) -> Result<bool, (usize, String)> {
        let at = |k: usize| move |why: String| (k, why);
        self.hello().map_err(at(0))?;
        if let Some(led) = led {
            if !(self.hold_until(BLINK_AT_S).map_err(at(0))? && self.blink(led).map_err(at(0))?) {
                return Ok(false);
            }
        }
        let mut due = self.clock.now_s();
        for (k, step) in steps.iter().enumerate() {
            if !self.hold_until(due).map_err(at(k.saturating_sub(1)))? {
                return Ok(false);
            }
            let time_s = self.clock.now_s();
            log.lock()
                .expect("log")
                .push(Commanded::streamed(time_s, due, step));
            if let Err(why) = self.say(Request::Set(step.pressures)) {
                log.lock().expect("log").pop();
                return Err((k, why));
            }
            if let Some(last) = log.lock().expect("log").last_mut() {
                last.end_s = self.clock.now_s();
            }
            due += step.hold_s;
        }
        let last = steps.len().saturating_sub(1);
        if !self.hold_until(due).map_err(at(last))? {
            return Ok(false);
        }
        match led {
            Some(led) => self.blink(led).map_err(at(last)),
            None => Ok(true),
        }
    }
}

/// Runs the protocol through the board on `path` (see the module docs), with `--sync-led` the
/// LED's switches kept in `led`; how it ended.
pub(super) fn drive_serial(
    steps: &[protocol::Step],
    (path, baud, dialect): (&str, u32, Option<&Dialect>),
    clock: &Clock,
    log: &Mutex<Vec<Commanded>>,
    stop: &AtomicBool,
    led: Option<&Mutex<Vec<f64>>>,
) -> Option<Ending> {
    let failed = |k: usize, message: String| {
        Some(Ending::CommandFailed {
            step: steps.get(k).map_or(0, |s| s.step),
            message,
        })
    };
    let link = match open(path, baud) {
        Ok(f) => f,
        Err(why) => return failed(0, why),
    };
    let reading = match link.try_clone() {
        Ok(f) => f,
        Err(e) => return failed(0, format!("the serial line {path}: {e}")),
    };
    let heard = Heard::default();
    let done = AtomicBool::new(false);
    std::thread::scope(|scope| {
        scope.spawn(|| listen(reading, (path, dialect), clock, log, &heard, &done));
        let mut host = Host {
            link,
            path,
            clock,
            stop,
            heard: &heard,
            dialect,
            last_set: None,
        };
        let ending = match host.drive(steps, log, led) {
            Ok(true) => Some(Ending::ProtocolDone),
            Ok(false) => None,
            Err((k, why)) => failed(k, why),
        };
        // Vented however it ended, while the board can still hear; what it measures after
        // is no step's.
        done.store(true, Ordering::SeqCst);
        let _ = host.say(Request::Vent);
        // Each switch when the board made it, on the session's clock, when it said so for
        // every one (else when its line was written).
        if let (Some(led), Some(offset)) = (led, heard.board_offset()) {
            let switched = heard.switched.lock().expect("heard");
            let mut written = led.lock().expect("led");
            if switched.len() == written.len() {
                *written = switched.iter().map(|b| b - offset).collect();
            }
        }
        ending
    })
}

/// Reads the board's replies until `done`: `P` replies go beside the command in force, the
/// first `ERR` or garbage breaks the link (said in `heard`).
fn listen(
    link: File,
    (path, dialect): (&str, Option<&Dialect>),
    clock: &Clock,
    log: &Mutex<Vec<Commanded>>,
    heard: &Heard,
    done: &AtomicBool,
) {
    let fd = link.as_raw_fd();
    let mut reader = std::io::BufReader::new(link);
    let mut bytes = Vec::new();
    let broken = |why: String| {
        heard.broken.lock().expect("heard").get_or_insert(why);
    };
    while !done.load(Ordering::SeqCst) {
        let mut poll = libc::pollfd {
            fd,
            events: libc::POLLIN,
            revents: 0,
        };
        // SAFETY: one pollfd, valid for the call.
        let ready = unsafe { libc::poll(&mut poll, 1, 20) };
        if ready <= 0 && reader.buffer().is_empty() {
            continue;
        }
        if poll.revents & (libc::POLLHUP | libc::POLLERR) != 0 && poll.revents & libc::POLLIN == 0 {
            broken(format!("the serial line {path} is gone (hung up)"));
            return;
        }
        bytes.clear();
        let limit = line::MAX_LINE_BYTES as u64 + 1;
        match (&mut reader).take(limit).read_until(b'\n', &mut bytes) {
            Ok(0) => {
                broken(format!("the serial line {path} is gone (end of file)"));
                return;
            }
            Err(e) => {
                broken(format!("the serial line {path} is gone ({e})"));
                return;
            }
            Ok(_) => {}
        }
        if bytes.len() > line::MAX_LINE_BYTES {
            broken(format!(
                "the serial line {path} sent a line longer than {} bytes (not handcap's line protocol)",
                line::MAX_LINE_BYTES
            ));
            return;
        }
        let text = String::from_utf8_lossy(&bytes);
        if text.trim().is_empty() {
            continue;
        }
        let now = clock.now_s();
        *heard.last_s.lock().expect("heard") = Some(now);
        // A dialect's lines: its measurements, or chatter.
        let reply = match dialect {
            Some(d) => match d.measured(&text) {
                Some((ms, kpa)) => Ok(Reply::Measured {
                    ms: ms.unwrap_or(f64::NAN),
                    kpa,
                }),
                None => continue,
            },
            None => Reply::parse(&text),
        };
        let asked = heard.asked.lock().expect("heard").pop_front();
        if let (Some((sent, led)), Ok(Reply::Measured { ms, .. } | Reply::Ok { ms })) =
            (asked, &reply)
        {
            let board_s = ms / 1e3;
            (heard.clocks.lock().expect("heard")).push((now - sent, board_s - (sent + now) / 2.0));
            if led {
                heard.switched.lock().expect("heard").push(board_s);
            }
        }
        match reply {
            Ok(hello @ Reply::Hello { .. }) => *heard.hello.lock().expect("heard") = Some(hello),
            Ok(Reply::Measured { kpa, .. }) => {
                if let Some(v) = kpa
                    .iter()
                    .find(|v| !super::regulator::MEASURED_KPA.contains(v))
                {
                    broken(format!(
                        "the serial line {path} said {:?}: {v} kPa is not a pressure a regulator measures",
                        line::short(&text)
                    ));
                    return;
                }
                let mut log = log.lock().expect("log");
                if let Some(c) = log.last_mut() {
                    c.measured = Some(kpa);
                }
            }
            Ok(Reply::Ok { .. }) => {}
            Ok(Reply::Err(why)) => {
                broken(format!("the board on {path} refused a command: {why}"));
                return;
            }
            Err(why) => {
                broken(format!(
                    "the serial line {path}: {why} (docs/regulator.md has the protocol)"
                ));
                return;
            }
        }
    }
}
