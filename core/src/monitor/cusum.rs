//! The alarms' statistic ([module docs](super)): a Bernoulli CUSUM, and a channel watched
//! through one against its baseline.

/// A Bernoulli CUSUM ([module docs](super)).
#[derive(Clone, Debug)]
pub struct Cusum {
    on_miss: f64,
    on_hit: f64,
    threshold: f64,
    stat: f64,
    looks: usize,
    last_zero: usize,
    fired: bool,
}

impl Cusum {
    /// Misses at rate `p0` while nothing changed, watched for a rise to 5·`p0` (at most 0.9);
    /// an alarm at `threshold`.
    pub fn new(p0: f64, threshold: f64) -> Cusum {
        let p1 = (5.0 * p0).min(0.9);
        Cusum {
            on_miss: (p1 / p0).ln(),
            on_hit: ((1.0 - p1) / (1.0 - p0)).ln(),
            threshold,
            stat: 0.0,
            looks: 0,
            last_zero: 0,
            fired: false,
        }
    }

    /// The statistic now.
    pub fn stat(&self) -> f64 {
        self.stat
    }

    /// Takes one look; on the alarm (once), how many looks back the change began.
    pub fn look(&mut self, missed: bool) -> Option<usize> {
        self.looks += 1;
        self.stat = (self.stat + if missed { self.on_miss } else { self.on_hit }).max(0.0);
        if self.stat == 0.0 {
            self.last_zero = self.looks;
        }
        (!self.fired && self.stat >= self.threshold).then(|| {
            self.fired = true;
            self.looks - self.last_zero
        })
    }
}

/// How sure the reference is to lie at or above the baseline's quantile it stands for
/// ([`crate::stats::quantile_upper_bound`] over the baseline's looks).
const REFERENCE_CONFIDENCE: f64 = 0.95;

/// One channel watched as its values come: its values kept until the baseline ends, then a
/// look every `look_s` through a [`Cusum`] against the baseline's reference.
#[derive(Clone, Debug)]
pub(super) struct Watcher {
    /// The reference: an upper confidence bound of this quantile of the baseline, at least
    /// `floor` and at most `cap`.
    quantile: f64,
    floor: f64,
    cap: f64,
    /// The baseline's values, and those at its looks, until the reference is set.
    baseline: Vec<f64>,
    baseline_looks: Vec<f64>,
    /// Once the baseline ended: the reference (`None`: no finite one), and the baseline's
    /// median (+∞ when more than half its values were).
    pub(super) decided: Option<(Option<f64>, f64)>,
    pub(super) cusum: Cusum,
    next_look: f64,
    look_times: Vec<f64>,
    /// Whether a value came.
    pub(super) seen: bool,
}

impl Watcher {
    /// Misses expected at rate `p0` against the `quantile` of the baseline (at most `cap`).
    pub(super) fn new(quantile: f64, cap: f64, p0: f64, threshold: f64) -> Watcher {
        Watcher {
            quantile,
            floor: 0.0,
            cap,
            baseline: Vec::new(),
            baseline_looks: Vec::new(),
            decided: None,
            cusum: Cusum::new(p0, threshold),
            next_look: f64::NEG_INFINITY,
            look_times: Vec::new(),
            seen: false,
        }
    }

    /// The same watcher whose reference is at least `floor`: a change smaller than that does
    /// not matter however calm the baseline was.
    pub(super) fn at_least(mut self, floor: f64) -> Watcher {
        self.floor = floor;
        self
    }

    /// The baseline's reference and its median; decided once. The reference is the
    /// [`REFERENCE_CONFIDENCE`] upper bound of the baseline's `quantile` over its looks (a
    /// baseline that happened to be calmer than the session does not set a reference the rest
    /// misses more often than p₀). A baseline of too few looks for the bound (fewer than
    /// ⌈ln(1 − confidence) / ln q⌉: 29 for the 0.9 quantile, 59 for 0.95), or whose bound is +∞ (a
    /// camera's refused rows at its upper looks), gives the quantile of all its values. At least
    /// `floor`, at most `cap`; without values, `cap` when it is finite, else `floor` when it is
    /// set.
    pub(super) fn decide(&mut self) -> (Option<f64>, f64) {
        *self.decided.get_or_insert_with(|| {
            let q = crate::stats::quantiles(&mut self.baseline, [self.quantile, 0.5]);
            let bound = crate::stats::quantile_upper_bound(
                &mut self.baseline_looks,
                self.quantile,
                REFERENCE_CONFIDENCE,
            );
            let plain = q.map(|[q, _]| q);
            let reference = bound
                .filter(|b| b.is_finite())
                .or(plain)
                .map(|r| r.max(self.floor).min(self.cap))
                .or_else(|| {
                    [self.cap, self.floor]
                        .into_iter()
                        .find(|&r| r > 0.0 && r.is_finite())
                })
                .filter(|r| r.is_finite());
            self.baseline = Vec::new();
            self.baseline_looks = Vec::new();
            (reference, q.map_or(0.0, |[_, median]| median))
        })
    }

    /// Takes the value `v` at `t` (the baseline ending at `baseline_end`); on the alarm, when
    /// the change began.
    pub(super) fn take(&mut self, t: f64, v: f64, baseline_end: f64, look_s: f64) -> Option<f64> {
        self.seen = true;
        let look = t >= self.next_look;
        if look {
            self.next_look = t + look_s;
        }
        if t < baseline_end {
            self.baseline.push(v);
            if look {
                self.baseline_looks.push(v);
            }
            return None;
        }
        let reference = self.decide().0?;
        if !look {
            return None;
        }
        self.look_times.push(t);
        let back = self.cusum.look(v > reference)?;
        let n = self.look_times.len();
        Some(self.look_times[n - 1 - back.min(n - 1)])
    }
}
