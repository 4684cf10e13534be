//! Optimisers over named parameters: which candidate scores best on an objective.
//!
//! A search sees only an objective — a function scoring a batch of candidates, lower is better —
//! and a box of named axes ([`SearchSpace`]), and reports each iteration to an [`Observer`] (progress bars and history writers
//! live there). It knows nothing of MSVR or data: the bridge that scores candidates by fitting
//! MSVR is [`crate::select::tune`]. Every search takes a seed; the same seed gives the same
//! result.
//!
//! - [`aco_paper`]: the paper's digit-encoded ant colony (§2.3.2, Table 1), on its own box of
//!   MSVR's C, ε and σ.
//! - [`aco_r`]: continuous ACO_R (Socha & Dorigo 2008) on the logarithms of the box's axes.
//! - [`grid`]: a log-spaced grid, the baseline the paper says ACO beats.

pub mod aco_paper;
pub mod aco_r;
pub mod grid;

use std::sync::atomic::{AtomicBool, Ordering};

use serde::{Deserialize, Serialize};

/// Values by name, in order: a candidate ([`Point`]) or a box ([`SearchSpace`]). Serialized as
/// a JSON object, the names its keys in this order.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Named<V>(Vec<(String, V)>);

impl<V: Copy> Named<V> {
    /// These values with `name` set to `value`: replaced where the name is, else added last.
    #[must_use]
    pub fn with(mut self, name: &str, value: V) -> Self {
        match self.0.iter_mut().find(|(n, _)| n == name) {
            Some((_, v)) => *v = value,
            None => self.0.push((name.to_string(), value)),
        }
        self
    }

    /// The value of `name`, if it has one.
    pub fn get(&self, name: &str) -> Option<V> {
        self.0.iter().find(|(n, _)| n == name).map(|&(_, v)| v)
    }

    /// (name, value) in order.
    pub fn iter(&self) -> impl Iterator<Item = (&str, V)> {
        self.0.iter().map(|(n, v)| (n.as_str(), *v))
    }

    pub fn len(&self) -> usize {
        self.0.len()
    }

    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }
}

/// (name, value) pairs in order, a name given again replacing its value ([`Named::with`]).
impl<'a, V: Copy> FromIterator<(&'a str, V)> for Named<V> {
    fn from_iter<I: IntoIterator<Item = (&'a str, V)>>(pairs: I) -> Self {
        pairs
            .into_iter()
            .fold(Named(Vec::new()), |named, (name, value)| {
                named.with(name, value)
            })
    }
}

impl<V: Serialize> Serialize for Named<V> {
    fn serialize<S: serde::Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        use serde::ser::SerializeMap;
        let mut map = serializer.serialize_map(Some(self.0.len()))?;
        for (name, value) in &self.0 {
            map.serialize_entry(name, value)?;
        }
        map.end()
    }
}

impl<'de, V: Deserialize<'de>> Deserialize<'de> for Named<V> {
    fn deserialize<D: serde::Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        struct Entries<V>(std::marker::PhantomData<V>);
        impl<'de, V: Deserialize<'de>> serde::de::Visitor<'de> for Entries<V> {
            type Value = Named<V>;
            fn expecting(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
                f.write_str("an object of named values")
            }
            fn visit_map<A: serde::de::MapAccess<'de>>(
                self,
                mut map: A,
            ) -> Result<Named<V>, A::Error> {
                let mut entries: Vec<(String, V)> = Vec::new();
                while let Some((name, value)) = map.next_entry::<String, V>()? {
                    if entries.iter().any(|(n, _)| *n == name) {
                        return Err(serde::de::Error::custom(format!("{name} given twice")));
                    }
                    entries.push((name, value));
                }
                Ok(Named(entries))
            }
        }
        deserializer.deserialize_map(Entries(std::marker::PhantomData))
    }
}

/// A candidate: a value per axis of the box it was drawn from, by name.
pub type Point = Named<f64>;

impl std::fmt::Display for Point {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        for (i, (name, value)) in self.iter().enumerate() {
            write!(f, "{}{name} {value:.4}", if i > 0 { ", " } else { "" })?;
        }
        Ok(())
    }
}

/// The box [`aco_r`] and [`grid`] search: named axes, each a range (lo, hi) searched in
/// logarithms. The axes' order is the order of the searches' random draws, and the grid's
/// nesting, the last axis varying slowest: an objective whose work is shared between candidates
/// that agree on one axis (MSVR's kernel, one per σ) puts that axis last. A range with lo = hi
/// holds its axis at that value. The MSVR bridge derives its box from the data
/// ([`crate::select::tune::space_for`]).
pub type SearchSpace = Named<(f64, f64)>;

