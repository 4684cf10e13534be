//! The micro-hand's design values, shared by everything that models it.
//!
//! The finger of the paper (§2.1, Figure 1): 50 mm long, 5.0 mm wide, 2.6 mm thick, three
//! McKibben muscles bonded in silicone with a gap between muscle 2 and muscles 1 and 3. These are
//! the drawing's numbers, not a model's constants: the virtual plant (`handcap::synth::plant`) and
//! the previous physics model ([`crate::model::previous`]) both start from them.

/// Length of the finger from its clamped base to the tip (mm).
pub const LENGTH_MM: f64 = 50.0;

/// Muscle centres (x, y) in the cross-section, hand frame (mm), muscles 1, 2, 3: muscles 1 and 3
/// side by side along x, muscle 2 across the gap at +y. Their centroid is the section's centre.
pub const MUSCLE_XY_MM: [[f64; 2]; 3] = [[-1.25, -0.4], [0.0, 0.8], [1.25, -0.4]];

/// The safety regulator's cap: no pressure above this is ever applied (kPa).
pub const MAX_PRESSURE_KPA: f64 = 300.0;

/// The inverse's default upper bound of every `_kpa` input (kPa): the micro-hand's protocol
/// range, below the regulator's [`MAX_PRESSURE_KPA`].
pub const DEFAULT_MAX_KPA: f64 = 250.0;
