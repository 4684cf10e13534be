//! The paper's multi-output SVR: one (C, ε, σ) shared by the outputs, the tube's loss
//! (robust by default, the paper's quadratic with its colony).

use super::Kind;
use crate::model::msvr::{Hyper, MsvrParams};

/// The paper's family.
pub struct Msvr;

impl Kind for Msvr {
    fn name(&self) -> &'static str {
        "msvr"
    }

    fn title(&self) -> &'static str {
        "MSVR"
    }

    fn description(&self) -> &'static str {
        "multi-output support vector regression"
    }

    fn axes(&self) -> &'static [&'static str] {
        &Hyper::AXES
    }

    fn solver(&self, params: MsvrParams) -> MsvrParams {
        params
    }
}
