//! The finger in time: how the muscles' pressures, and so the tip, follow the regulator's
//! commands.
//!
//! # Equations (per muscle i; t in s, pressures in kPa)
//!
//! 1. Tubing: a transport delay d and a first-order lag τ_i,
//!    τ_i · dp_i/dt = u_i(t − d) − p_i, where u is the command held from each command's time
//!    (0 before the first: the session starts at rest).
//! 2. Hysteresis: p̃ = play(p), the plant's play operator ([`super::plant::play`], width
//!    `hysteresis_kpa`).
//! 3. Creep of the silicone: a slow state q with τ_c · dq/dt = p̃ − q; the rod feels
//!    p_eff = (1 − a) · p̃ + a · q, so after a change the tip goes (1 − a) of the way with the
//!    pressure and creeps the last share a over seconds.
//!
//! Held long enough, q = p̃ = p = u: without hysteresis the settled tip is the plant's map of
//! the command, whatever the dynamics. The tip at any instant is the plant's rod under p_eff
//! (the rod itself is quasi-static: its own modes are far faster than the tubing).
//!
//! The equations are integrated on a 1 ms grid, exactly for a delayed command constant over
//! each grid step (taken at the step's middle); between grid points p_eff is interpolated
//! linearly.

use serde::Serialize;

use super::plant::{play, Pressures};

/// The integration grid (s).
const GRID_S: f64 = 1e-3;

/// The pneumatic line and the silicone (see the module docs).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Dynamics {
    /// Transport delay d from the regulator to the muscles (s).
    pub delay_s: f64,
    /// Each muscle's lag τ_i (s), muscles 1, 2, 3.
    pub lag_s: [f64; 3],
    /// The share a of the response that creeps.
    pub creep_share: f64,
    /// The creep's time constant τ_c (s).
    pub creep_s: f64,
}

impl Dynamics {
    /// The step sessions' regulator: a short line, the pressure settled 0.1 s after a command
    /// to e^{−5}; no delay, no creep.
    pub const STEPS: Dynamics = Dynamics {
        delay_s: 0.0,
        lag_s: [0.02; 3],
        creep_share: 0.0,
        creep_s: 1.0,
    };
    /// A McKibben hand on a metre of tubing (`notes/motion.md`): 30 ms of transport delay,
    /// lags of 0.15-0.4 s (the muscles' volumes differ), 8 % of the response creeping with a
    /// time constant of 3 s.
    pub const PNEUMATIC: Dynamics = Dynamics {
        delay_s: 0.03,
        lag_s: [0.15, 0.25, 0.4],
        creep_share: 0.08,
        creep_s: 3.0,
    };

    /// Why these constants are not a line's, if they are not.
    pub fn check(&self) -> Result<(), String> {
        if !(0.0..=1.0).contains(&self.delay_s) {
            return Err(format!("delay {} s must lie in 0-1 s", self.delay_s));
        }
        if !self.lag_s.iter().all(|&t| (0.0..=10.0).contains(&t)) {
            return Err(format!("lags {:?} s must lie in 0-10 s", self.lag_s));
        }
        if !((0.0..1.0).contains(&self.creep_share) && self.creep_s > 0.0 && self.creep_s <= 600.0)
        {
            return Err(format!(
                "creep share {} must lie in [0, 1) and its time {} s in (0, 600]",
                self.creep_share, self.creep_s
            ));
        }
        Ok(())
    }
}

/// The pressures the rod feels (p_eff) over a session, on the integration grid from t = 0:
/// simulated at once ([`Motion::simulate`]) or as the commands come ([`Motion::command`],
/// [`Motion::run_to`]: a live plant).
#[derive(Clone, Debug)]
pub struct Motion {
    effective: Vec<Pressures>,
    dynamics: Dynamics,
    hysteresis_kpa: f64,
    /// The commands (time, pressures held from it), and how many the grid has reached.
    commands: Vec<(f64, Pressures)>,
    next: usize,
    /// The command in force at the grid's end, and the line's state there: each muscle's
    /// pressure, after the play, and the creeping share.
    command: Pressures,
    line: Pressures,
    played: Pressures,
    slow: Pressures,
}