impl SearchSpace {
    /// At least one axis, each a range 0 < lo ≤ hi of finite numbers (the searches work in
    /// logarithms).
    ///
    /// # Errors
    /// [`SearchError::InvalidAxis`] naming the axis; [`SearchError::NoAxes`].
    pub fn check(&self) -> Result<(), SearchError> {
        if self.is_empty() {
            return Err(SearchError::NoAxes);
        }
        for (name, (lo, hi)) in self.iter() {
            if !(lo > 0.0 && lo <= hi && hi.is_finite()) {
                return Err(SearchError::InvalidAxis {
                    name: name.to_string(),
                    lo,
                    hi,
                });
            }
        }
        Ok(())
    }

    /// (ln lo, ln hi) per axis, in order.
    fn log_bounds(&self) -> Vec<(f64, f64)> {
        self.iter()
            .map(|(_, (lo, hi))| (lo.ln(), hi.ln()))
            .collect()
    }

    /// The point at logarithms `x` (one per axis, in order); an axis held at one value gives
    /// that value exactly (its logarithm's exponential may not).
    fn point_at_log(&self, x: &[f64]) -> Point {
        Named(
            self.0
                .iter()
                .zip(x)
                .map(|((name, (lo, hi)), v)| (name.clone(), if lo == hi { *lo } else { v.exp() }))
                .collect(),
        )
    }
}

/// What one iteration of a search did.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct IterationRecord {
    /// 1-based.
    pub iteration: usize,
    /// Fitness over this iteration's valid candidates.
    pub min: f64,
    pub mean: f64,
    pub max: f64,
    /// Valid candidates this iteration.
    pub valid: usize,
    pub best: Point,
    pub best_fitness: f64,
}

/// Receives each iteration as it ends, and the end of the search.
pub trait Observer {
    fn iteration(&mut self, record: &IterationRecord);
    /// The search ended (finished, stopped or failed).
    fn ended(&mut self) {}
}

/// An observer that does nothing.
impl Observer for () {
    fn iteration(&mut self, _: &IterationRecord) {}
}

/// Why a search stopped.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SearchStop {
    /// Every ant took the same path (the paper's convergence rule).
    SamePath,
    /// The iteration cap.
    MaxIterations,
    /// The evaluation budget.
    Budget,
    /// Interrupted (Ctrl-C): the best found so far.
    Interrupted,
}

/// The outcome of a search.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SearchResult {
    pub best: Point,
    pub best_fitness: f64,
    pub stop: SearchStop,
    pub history: Vec<IterationRecord>,
}

/// Errors of a search.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum SearchError {
    #[error("the search found no candidate with a finite fitness (interrupted too early, or every fit failed)")]
    NothingValid,
    #[error("{name} = {value}: {requirement}")]
    InvalidSetting {
        name: &'static str,
        value: f64,
        requirement: std::borrow::Cow<'static, str>,
    },
    #[error("the search range of {name} is [{lo}, {hi}]: it must be 0 < low ≤ high, finite")]
    InvalidAxis { name: String, lo: f64, hi: f64 },
    #[error("the search box has no axis: nothing to search")]
    NoAxes,
}

/// The error for a setting outside its range.
fn invalid<T>(
    name: &'static str,
    value: f64,
    requirement: impl Into<std::borrow::Cow<'static, str>>,
) -> Result<T, SearchError> {
    Err(SearchError::InvalidSetting {
        name,
        value,
        requirement: requirement.into(),
    })
}

/// What a search optimises: scores a batch of candidates, lower is better, +∞ for an invalid
/// candidate or a failed fit. The second argument is the search's bar: a candidate whose
/// fitness reaches it cannot change the search (it would not enter ACO_R's archive, nor beat
/// the grid's best), so the objective may stop scoring it early and return any value ≥ the bar
/// (racing). +∞ asks for every fitness in full.
pub type Objective<'a> = dyn Fn(&[Point], f64) -> Vec<f64> + Sync + 'a;

/// Keeps the best candidate and the history, and builds each iteration's record.
struct Tracker<'a> {
    best: Option<(Point, f64)>,
    history: Vec<IterationRecord>,
    observer: &'a mut dyn Observer,
    interrupt: &'a AtomicBool,
}

impl<'a> Tracker<'a> {
    fn new(observer: &'a mut dyn Observer, interrupt: &'a AtomicBool) -> Self {
        Tracker {
            best: None,
            history: Vec::new(),
            observer,
            interrupt,
        }
    }

    fn interrupted(&self) -> bool {
        self.interrupt.load(Ordering::Relaxed)
    }

    /// The best fitness so far (+∞ before any).
    fn best_fitness(&self) -> f64 {
        self.best.as_ref().map_or(f64::INFINITY, |(_, f)| *f)
    }

