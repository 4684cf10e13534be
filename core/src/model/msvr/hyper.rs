//! MSVR's hyper-parameters (C, ε, σ), their rule, and their place in a search box: the axes
//! `c`, `epsilon` and `sigma` of [`crate::search::SearchSpace`].

use serde::{Deserialize, Serialize};

use crate::search::Point;

/// One candidate: penalty C, tube radius ε (output units), RBF width σ (scaled input units).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Hyper {
    pub c: f64,
    pub epsilon: f64,
    pub sigma: f64,
}

/// The paper's Table 2: the (C, ε, σ) its colony selected for the micro-hand (path
/// 326701690259), the parameters `handcap model --search none` uses by default.
pub const PAPER_TABLE2: Hyper = Hyper {
    c: 326.7,
    epsilon: 0.0169,
    sigma: 0.259,
};

/// A parameter outside its range: which one, its value and the rule.
#[derive(Clone, Copy, Debug, PartialEq, thiserror::Error)]
#[error("{name} = {value}: {requirement}")]
pub struct InvalidParam {
    pub name: &'static str,
    pub value: f64,
    pub requirement: &'static str,
}

impl Hyper {
    /// The names of (C, ε, σ) as a search's axes, in the order of its draws: σ last, the grid's
    /// slowest axis, so candidates that share a kernel are scored together.
    pub const AXES: [&'static str; 3] = ["c", "epsilon", "sigma"];

    /// The one rule for (C, ε, σ): C finite and > 0, ε finite and ≥ 0 (ε = 0 is kernel ridge
    /// regression), σ > 0 with 1/(2σ²) a finite number > 0.
    ///
    /// # Errors
    /// [`InvalidParam`] naming the first value that breaks it.
    pub fn check(&self) -> Result<(), InvalidParam> {
        let bad = |name, value, requirement| {
            Err(InvalidParam {
                name,
                value,
                requirement,
            })
        };
        if !(self.c > 0.0 && self.c.is_finite()) {
            return bad("C", self.c, "must be finite and > 0");
        }
        if !(self.epsilon >= 0.0 && self.epsilon.is_finite()) {
            return bad("epsilon", self.epsilon, "must be finite and ≥ 0");
        }
        if !(self.sigma >= 1e-150 && self.sigma <= 1e150) {
            return bad(
                "sigma",
                self.sigma,
                "must lie in [1e-150, 1e150] (the kernel's 1/(2σ²) must be a finite number > 0)",
            );
        }
        Ok(())
    }

    /// The (C, ε, σ) a search's candidate names; a value it lacks is NaN, which
    /// [`Hyper::check`] refuses.
    pub fn from_point(p: &Point) -> Hyper {
        let [c, epsilon, sigma] = Hyper::AXES.map(|name| p.get(name).unwrap_or(f64::NAN));
        Hyper { c, epsilon, sigma }
    }

    /// These values with those the point names in their place (a search whose box leaves an
    /// axis out holds it at this value).
    pub fn at(self, p: &Point) -> Hyper {
        Hyper {
            c: p.get("c").unwrap_or(self.c),
            epsilon: p.get("epsilon").unwrap_or(self.epsilon),
            sigma: p.get("sigma").unwrap_or(self.sigma),
        }
    }
}