impl Motion {
    /// How far past its `end_s` [`Motion::run_to`] simulates (s): three grid steps.
    pub const AHEAD_S: f64 = 3.0 * GRID_S;

    /// A plant at rest from t = 0, no command yet.
    pub fn at_rest(dynamics: &Dynamics, hysteresis_kpa: f64) -> Motion {
        Motion {
            effective: vec![[0.0; 3]],
            dynamics: *dynamics,
            hysteresis_kpa,
            commands: Vec::new(),
            next: 0,
            command: [0.0; 3],
            line: [0.0; 3],
            played: [0.0; 3],
            slow: [0.0; 3],
        }
    }

    /// Simulates `commands` (times in s, increasing, and the pressures held from each) until
    /// `end_s`, from rest.
    pub fn simulate(
        commands: &[(f64, Pressures)],
        dynamics: &Dynamics,
        hysteresis_kpa: f64,
        end_s: f64,
    ) -> Motion {
        let mut motion = Motion::at_rest(dynamics, hysteresis_kpa);
        motion.commands = commands.to_vec();
        motion.run_to(end_s);
        motion
    }

    /// Holds `pressures` from `time_s` (s): not before the last command, nor before the end
    /// of the grid already simulated ([`Motion::run_to`]).
    pub fn command(&mut self, time_s: f64, pressures: Pressures) {
        debug_assert!(self.commands.last().is_none_or(|&(t, _)| t <= time_s));
        self.commands.push((time_s, pressures));
    }

    /// The grid simulated to cover `end_s` (s): [`Motion::at`] is exact up to there once every
    /// command up to [`Motion::AHEAD_S`] after `end_s` has been given.
    pub fn run_to(&mut self, end_s: f64) {
        let n = (end_s.max(0.0) / GRID_S).ceil() as usize + 2;
        let d = self.dynamics;
        let lag = d.lag_s.map(decay);
        let creep = decay(d.creep_s);
        let a = d.creep_share;
        for k in self.effective.len()..n {
            let seen = (k as f64 - 0.5) * GRID_S - d.delay_s;
            while self.next < self.commands.len() && self.commands[self.next].0 <= seen {
                self.command = self.commands[self.next].1;
                self.next += 1;
            }
            self.line = std::array::from_fn(|i| {
                self.command[i] + (self.line[i] - self.command[i]) * lag[i]
            });
            play(&mut self.played, self.line, self.hysteresis_kpa);
            self.slow =
                std::array::from_fn(|i| self.played[i] + (self.slow[i] - self.played[i]) * creep);
            let (played, slow) = (self.played, self.slow);
            self.effective.push(std::array::from_fn(|i| {
                ((1.0 - a) * played[i] + a * slow[i]).clamp(0.0, crate::hand::MAX_PRESSURE_KPA)
            }));
        }
    }

    /// The pressures in the line at the grid's end (kPa): what gauges at the muscles read.
    pub fn measured(&self) -> Pressures {
        self.line
    }

    /// The pressures the rod feels at `t` (s): rest before 0, the last simulated after the end.
    pub fn at(&self, t: f64) -> Pressures {
        let x = (t / GRID_S).max(0.0);
        let k = x.floor() as usize;
        if k + 1 >= self.effective.len() {
            return *self.effective.last().expect("at least two grid points");
        }
        let f = x - k as f64;
        let (a, b) = (self.effective[k], self.effective[k + 1]);
        std::array::from_fn(|i| a[i] + (b[i] - a[i]) * f)
    }
}

