//! A recorded session replayed through a [`Monitor`]: its channels' values merged in time
//! order.

use super::{Monitor, Monitored, Series, Settings};

/// The rows' predicted and measured outputs, row after row (`rest.len()` each), and the
/// model's outputs at rest.
#[derive(Clone, Copy, Debug)]
pub struct Outputs<'a> {
    pub predicted: &'a [f64],
    pub measured: &'a [f64],
    pub rest: &'a [f64],
}

/// One camera's still-scene channel: its name and how far its view of the still scene lay from
/// the session's first frame's at each time (px).
pub type Scene<'a> = (&'a str, Series<'a>);

/// Watches the model's `errors` (the distance from each prediction to its measured tip), when
/// known the `geometry` (each row's reprojection residual, px; +∞ where the views disagreed
/// beyond the triangulation's gate), each camera's `scene` and the `outputs` (for the
/// finger's response); `radius` is the model file's calibrated radius at `settings.level`.
/// The rows go through a [`Monitor`] in time order.
pub fn watch(
    errors: Series,
    geometry: Option<Series>,
    scene: &[Scene],
    outputs: Option<Outputs>,
    radius: f64,
    settings: &Settings,
) -> Monitored {
    let mut monitor = Monitor::new(radius, settings);
    if let Some(o) = outputs {
        monitor = monitor.with_rest(o.rest.to_vec());
    }
    let empty = Series {
        times: &[],
        values: &[],
    };
    let geometry = geometry.unwrap_or(empty);
    let mut g = geometry.times.iter().zip(geometry.values).peekable();
    let mut cameras: Vec<_> = scene
        .iter()
        .map(|(name, s)| (*name, s.times.iter().zip(s.values).peekable()))
        .collect();
    let mut until = |monitor: &mut Monitor, t: f64| {
        while let Some((&s, &px)) = g.next_if(|(&s, _)| s <= t) {
            monitor.geometry(s, px);
        }
        for (name, values) in &mut cameras {
            while let Some((&s, &px)) = values.next_if(|(&s, _)| s <= t) {
                monitor.scene(name, s, px);
            }
        }
    };
    for (k, (&t, &e)) in errors.times.iter().zip(errors.values).enumerate() {
        until(&mut monitor, t);
        if let Some(o) = outputs {
            let row = k * o.rest.len()..(k + 1) * o.rest.len();
            monitor.outputs(t, &o.predicted[row.clone()], &o.measured[row]);
        }
        monitor.error(t, e);
    }
    until(&mut monitor, f64::INFINITY);
    monitor.finish()
}
