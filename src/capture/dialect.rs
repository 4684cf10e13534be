//! Another firmware's commands on the serial line (`--dialect FILE`): the lines handcap writes
//! for each request of its line protocol ([`super::line`]), and the form of the lines in which
//! the board says what it measured, as templates with `{fields}`:
//!
//! ```toml
//! # A board speaking `SET;<time>;<p1>;<p2>;<p3>` in psi, printing `<ms>,<p1>,<p2>,<p3>` as it measures.
//! unit = "psi"                        # kPa (default), psi or bar, both ways
//! set = "SET;{ms};{p1};{p2};{p3}"     # required: {p1} {p2} {p3} the pressures, {ms} the session's clock
//! vent = "SET;0;0;0;0"                # required: every channel to 0
//! measured = "{ms},{m1},{m2},{m3}"    # optional: {m1} {m2} {m3} measured, {ms} the board's clock, {_} ignored
//! keepalive = "READ"                  # optional: sent every 0.1 s while a step holds (default: the SET again)
//! hello = "ECHO;0"                    # optional: sent once before the first step
//! led_on = "LED;1"                    # optional, both or neither: --sync-led needs them
//! led_off = "LED;0"
//! ```
//!
//! A board's line that does not have the `measured` form is firmware chatter: it shows the
//! board alive and is otherwise left alone. Without `measured` nothing is read back, and the
//! board's silence cannot be told from its death: its own watchdog must vent.

use std::path::Path;

use serde::Deserialize;

/// Kilopascals per unit a dialect's pressures are in.
const UNITS: [(&str, f64); 3] = [("kPa", 1.0), ("psi", 6.894_757_293_168), ("bar", 100.0)];

/// A field of a template.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Field {
    /// A commanded pressure (channel 0-2).
    Set(usize),
    /// A measured pressure (channel 0-2).
    Measured(usize),
    /// A clock in ms: the session's in a command, the board's in a measurement.
    Ms,
    /// A number the board prints that handcap does not use.
    Ignored,
}

#[derive(Clone, Debug, PartialEq)]
enum Piece {
    Text(String),
    Field(Field),
}

/// A line with `{fields}`: written with values, or matched against a board's line.
#[derive(Clone, Debug, PartialEq)]
pub struct Template(Vec<Piece>);

impl Template {
    /// `text`'s pieces; `allowed` the fields it may hold.
    fn parse(key: &str, text: &str, allowed: &[&str]) -> Result<Template, String> {
        let mut pieces = Vec::new();
        let mut rest = text;
        while let Some(open) = rest.find('{') {
            let close = rest[open..]
                .find('}')
                .ok_or_else(|| format!("{key} = {text:?}: a {{ without its }}"))?
                + open;
            if open > 0 {
                pieces.push(Piece::Text(rest[..open].to_string()));
            }
            let name = &rest[open + 1..close];
            if !allowed.contains(&name) {
                return Err(format!(
                    "{key} = {text:?}: {{{name}}} is not one of its fields ({})",
                    allowed
                        .iter()
                        .map(|a| format!("{{{a}}}"))
                        .collect::<Vec<_>>()
                        .join(" ")
                ));
            }
            pieces.push(Piece::Field(match name {
                "p1" | "p2" | "p3" => Field::Set(usize::from(name.as_bytes()[1] - b'1')),
                "m1" | "m2" | "m3" => Field::Measured(usize::from(name.as_bytes()[1] - b'1')),
                "ms" => Field::Ms,
                _ => Field::Ignored,
            }));
            rest = &rest[close + 1..];
        }
        if !rest.is_empty() {
            pieces.push(Piece::Text(rest.to_string()));
        }
        if text.contains('\n') || text.trim().is_empty() {
            return Err(format!(
                "{key} = {text:?}: give one line with something on it"
            ));
        }
        Ok(Template(pieces))
    }

    fn has(&self, field: Field) -> bool {
        self.0.contains(&Piece::Field(field))
    }

