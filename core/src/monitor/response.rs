//! The finger's response test ([module docs](super)): each look's scale of the errors on the
//! prediction's displacement from rest, through a two-sided CUSUM.

use super::{Settings, RESPONSE_SHIFT};

/// The finger's response against the model's, a look at a time ([module docs](super)).
#[derive(Clone, Debug)]
pub(super) struct Response {
    /// The model's outputs at rest, and the least mean squared displacement from it a look
    /// needs (r₀²).
    rest: Vec<f64>,
    least: f64,
    /// The look's sums: Σ e·d, Σ |d|², its rows; and when the next begins.
    sums: (f64, f64, usize),
    next_look: f64,
    baseline: Vec<f64>,
    reference: Option<f64>,
    /// The statistics up and down, and when each was last 0 (s; from the first look after the
    /// baseline).
    stat: [f64; 2],
    zero_s: [f64; 2],
    threshold: f64,
}

impl Response {
    pub(super) fn new(rest: Vec<f64>, radius: f64, settings: &Settings) -> Response {
        Response {
            rest,
            least: radius * radius,
            sums: (0.0, 0.0, 0),
            next_look: f64::NEG_INFINITY,
            baseline: Vec::new(),
            reference: None,
            stat: [0.0; 2],
            zero_s: [f64::NEG_INFINITY; 2],
            threshold: settings.response_threshold(),
        }
    }

    /// The larger statistic now.
    pub(super) fn stat(&self) -> f64 {
        self.stat[0].max(self.stat[1])
    }

    /// Takes a row's `predicted` and `measured` outputs at `t`; on an alarm, when the change
    /// began and whether the finger moves further than modelled.
    pub(super) fn take(
        &mut self,
        t: f64,
        predicted: &[f64],
        measured: &[f64],
        baseline_end: f64,
        look_s: f64,
    ) -> Option<(f64, bool)> {
        let mut fired = None;
        if t >= self.next_look {
            let (num, den, rows) = std::mem::take(&mut self.sums);
            if rows > 0 && den > rows as f64 * self.least {
                fired = self.look(t, num / den, baseline_end);
            }
            self.next_look = t + look_s;
        }
        let (mut num, mut den) = (0.0, 0.0);
        for ((p, m), r) in predicted.iter().zip(measured).zip(&self.rest) {
            num += (m - p) * (p - r);
            den += (p - r) * (p - r);
        }
        self.sums = (self.sums.0 + num, self.sums.1 + den, self.sums.2 + 1);
        fired
    }

    /// A look's scale `s`, closed at `t`.
    fn look(&mut self, t: f64, s: f64, baseline_end: f64) -> Option<(f64, bool)> {
        if t < baseline_end {
            self.baseline.push(s);
            return None;
        }
        let reference = match self.reference {
            Some(reference) => reference,
            None => {
                // The first look after the baseline: a change is dated no earlier.
                let median = crate::stats::quantiles(&mut self.baseline, [0.5]);
                self.zero_s = [t; 2];
                *self.reference.insert(median.map_or(0.0, |[m]| m))
            }
        };
        let d = s - reference;
        let k = RESPONSE_SHIFT / 2.0;
        for (side, step) in [d - k, -d - k].into_iter().enumerate() {
            self.stat[side] = (self.stat[side] + step).max(0.0);
            if self.stat[side] == 0.0 {
                self.zero_s[side] = t;
            }
        }
        let side = (0..2).find(|&i| self.stat[i] >= self.threshold)?;
        Some((self.zero_s[side], side == 0))
    }
}