    /// Records one iteration's candidates and scores (+∞ marks an invalid candidate).
    fn record(&mut self, candidates: &[Point], scores: &[f64]) {
        let valid: Vec<f64> = scores.iter().copied().filter(|s| s.is_finite()).collect();
        for (p, &s) in candidates.iter().zip(scores) {
            if s.is_finite() && self.best.as_ref().is_none_or(|(_, b)| s < *b) {
                self.best = Some((p.clone(), s));
            }
        }
        let (best, best_fitness) = self
            .best
            .clone()
            .unwrap_or_else(|| (candidates[0].clone(), f64::INFINITY));
        let (min, max) = valid
            .iter()
            .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), &s| {
                (lo.min(s), hi.max(s))
            });
        let record = IterationRecord {
            iteration: self.history.len() + 1,
            min,
            mean: valid.iter().sum::<f64>() / valid.len() as f64,
            max,
            valid: valid.len(),
            best,
            best_fitness,
        };
        self.observer.iteration(&record);
        self.history.push(record);
    }

    fn finish(self, stop: SearchStop) -> Result<SearchResult, SearchError> {
        let (best, best_fitness) = self.best.ok_or(SearchError::NothingValid)?;
        Ok(SearchResult {
            best,
            best_fitness,
            stop,
            history: self.history,
        })
    }
}

/// A search method with its settings.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "method", rename_all = "kebab-case")]
pub enum Method {
    AcoPaper(aco_paper::AcoPaper),
    AcoR(aco_r::AcoR),
    Grid(grid::Grid),
}

impl std::fmt::Display for Method {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Method::AcoPaper(m) => write!(
                f,
                "the paper's ant colony ({} ants, ρ {}, τ0 {}, at most {} iterations, seed {})",
                m.ants, m.rho, m.tau0, m.max_iter, m.seed
            ),
            Method::AcoR(m) => write!(
                f,
                "ACO_R (archive {}, {} ants, q {}, ξ {}, budget {}, seed {})",
                m.archive, m.ants, m.q, m.xi, m.budget, m.seed
            ),
            Method::Grid(m) => write!(f, "a log-spaced grid of at most {} candidates", m.budget),
        }
    }
}

impl Method {
    /// The same method with another candidate budget (ACO_R and the grid; the paper's colony
    /// has none).
    #[must_use]
    pub fn with_budget(self, budget: usize) -> Method {
        match self {
            Method::AcoPaper(_) => self,
            Method::AcoR(m) => Method::AcoR(aco_r::AcoR { budget, ..m }),
            Method::Grid(m) => Method::Grid(grid::Grid { budget, ..m }),
        }
    }
}

/// An optimiser: runs on an objective inside a box and says why it stopped.
pub trait Search {
    /// The `--search` name.
    fn name(&self) -> &'static str;
    /// Iterations it runs at most in a box of `axes` axes (for a progress bar).
    fn iteration_cap(&self, axes: usize) -> usize;
    /// Whether it searches `space` (the paper's colony has its own digit box and ignores it).
    fn uses_space(&self) -> bool;
    /// Runs the search.
    ///
    /// # Errors
    /// [`SearchError::InvalidSetting`] for a bad setting; [`SearchError::NothingValid`] when no
    /// candidate scored a finite fitness.
    fn run(
        &self,
        space: &SearchSpace,
        objective: &Objective,
        observer: &mut dyn Observer,
        interrupt: &AtomicBool,
    ) -> Result<SearchResult, SearchError>;
}

impl Search for Method {
    fn name(&self) -> &'static str {
        match self {
            Method::AcoPaper(_) => "aco-paper",
            Method::AcoR(_) => "aco-r",
            Method::Grid(_) => "grid",
        }
    }

    fn iteration_cap(&self, axes: usize) -> usize {
        match self {
            Method::AcoPaper(m) => m.max_iter,
            Method::AcoR(m) => (m.budget.saturating_sub(m.archive)).div_ceil(m.ants.max(1)) + 1,
            Method::Grid(m) => m.points(axes).div_ceil(m.batch.max(1)),
        }
    }

    fn uses_space(&self) -> bool {
        !matches!(self, Method::AcoPaper(_))
    }

    fn run(
        &self,
        space: &SearchSpace,
        objective: &Objective,
        observer: &mut dyn Observer,
        interrupt: &AtomicBool,
    ) -> Result<SearchResult, SearchError> {
        let result = match self {
            Method::AcoPaper(m) => m.run(objective, observer, interrupt),
            Method::AcoR(m) => m.run(space, objective, observer, interrupt),
            Method::Grid(m) => m.run(space, objective, observer, interrupt),
        };
        observer.ended();
        result
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn named_values_are_a_json_object_in_their_order() {
        let p = Point::default()
            .with("sigma", 0.5)
            .with("c", 10.0)
            .with("sigma", 0.25);
        let json = serde_json::to_string(&p).unwrap();
        assert_eq!(json, r#"{"sigma":0.25,"c":10.0}"#);
        let back: Point = serde_json::from_str(&json).unwrap();
        assert_eq!(back, p);
        let space: SearchSpace =
            serde_json::from_str(r#"{"c":[0.1,10.0],"epsilon":[1e-4,0.5]}"#).unwrap();
        assert_eq!(space.get("epsilon"), Some((1e-4, 0.5)));
        let twice = serde_json::from_str::<Point>(r#"{"c":1.0,"c":2.0}"#).unwrap_err();
        assert!(twice.to_string().contains("c given twice"), "{twice}");
    }
}