/// e^{−Δ/τ} for one grid step; 0 for no lag.
fn decay(tau_s: f64) -> f64 {
    if tau_s > 0.0 {
        (-GRID_S / tau_s).exp()
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn step_to(p: Pressures) -> Vec<(f64, Pressures)> {
        vec![(0.0, [0.0; 3]), (1.0, p)]
    }

    #[test]
    fn a_held_command_settles_to_itself() {
        let motion = Motion::simulate(
            &step_to([50.0, 120.0, 200.0]),
            &Dynamics::PNEUMATIC,
            0.0,
            40.0,
        );
        let p = motion.at(39.0);
        for (got, want) in p.iter().zip([50.0, 120.0, 200.0]) {
            assert!((got - want).abs() < 1e-3, "{p:?}");
        }
        assert_eq!(motion.at(0.9), [0.0; 3], "before the command: rest");
    }

    #[test]
    fn commands_given_as_they_come_move_the_rod_as_given_at_once() {
        let commands = [
            (0.2, [50.0, 0.0, 100.0]),
            (0.7, [200.0, 30.0, 0.0]),
            (1.333, [0.0, 250.0, 80.0]),
        ];
        for dynamics in [Dynamics::PNEUMATIC, Dynamics::STEPS] {
            let whole = Motion::simulate(&commands, &dynamics, 10.0, 3.0);
            let mut live = Motion::at_rest(&dynamics, 10.0);
            for (t, p) in commands {
                live.run_to(t - Motion::AHEAD_S);
                live.command(t, p);
            }
            live.run_to(3.0);
            assert_eq!(live.effective, whole.effective);
            assert!(whole.at(2.0)[1] > 200.0, "{:?}", whole.at(2.0));
        }
    }

    #[test]
    fn the_line_delays_and_lags_each_muscle_by_its_own_time() {
        let d = Dynamics {
            creep_share: 0.0,
            ..Dynamics::PNEUMATIC
        };
        let motion = Motion::simulate(&step_to([100.0; 3]), &d, 0.0, 5.0);
        // Nothing arrives before the delay.
        assert!(motion.at(1.0 + 0.9 * d.delay_s).iter().all(|&p| p == 0.0));
        // One lag after the delay, each muscle is at 1 − e^{−1} of the step.
        for i in 0..3 {
            let p = motion.at(1.0 + d.delay_s + d.lag_s[i])[i];
            let want = 100.0 * (1.0 - (-1.0f64).exp());
            assert!(
                (p - want).abs() < 0.3,
                "muscle {}: {p} kPa, want {want}",
                i + 1
            );
        }
    }

    #[test]
    fn creep_brings_the_last_share_over_seconds() {
        let d = Dynamics {
            delay_s: 0.0,
            lag_s: [0.0; 3],
            ..Dynamics::PNEUMATIC
        };
        let motion = Motion::simulate(&step_to([100.0; 3]), &d, 0.0, 30.0);
        let early = motion.at(1.01)[0];
        assert!(
            (early - 100.0 * (1.0 - d.creep_share)).abs() < 0.1,
            "{early}"
        );
        let one_tau = motion.at(1.0 + d.creep_s)[0];
        let want = 100.0 - 100.0 * d.creep_share * (-1.0f64).exp();
        assert!((one_tau - want).abs() < 0.05, "{one_tau} vs {want}");
    }

    #[test]
    fn hysteresis_remains_when_the_command_is_held() {
        let commands = [(0.0, [200.0; 3]), (5.0, [100.0; 3])];
        let motion = Motion::simulate(&commands, &Dynamics::STEPS, 20.0, 10.0);
        // Unloaded from 200 to 100 kPa through a play of 20 kPa: stuck 10 kPa above.
        assert!(
            (motion.at(9.9)[0] - 110.0).abs() < 1e-6,
            "{:?}",
            motion.at(9.9)
        );
    }

    #[test]
    fn the_constants_are_checked() {
        assert!(Dynamics::PNEUMATIC.check().is_ok() && Dynamics::STEPS.check().is_ok());
        let bad = Dynamics {
            creep_share: 1.0,
            ..Dynamics::PNEUMATIC
        };
        assert!(bad.check().unwrap_err().contains("creep share"));
    }
}
