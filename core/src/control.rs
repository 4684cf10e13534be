//! Long work stopped and watched from outside, without a handle threaded through every call:
//! a front end asks for a stop (Ctrl-C or a termination signal on the command line,
//! `KeyboardInterrupt` in Python) and shows the solver's iterations; the solvers' loops check
//! for a stop asked after they began, and count their iterations.
//!
//! A stop ends the work begun before it: a search's candidate fits end at once, and the fit of
//! the chosen parameters that follows runs unless another stop is asked.

use std::sync::atomic::{AtomicUsize, Ordering};

static STOPS: AtomicUsize = AtomicUsize::new(0);
static ITERATIONS: AtomicUsize = AtomicUsize::new(0);

/// Asks every fit running now to stop.
pub fn request_stop() {
    STOPS.fetch_add(1, Ordering::SeqCst);
}

/// A moment to check for stops against.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Since(usize);

impl Since {
    /// The process's start: work that checks this stops at any stop asked at all.
    pub const START: Since = Since(0);

    /// Now: work that checks this stops at any stop asked from now on.
    pub fn now() -> Self {
        Since(STOPS.load(Ordering::SeqCst))
    }

    /// Whether a stop was asked since.
    pub fn stopped(self) -> bool {
        STOPS.load(Ordering::Relaxed) > self.0
    }
}

/// Counts one solver iteration done (any fit's).
pub fn iteration_done() {
    ITERATIONS.fetch_add(1, Ordering::Relaxed);
}

/// Solver iterations done so far, by every fit: a front end shows the rise of this count
/// while one fit runs.
pub fn iterations() -> usize {
    ITERATIONS.load(Ordering::Relaxed)
}
