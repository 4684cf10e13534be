//! The lab's regulator board: a pseudo-terminal that speaks handcap's line protocol
//! ([`crate::capture::line`]) as a microcontroller on USB serial would: each `SET` reaches the
//! finger's muscles through the pneumatic line, `READ` answers what the line's gauges read, `LED`
//! switches the lamp both cameras see, and the firmware's watchdog vents when the host falls
//! silent.

use std::fs::File;
use std::io::{Read, Write};
use std::os::fd::{AsRawFd, FromRawFd};
use std::path::PathBuf;

use super::Shared;
use crate::capture::line::{self, Reply, Request};

/// One line the board received, as the truth keeps it.
#[derive(Clone, Debug)]
pub struct Received {
    /// When it came (lab clock, s).
    pub time_s: f64,
    /// The line as received, or `(watchdog)` for the firmware's own vent.
    pub line: String,
    pub reply: String,
}

/// The pseudo-terminal: its controller end (the board's side) and the path a host opens.
pub struct Pty {
    controller: File,
    /// The device end, held open so that the board reads on while hosts come and go.
    _device: File,
    pub path: PathBuf,
}

impl Pty {
    /// A new pseudo-terminal, its device end raw (no echo, no line editing: a serial port).
    pub fn open() -> std::io::Result<Pty> {
        let err = std::io::Error::last_os_error;
        // SAFETY: plain POSIX calls on a descriptor this function owns; ptsname_r writes a
        // NUL-terminated name into the buffer it is given.
        unsafe {
            let fd = libc::posix_openpt(libc::O_RDWR | libc::O_NOCTTY | libc::O_CLOEXEC);
            if fd < 0 {
                return Err(err());
            }
            let controller = File::from_raw_fd(fd);
            if libc::grantpt(fd) != 0 || libc::unlockpt(fd) != 0 {
                return Err(err());
            }
            let mut name = [0 as libc::c_char; 128];
            if libc::ptsname_r(fd, name.as_mut_ptr(), name.len()) != 0 {
                return Err(err());
            }
            let path = PathBuf::from(
                std::ffi::CStr::from_ptr(name.as_ptr())
                    .to_string_lossy()
                    .into_owned(),
            );
            let device = std::fs::OpenOptions::new()
                .read(true)
                .write(true)
                .custom_flags(libc::O_NOCTTY)
                .open(&path)?;
            raw(&device)?;
            Ok(Pty {
                controller,
                _device: device,
                path,
            })
        }
    }

    /// The board's end, for a firmware of another kind (a test's).
    pub fn board_end(&self) -> std::io::Result<File> {
        self.controller.try_clone()
    }
}

use std::os::unix::fs::OpenOptionsExt;

/// Sets a terminal raw (as `cfmakeraw`): bytes pass as they are, both ways.
pub fn raw(terminal: &File) -> std::io::Result<()> {
    // SAFETY: termios is plain data filled by tcgetattr on a descriptor we own.
    unsafe {
        let mut t: libc::termios = std::mem::zeroed();
        if libc::tcgetattr(terminal.as_raw_fd(), &mut t) != 0 {
            return Err(std::io::Error::last_os_error());
        }
        libc::cfmakeraw(&mut t);
        if libc::tcsetattr(terminal.as_raw_fd(), libc::TCSANOW, &t) != 0 {
            return Err(std::io::Error::last_os_error());
        }
    }
    Ok(())
}

/// Runs the board on `pty` until `stop`: reads lines, answers each, vents on silence.
pub fn run(pty: Pty, shared: &Shared) {
    let mut controller = pty.controller;
    let fd = controller.as_raw_fd();
    let mut pending: Vec<u8> = Vec::new();
    let mut last_line_s: Option<f64> = None;
    let mut buf = [0u8; 512];
    while !shared.stopped() {
        let mut poll = libc::pollfd {
            fd,
            events: libc::POLLIN,
            revents: 0,
        };
        // SAFETY: one pollfd, valid for the call.
        let ready = unsafe { libc::poll(&mut poll, 1, 20) };
        if ready > 0 && poll.revents & libc::POLLIN != 0 {
            let Ok(n @ 1..) = controller.read(&mut buf) else {
                continue;
            };
            pending.extend_from_slice(&buf[..n]);
            while let Some(end) = pending.iter().position(|&b| b == b'\n') {
                let bytes: Vec<u8> = pending.drain(..=end).collect();
                let text = String::from_utf8_lossy(&bytes).trim().to_string();
                let request = Request::parse(&text);
                let arms = matches!(request, Ok(Request::Set(_)));
                let reply = answer(&text, request, shared);
                if arms || last_line_s.is_some() {
                    last_line_s = Some(shared.now_s());
                }
                let _ = controller.write_all(format!("{reply}\n").as_bytes());
            }
            if pending.len() > line::MAX_LINE_BYTES {
                pending.clear();
                let _ = controller.write_all(b"ERR a line longer than 256 bytes\n");
            }
        }
        // The firmware's watchdog: silence after the first SET vents, once.
        if last_line_s.is_some_and(|t| shared.now_s() - t > line::WATCHDOG_S) {
            last_line_s = None;
            let ms = shared.vent();
            shared.received(Received {
                time_s: ms / 1e3,
                line: "(watchdog)".into(),
                reply: format!("vented after {} s of silence", line::WATCHDOG_S),
            });
        }
    }
}

/// The reply to one line, the line and reply kept in the truth.
fn answer(text: &str, request: Result<Request, String>, shared: &Shared) -> Reply {
    let reply = match request {
        Err(why) => Reply::Err(why),
        Ok(Request::Hello) => Reply::Hello {
            version: line::VERSION,
            channels: 3,
        },
        Ok(Request::Set(p)) => shared.set(p),
        Ok(Request::Read) => shared.read(),
        Ok(Request::Led(on)) => Reply::Ok { ms: shared.led(on) },
        Ok(Request::Vent) => Reply::Ok { ms: shared.vent() },
    };
    shared.received(Received {
        time_s: shared.now_s(),
        line: text.to_string(),
        reply: reply.to_string(),
    });
    reply
}