    /// The line with the pressures `p` (in the dialect's unit) and the clock `ms` filled in.
    fn write(&self, p: [f64; 3], ms: f64) -> String {
        let number = |v: f64| format!("{}", (v * 1e3).round() / 1e3);
        self.0
            .iter()
            .map(|piece| match piece {
                Piece::Text(t) => t.clone(),
                Piece::Field(Field::Set(k)) => number(p[k.to_owned()]),
                Piece::Field(Field::Ms) => format!("{}", ms.round()),
                Piece::Field(_) => String::new(),
            })
            .collect()
    }

    /// The fields of `line` when it has this form: each field a number running to the next
    /// piece of text (or the line's end).
    fn read(&self, line: &str) -> Option<Vec<(Field, f64)>> {
        let mut rest = line.trim_end_matches(['\r', '\n']);
        let mut fields = Vec::new();
        for (k, piece) in self.0.iter().enumerate() {
            match piece {
                Piece::Text(t) => rest = rest.strip_prefix(t.as_str())?,
                Piece::Field(field) => {
                    let end = match self.0.get(k + 1) {
                        Some(Piece::Text(t)) => rest.find(t.as_str())?,
                        _ => rest.len(),
                    };
                    let value = rest[..end].trim().parse::<f64>().ok()?;
                    fields.push((*field, value));
                    rest = &rest[end..];
                }
            }
        }
        rest.trim().is_empty().then_some(fields)
    }
}

/// The file as written.
#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct File {
    unit: Option<String>,
    set: String,
    vent: String,
    measured: Option<String>,
    keepalive: Option<String>,
    hello: Option<String>,
    led_on: Option<String>,
    led_off: Option<String>,
}

/// A firmware's dialect (see the module docs).
#[derive(Clone, Debug, PartialEq)]
pub struct Dialect {
    /// kPa per unit of the dialect's pressures.
    kpa_per_unit: f64,
    set: Template,
    vent: Template,
    measured: Option<Template>,
    keepalive: Option<Template>,
    hello: Option<Template>,
    led: Option<[Template; 2]>,
}

impl Dialect {
    /// Reads a dialect file.
    ///
    /// # Errors
    /// One line naming the file and what is wrong in it.
    pub fn read(path: &Path) -> Result<Dialect, String> {
        let named =
            |why: String| format!("{}: {why}; docs/regulator.md has the form", path.display());
        let text = std::fs::read_to_string(path).map_err(|e| named(e.to_string()))?;
        let file: File = toml::from_str(&text).map_err(|e| named(e.message().to_string()))?;
        Dialect::of(file).map_err(named)
    }

    fn of(f: File) -> Result<Dialect, String> {
        let unit = f.unit.as_deref().unwrap_or("kPa");
        let kpa_per_unit = UNITS
            .iter()
            .find(|(name, _)| name.eq_ignore_ascii_case(unit))
            .map(|&(_, k)| k)
            .ok_or_else(|| format!("unit = {unit:?}: use kPa, psi or bar"))?;
        let command = ["ms"];
        let optional = |key: &str, text: &Option<String>, allowed: &[&str]| {
            text.as_deref()
                .map(|t| Template::parse(key, t, allowed))
                .transpose()
        };
        let set = Template::parse("set", &f.set, &["p1", "p2", "p3", "ms"])?;
        if let Some(k) = (0..3).find(|&k| !set.has(Field::Set(k))) {
            return Err(format!("set = {:?} has no {{p{}}}", f.set, k + 1));
        }
        let measured = optional("measured", &f.measured, &["m1", "m2", "m3", "ms", "_"])?;
        if let Some(m) = &measured {
            if let Some(k) = (0..3).find(|&k| !m.has(Field::Measured(k))) {
                return Err(format!("measured has no {{m{}}}", k + 1));
            }
        }
        let led = match (
            optional("led_on", &f.led_on, &command)?,
            optional("led_off", &f.led_off, &command)?,
        ) {
            (Some(on), Some(off)) => Some([off, on]),
            (None, None) => None,
            _ => return Err("give led_on and led_off both, or neither".into()),
        };
        Ok(Dialect {
            kpa_per_unit,
            set,
            vent: Template::parse("vent", &f.vent, &command)?,
            measured,
            keepalive: optional("keepalive", &f.keepalive, &command)?,
            hello: optional("hello", &f.hello, &command)?,
            led,
        })
    }

    /// Whether the dialect switches an LED (`--sync-led` needs it).
    pub fn has_led(&self) -> bool {
        self.led.is_some()
    }

