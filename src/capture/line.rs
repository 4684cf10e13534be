//! handcap's regulator line protocol: newline-terminated ASCII over a serial line (USB CDC
//! at any baud rate), one reply line for every request, keywords in any case, numbers in
//! plain decimal (`docs/regulator.md` is the firmware writer's copy).
//!
//! | host → board | board → host |
//! |---|---|
//! | `HELLO` | `HANDCAP 1 3`: protocol version 1, 3 channels |
//! | `SET p1 p2 p3` (kPa) | `P ms m1 m2 m3`: the board's clock (ms) and the pressures it measures then (kPa) |
//! | `READ` | `P ms m1 m2 m3` |
//! | `LED 1` / `LED 0` | `OK ms`: the LED in view of the cameras switched at the board's `ms` |
//! | `VENT` | `OK ms`: every channel to 0 kPa |
//! | anything else, or a pressure outside 0 to [`MAX_PRESSURE_KPA`] | `ERR why` (nothing changed) |
//!
//! The board vents by itself when no line has come for [`WATCHDOG_S`] since the first `SET`
//! (the link gone, the host dead): a host that holds a step sends `READ` at least every
//! [`KEEPALIVE_S`], which also logs the measured pressures while the step is held.

use std::fmt;

use crate::hand::MAX_PRESSURE_KPA;

/// The protocol's version, said by `HELLO`'s reply.
pub const VERSION: u32 = 1;
/// Silence after which the board vents (s).
pub const WATCHDOG_S: f64 = 1.0;
/// How often a host holding a step reads the pressures (s): well inside [`WATCHDOG_S`].
pub const KEEPALIVE_S: f64 = 0.1;
/// The longest line either side sends (bytes); a longer one is garbage.
pub const MAX_LINE_BYTES: usize = 256;

/// What the host asks.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Request {
    Hello,
    Set([f64; 3]),
    Read,
    Led(bool),
    Vent,
}

/// What the board answers.
#[derive(Clone, Debug, PartialEq)]
pub enum Reply {
    Hello { version: u32, channels: usize },
    Measured { ms: f64, kpa: [f64; 3] },
    Ok { ms: f64 },
    Err(String),
}

fn numbers(words: &[&str]) -> Option<Vec<f64>> {
    words
        .iter()
        .map(|w| w.parse::<f64>().ok().filter(|v| v.is_finite()))
        .collect()
}

impl Request {
    /// A request line (without its newline), or why it is not one.
    pub fn parse(line: &str) -> Result<Request, String> {
        let words: Vec<&str> = line.split_whitespace().collect();
        let Some((keyword, rest)) = words.split_first() else {
            return Err("an empty line".into());
        };
        let request = match (keyword.to_ascii_uppercase().as_str(), rest) {
            ("HELLO", []) => Request::Hello,
            ("READ", []) => Request::Read,
            ("VENT", []) => Request::Vent,
            ("LED", ["1"]) => Request::Led(true),
            ("LED", ["0"]) => Request::Led(false),
            ("SET", [_, _, _]) => {
                let p = numbers(rest).ok_or("SET takes three numbers (kPa)")?;
                if let Some(v) = p.iter().find(|v| !(0.0..=MAX_PRESSURE_KPA).contains(*v)) {
                    return Err(format!("{v} kPa is outside 0 to {MAX_PRESSURE_KPA} kPa"));
                }
                Request::Set([p[0], p[1], p[2]])
            }
            _ => return Err("not HELLO, SET p1 p2 p3, READ, LED 0|1 or VENT".into()),
        };
        Ok(request)
    }
}

impl fmt::Display for Request {
    fn fmt(&self, f: &mut fmt::Formatter) -> fmt::Result {
        match self {
            Request::Hello => write!(f, "HELLO"),
            Request::Set(p) => {
                let [a, b, c] = p.map(crate::data::format_number);
                write!(f, "SET {a} {b} {c}")
            }
            Request::Read => write!(f, "READ"),
            Request::Led(on) => write!(f, "LED {}", u8::from(*on)),
            Request::Vent => write!(f, "VENT"),
        }
    }
}

impl Reply {
    /// A reply line (without its newline), or why it is not one.
    pub fn parse(line: &str) -> Result<Reply, String> {
        let words: Vec<&str> = line.split_whitespace().collect();
        let bad = || {
            format!(
                "{:?} is not a reply of handcap's line protocol",
                short(line)
            )
        };
        let Some((keyword, rest)) = words.split_first() else {
            return Err(bad());
        };
        match (keyword.to_ascii_uppercase().as_str(), rest) {
            ("ERR", _) => Ok(Reply::Err(rest.join(" "))),
            ("HANDCAP", [v, c]) => match (v.parse(), c.parse()) {
                (Ok(version), Ok(channels)) => Ok(Reply::Hello { version, channels }),
                _ => Err(bad()),
            },
            ("P", [_, _, _, _]) => match numbers(rest) {
                Some(n) => Ok(Reply::Measured {
                    ms: n[0],
                    kpa: [n[1], n[2], n[3]],
                }),
                None => Err(bad()),
            },
            ("OK", [_]) => match numbers(rest) {
                Some(n) => Ok(Reply::Ok { ms: n[0] }),
                None => Err(bad()),
            },
            _ => Err(bad()),
        }
    }
}

impl fmt::Display for Reply {
    fn fmt(&self, f: &mut fmt::Formatter) -> fmt::Result {
        match self {
            Reply::Hello { version, channels } => write!(f, "HANDCAP {version} {channels}"),
            Reply::Measured { ms, kpa } => {
                write!(f, "P {ms:.3} {:.2} {:.2} {:.2}", kpa[0], kpa[1], kpa[2])
            }
            Reply::Ok { ms } => write!(f, "OK {ms:.3}"),
            Reply::Err(why) => write!(f, "ERR {why}"),
        }
    }
}

/// The first 60 characters of a line, for a message.
pub fn short(line: &str) -> String {
    line.trim().chars().take(60).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_message_reads_back_as_written() {
        for r in [
            Request::Hello,
            Request::Set([0.0, 125.5, 300.0]),
            Request::Read,
            Request::Led(true),
            Request::Led(false),
            Request::Vent,
        ] {
            assert_eq!(Request::parse(&r.to_string()), Ok(r));
        }
        for r in [
            Reply::Hello {
                version: 1,
                channels: 3,
            },
            Reply::Measured {
                ms: 1234.5,
                kpa: [0.0, 99.25, 300.0],
            },
            Reply::Ok { ms: 2.0 },
            Reply::Err("why".into()),
        ] {
            assert_eq!(Reply::parse(&r.to_string()), Ok(r));
        }
        assert_eq!(
            Request::parse(" set 1 2 3\r"),
            Ok(Request::Set([1.0, 2.0, 3.0]))
        );
    }

    #[test]
    fn a_bad_line_says_why() {
        let err = |l: &str| Request::parse(l).unwrap_err();
        assert!(err("SET 1 2 301").contains("301 kPa is outside 0 to 300"));
        assert!(err("SET 1 2 -1").contains("outside"));
        assert!(err("SET 1 2 nan").contains("three numbers"));
        assert!(err("SET 1 2").contains("not HELLO"));
        assert!(err("LED 2").contains("not HELLO"));
        assert_eq!(err(""), "an empty line");
        assert!(Reply::parse("P 1 2 3").is_err());
        assert!(Reply::parse("garbage").unwrap_err().contains("not a reply"));
    }
}
