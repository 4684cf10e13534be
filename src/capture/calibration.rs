//! A calibration capture's judge: every [`BOARD_EVERY_S`] the latest frame of each camera is
//! searched for the board; a pair is taken when both show it, it has stood still (no corner
//! moved over [`crate::calib::video::STILL_PX`] between looks) longer than the two cameras'
//! delays may differ ([`super::motion`]), and it stands somewhere new
//! (`calib::video::new_place`).

use std::path::{Path, PathBuf};

use opencv::core::Vector;
use opencv::prelude::*;

use super::{motion, BoardPairs, CaptureError, Grabbed};
use crate::calib::detect::{find_board, Seen};
use crate::calib::video::{footprint, new_place, STILL_PX};
use crate::fsio;

/// How often the latest frames are searched for the board (s).
pub const BOARD_EVERY_S: f64 = 0.2;

/// The pairs taken so far and where their boards stood.
pub struct Judge {
    pub spec: BoardPairs,
    dir: PathBuf,
    previous: Option<[Seen; 2]>,
    /// Since when (s) the board has stood still in both cameras.
    still_since: Option<f64>,
    places: Vec<[f64; 6]>,
    /// Each camera's motion, for the right camera's delay behind the left.
    pub motion: motion::Motion,
    pub delay: Option<motion::Delay>,
    pub taken: usize,
    pub refused: String,
}

/// How long the cameras' delay is waited for before a pair is taken (s): the board moving
/// into view shows it.
pub const DELAY_WAIT_S: f64 = 5.0;
/// How long the board must stand still when the delay could not be measured (s).
pub const UNMEASURED_STILL_S: f64 = 1.0;

fn corners(spec: &BoardPairs, bytes: &[u8]) -> Option<(Seen, [i32; 2])> {
    let gray = crate::cv::decode_image(
        &Vector::from_slice(bytes),
        opencv::imgcodecs::IMREAD_GRAYSCALE,
    )
    .ok()?;
    let found = find_board(&gray, &spec.board, spec.board.first_detector()).ok()??;
    Some((found, [gray.cols(), gray.rows()]))
}

impl Judge {
    /// # Errors
    /// The `calib` folder or its board file cannot be written.
    pub fn new(spec: BoardPairs, out: &Path) -> Result<Self, CaptureError> {
        let dir = out.join("calib");
        std::fs::create_dir_all(&dir).map_err(|source| CaptureError::Write {
            path: dir.clone(),
            source,
        })?;
        let board = dir.join(crate::calib::file::BOARD_FILE);
        fsio::write_bytes(
            &board,
            crate::calib::file::board_yaml(&spec.board).as_bytes(),
        )
        .map_err(|source| CaptureError::Write {
            path: board,
            source,
        })?;
        Ok(Judge {
            spec,
            dir,
            previous: None,
            still_since: None,
            places: Vec::new(),
            motion: motion::Motion::default(),
            delay: None,
            taken: 0,
            refused: String::new(),
        })
    }

    pub fn done(&self) -> bool {
        self.taken
            >= if self.spec.reference {
                1
            } else {
                self.spec.pairs
            }
    }

    /// How long (s) the board must have stood still in both cameras at `now` for a pair,
    /// or why none may be taken yet. Each camera's latest frame shows the board as it
    /// stood its delay ago: still longer than the two delays differ, both show one place.
    fn still_needed_s(&self, now: f64) -> Result<f64, String> {
        match self.delay {
            Some(d) => Ok(BOARD_EVERY_S + d.largest_s),
            None if now < DELAY_WAIT_S => Err(
                "move the board in view of both cameras: their delays are being measured".into(),
            ),
            None => Ok(UNMEASURED_STILL_S),
        }
    }

    /// Looks at the latest left and right frames at `now` (s); takes them when they
    /// qualify.
    ///
    /// # Errors
    /// A pair's file cannot be written.
    pub(super) fn look(
        &mut self,
        left: &Grabbed,
        right: &Grabbed,
        now: f64,
    ) -> Result<(), CaptureError> {
        self.delay = self.motion.delay().or(self.delay);
        let (l, r) = (
            corners(&self.spec, &left.frame.bytes),
            corners(&self.spec, &right.frame.bytes),
        );
        let previous = self.previous.take();
        let (Some((l, size)), Some((r, _))) = (l, r) else {
            self.still_since = None;
            self.refused = "the board is not seen in both cameras".into();
            return Ok(());
        };
        // The rule `calibrate` will hold the pair to.
        if let Err(why) = crate::calib::pairs::match_corners(&self.spec.board, &l, &r) {
            self.still_since = None;
            self.refused = why;
            return Ok(());
        }
        let moved = match &previous {
            Some([pl, pr]) => l.moved_from(pl).max(r.moved_from(pr)),
            None => f64::INFINITY,
        };
        self.previous = Some([l.clone(), r]);
        if moved > STILL_PX {
            self.still_since = Some(now);
            self.refused = "the board is moving: hold it still".into();
            return Ok(());
        }
        let since = *self.still_since.get_or_insert(now);
        let needed = match self.still_needed_s(now) {
            Ok(s) => s,
            Err(why) => {
                self.refused = why;
                return Ok(());
            }
        };
        if now - since < needed - 1e-6 {
            self.refused = format!(
                "hold it still: {:.1} s of {needed:.1} s (the cameras' delays may differ by {:.0} ms)",
                now - since,
                1e3 * self.delay.map_or(0.0, |d| d.largest_s)
            );
            return Ok(());
        }
        let place = footprint(&self.spec.board, &l, size);
        if !self.spec.reference && !new_place(&place, &self.places) {
            self.refused = "the board stands where a pair was taken: move or tilt it".into();
            return Ok(());
        }
        let name = if self.spec.reference {
            "ref".to_string()
        } else {
            format!("{:02}", self.taken)
        };
        for grabbed in [left, right] {
            let path = self.dir.join(format!(
                "{}_{name}.{}",
                grabbed.side().name(),
                grabbed.frame.extension
            ));
            fsio::write_bytes(&path, &grabbed.frame.bytes)
                .map_err(|source| CaptureError::Write { path, source })?;
        }
        self.places.push(place);
        self.taken += 1;
        self.refused.clear();
        Ok(())
    }
}