    /// Whether the board says what it measured (and so whether its silence tells).
    pub fn reads_back(&self) -> bool {
        self.measured.is_some()
    }

    /// The line for `request` at `ms` on the session's clock; `None` for one the dialect has
    /// no line for (a `HELLO` without `hello`, a `READ` without `keepalive`: the host sends the
    /// step's `SET` again instead).
    pub fn line(&self, request: super::line::Request, ms: f64) -> Option<String> {
        use super::line::Request;
        let none = [0.0; 3];
        match request {
            Request::Hello => self.hello.as_ref().map(|t| t.write(none, ms)),
            Request::Set(p) => Some(self.set.write(p.map(|v| v / self.kpa_per_unit), ms)),
            Request::Read => self.keepalive.as_ref().map(|t| t.write(none, ms)),
            Request::Led(on) => self
                .led
                .as_ref()
                .map(|l| l[usize::from(on)].write(none, ms)),
            Request::Vent => Some(self.vent.write(none, ms)),
        }
    }

    /// A board's line in the `measured` form: the board's clock (ms, when it says it) and the
    /// pressures (kPa).
    pub fn measured(&self, line: &str) -> Option<(Option<f64>, [f64; 3])> {
        let fields = self.measured.as_ref()?.read(line)?;
        let mut kpa = [0.0; 3];
        let mut ms = None;
        for (field, v) in fields {
            match field {
                Field::Measured(k) => kpa[k] = v * self.kpa_per_unit,
                Field::Ms => ms = Some(v),
                _ => {}
            }
        }
        Some((ms, kpa))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::capture::line::Request;

    fn harvard() -> Dialect {
        Dialect::of(File {
            unit: Some("psi".into()),
            set: "SET;{ms};{p1};{p2};{p3}".into(),
            vent: "SET;0;0;0;0".into(),
            measured: Some("{ms},{_},{m1},{m2},{m3}".into()),
            keepalive: None,
            hello: Some("ECHO;0".into()),
            led_on: Some("LED;1".into()),
            led_off: Some("LED;0".into()),
        })
        .unwrap()
    }

    #[test]
    fn a_dialect_writes_its_commands_and_reads_its_measurements_in_its_unit() {
        let d = harvard();
        let psi = 6.894_757_293_168;
        assert_eq!(
            d.line(Request::Set([psi, 2.0 * psi, 0.0]), 1234.4).unwrap(),
            "SET;1234;1;2;0"
        );
        assert_eq!(d.line(Request::Vent, 5.0).unwrap(), "SET;0;0;0;0");
        assert_eq!(d.line(Request::Led(true), 5.0).unwrap(), "LED;1");
        assert_eq!(d.line(Request::Read, 5.0), None);
        let (ms, kpa) = d.measured("1500,9.9,1,2.5,-0.1\r\n").unwrap();
        assert_eq!(ms, Some(1500.0));
        for (got, want) in kpa.iter().zip([psi, 2.5 * psi, -0.1 * psi]) {
            assert!((got - want).abs() < 1e-9, "{kpa:?}");
        }
        // Chatter, a field that is no number, a line with more: not measurements.
        for line in [
            "ok",
            "1500,9.9,1,2.5",
            "1500,9.9,x,2.5,1",
            "1500,9.9,1,2.5,1,7",
        ] {
            assert_eq!(d.measured(line), None, "{line}");
        }
    }

    #[test]
    fn a_dialect_missing_a_pressure_or_naming_an_unknown_field_is_refused() {
        let file = |set: &str, led_on: Option<&str>| File {
            unit: None,
            set: set.into(),
            vent: "V".into(),
            measured: None,
            keepalive: None,
            hello: None,
            led_on: led_on.map(String::from),
            led_off: None,
        };
        let err = |f| Dialect::of(f).unwrap_err();
        assert!(err(file("S {p1} {p2}", None)).contains("no {p3}"));
        assert!(err(file("S {p1} {p2} {p4}", None)).contains("{p4} is not one of its fields"));
        assert!(err(file("S {p1} {p2} {p3", None)).contains("without its }"));
        assert!(err(file("S {p1} {p2} {p3}", Some("L1"))).contains("led_on and led_off both"));
    }
}
