//! Line plots written as PNG and SVG (plotters).
//!
//! Labels use DejaVu Sans read from the system (`fonts-dejavu-core`, which `scripts/setup.sh`
//! installs). The PNG is drawn into a temporary file and renamed into place; the SVG is built in
//! memory and written atomically.

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use plotters::coord::ranged1d::{Ranged, ValueFormatter};
use plotters::coord::types::RangedCoordf64;
use plotters::prelude::*;

use crate::fsio;

/// Where the labels' font is read from.
pub const FONT_PATH: &str = "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf";
const SIZE: (u32, u32) = (800, 500);

/// Errors of drawing a figure.
#[derive(Debug, thiserror::Error)]
pub enum FigureError {
    #[error("cannot load the figure font {FONT_PATH}: {0}; install fonts-dejavu-core (scripts/setup.sh does)")]
    Font(String),
    #[error("drawing {path}: {message}")]
    Draw { path: PathBuf, message: String },
}

/// How a series is drawn.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Mark {
    Line,
    Points,
    /// Bars from 0, `width` wide (x units), shifted by `offset` (to put series side by side).
    Bars {
        offset: f64,
        width: f64,
    },
}

/// One named series of (x, y) points.
#[derive(Clone, Debug)]
pub struct Series {
    pub label: String,
    pub points: Vec<(f64, f64)>,
    pub mark: Mark,
    /// Index into the palette ([`BLACK_INDEX`] is black), so a model keeps its colour across
    /// figures.
    pub colour: usize,
}

/// The palette index of black, for measured data.
pub const BLACK_INDEX: usize = 5;

/// A plot of series against one x axis.
#[derive(Clone, Debug)]
pub struct LinePlot {
    pub title: String,
    pub x_label: String,
    pub y_label: String,
    pub series: Vec<Series>,
    /// A logarithmic y axis (points with y ≤ 0 are left out).
    pub log_y: bool,
    /// Names of the categories at x = 0, 1, 2, …, shown as the x axis's labels instead of
    /// numbers (empty: a numeric axis).
    pub x_names: Vec<String>,
}

fn register_font() -> Result<(), FigureError> {
    static FONT: OnceLock<Result<(), String>> = OnceLock::new();
    FONT.get_or_init(|| {
        let bytes = std::fs::read(FONT_PATH).map_err(|e| e.to_string())?;
        let bytes: &'static [u8] = Box::leak(bytes.into_boxed_slice());
        plotters::style::register_font("sans-serif", FontStyle::Normal, bytes)
            .map_err(|_| "not a font file".to_string())
    })
    .clone()
    .map_err(FigureError::Font)
}

/// The files [`write_line_plot`] writes for `stem`: `STEM.png` and `STEM.svg`, the extension
/// added to the whole name (a stem with a dot, `sweep.a_x_mm`, keeps it).
pub fn line_plot_files(stem: &Path) -> [PathBuf; 2] {
    ["png", "svg"].map(|ext| {
        let mut name = stem.as_os_str().to_owned();
        name.push(".");
        name.push(ext);
        PathBuf::from(name)
    })
}

/// Writes the two [`line_plot_files`] of `stem`.
///
/// # Errors
/// [`FigureError`] when the font is missing or a file cannot be drawn or written.
pub fn write_line_plot(stem: &Path, plot: &LinePlot) -> Result<(), FigureError> {
    register_font()?;
    let [png, svg_path] = line_plot_files(stem);
    let draw_err = |path: &Path| {
        let path = path.to_path_buf();
        move |e: String| FigureError::Draw { path, message: e }
    };
    // Drawn in memory, encoded as plotters would (image's PNG encoder, its defaults), written
    // atomically: a full disk is an I/O error naming the file, not a backend dump.
    let mut rgb = vec![0u8; 3 * SIZE.0 as usize * SIZE.1 as usize];
    draw(
        BitMapBackend::with_buffer(&mut rgb, SIZE).into_drawing_area(),
        plot,
    )
    .map_err(draw_err(&png))?;
    fsio::write_atomic(&png, |w| {
        use image::ImageEncoder;
        image::codecs::png::PngEncoder::new(w)
            .write_image(&rgb, SIZE.0, SIZE.1, image::ColorType::Rgb8)
            .map_err(std::io::Error::other)
    })
    .map_err(|e| draw_err(&png)(e.to_string()))?;

    let mut svg = String::new();
    draw(
        SVGBackend::with_string(&mut svg, SIZE).into_drawing_area(),
        plot,
    )
    .map_err(draw_err(&svg_path))?;
    fsio::write_bytes(&svg_path, svg.as_bytes()).map_err(|e| draw_err(&svg_path)(e.to_string()))
}

const COLOURS: [RGBColor; 6] = [
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
    RGBColor(255, 127, 14),
    RGBColor(148, 103, 189),
    RGBColor(0, 0, 0),
];

fn draw<DB: DrawingBackend>(
    area: DrawingArea<DB, plotters::coord::Shift>,
    plot: &LinePlot,
) -> Result<(), String>
where
    DB::ErrorType: 'static,
{
    area.fill(&WHITE).map_err(|e| e.to_string())?;
    let mut shown: Vec<(f64, f64)> = plot
        .series
        .iter()
        .flat_map(|s| s.points.iter().copied())
        .filter(|&p| plot.shows(p))
        .collect();
    // Bars stand on zero, which must be in view.
    if let Some(&(x, _)) = shown.first() {
        if plot
            .series
            .iter()
            .any(|s| matches!(s.mark, Mark::Bars { .. }))
        {
            shown.push((x, 0.0));
        }
    }
    let (x0, x1) = if plot.x_names.is_empty() {
        padded(shown.iter().map(|p| p.0))
    } else {
        (-0.6, plot.x_names.len() as f64 - 0.4)
    };
    // Room above the data for the legend, which sits in the top right corner.
    let legend = plot.series.len() > 1;
    let mut builder = ChartBuilder::on(&area);
    builder
        .caption(&plot.title, ("sans-serif", 22))
        .margin(12)
        .x_label_area_size(45)
        .y_label_area_size(70);
    if plot.log_y {
        let (lo, hi) = headroom(padded(shown.iter().map(|p| p.1.log10())), legend);
        let y = (10f64.powf(lo)..10f64.powf(hi)).log_scale();
        let chart = builder
            .build_cartesian_2d(x0..x1, y)
            .map_err(|e| e.to_string())?;
        fill(chart, plot)?;
    } else {
        let (y0, y1) = headroom(padded(shown.iter().map(|p| p.1)), legend);
        let chart = builder
            .build_cartesian_2d(x0..x1, y0..y1)
            .map_err(|e| e.to_string())?;
        fill(chart, plot)?;
    }
    area.present().map_err(|e| e.to_string())
}

impl LinePlot {
    /// Whether a point can be drawn on this plot's axes.
    fn shows(&self, (x, y): (f64, f64)) -> bool {
        x.is_finite() && y.is_finite() && (!self.log_y || y > 0.0)
    }
}

/// Draws the mesh, the series and the legend into a built chart.
fn fill<'a, DB, Y>(
    mut chart: ChartContext<'a, DB, Cartesian2d<RangedCoordf64, Y>>,
    plot: &LinePlot,
) -> Result<(), String>
where
    DB: DrawingBackend + 'a,
    DB::ErrorType: 'static,
    Y: Ranged<ValueType = f64> + ValueFormatter<f64>,
{
    let e = |err: DrawingAreaErrorKind<DB::ErrorType>| err.to_string();
    let name = |x: &f64| {
        let k = x.round();
        match plot.x_names.get(k as usize) {
            Some(name) if (x - k).abs() < 1e-6 && k >= 0.0 => name.clone(),
            _ => String::new(),
        }
    };
    let (x_range, y_range) = (chart.x_range(), chart.y_range());
    // Whole-number x data (iterations, steps) get whole-number ticks.
    let whole_x = plot
        .series
        .iter()
        .flat_map(|s| &s.points)
        .all(|p| p.0.fract() == 0.0);
    let x_span = x_range.end - x_range.start;
    let x_digits = if whole_x { 0 } else { digits(x_span) };
    let y_digits = if plot.log_y {
        0
    } else {
        digits(y_range.end - y_range.start)
    };
    let x_tick = |v: &f64| tick(*v, x_digits);
    let y_tick = |v: &f64| tick(*v, y_digits);
    let mut mesh = chart.configure_mesh();
    mesh.x_desc(&plot.x_label)
        .y_desc(&plot.y_label)
        .label_style(("sans-serif", 14))
        .y_label_formatter(&y_tick);
    if plot.x_names.is_empty() {
        mesh.x_label_formatter(&x_tick);
        if whole_x && x_span < 12.0 {
            // Plotters would put ticks between the whole numbers of a short axis.
            mesh.x_labels(x_span as usize + 1);
        }
    } else {
        mesh.x_labels(plot.x_names.len().min(30))
            .x_label_formatter(&name);
    }
    mesh.draw().map_err(e)?;
    for s in &plot.series {
        let colour = COLOURS[s.colour % COLOURS.len()];
        let points = s.points.iter().copied().filter(|&p| plot.shows(p));
        // A log axis cannot show zero: the points it leaves out are counted in the legend.
        let hidden = s.points.len() - s.points.iter().filter(|&&p| plot.shows(p)).count();
        let label = match hidden {
            0 => s.label.clone(),
            n => format!("{} ({n} at or below 0 not drawn)", s.label),
        };
        let drawn = match s.mark {
            Mark::Line => chart.draw_series(LineSeries::new(points, colour.stroke_width(2))),
            Mark::Points => chart.draw_series(points.map(|p| Circle::new(p, 3, colour.filled()))),
            Mark::Bars { offset, width } => chart.draw_series(points.map(|(x, y)| {
                let x = x + offset;
                Rectangle::new(
                    [(x - width / 2.0, 0.0), (x + width / 2.0, y)],
                    colour.filled(),
                )
            })),
        }
        .map_err(e)?;
        // The legend shows each series as it is drawn.
        let mark = s.mark;
        drawn
            .label(label)
            .legend(move |(x, y)| -> DynElement<'static, _, _> {
                match mark {
                    Mark::Line => {
                        PathElement::new([(x, y), (x + 20, y)], colour.stroke_width(2)).into_dyn()
                    }
                    Mark::Points => Circle::new((x + 10, y), 3, colour.filled()).into_dyn(),
                    Mark::Bars { .. } => {
                        Rectangle::new([(x + 4, y - 5), (x + 16, y + 5)], colour.filled())
                            .into_dyn()
                    }
                }
            });
    }
    if plot.series.len() > 1 {
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperRight)
            .background_style(WHITE.mix(0.8))
            .border_style(BLACK)
            .label_font(("sans-serif", 14))
            .draw()
            .map_err(e)?;
    }
    Ok(())
}

/// Decimals that tell an axis's ticks apart: about a tenth of its span's.
fn digits(span: f64) -> usize {
    if span > 0.0 && span.is_finite() {
        (-(span / 10.0).log10()).ceil().clamp(0.0, 6.0) as usize
    } else {
        0
    }
}

/// A tick label: `digits` decimals, more if the value needs them (up to 6), none for whole
/// numbers on a whole-number axis ("10", not "10.0").
fn tick(v: f64, digits: usize) -> String {
    let exact = (digits..=6)
        .find(|&d| {
            let scale = 10f64.powi(d as i32);
            ((v * scale).round() / scale - v).abs() <= 1e-9 * v.abs().max(1.0)
        })
        .unwrap_or(6);
    let text = format!("{v:.exact$}");
    if text.starts_with('-') && text[1..].chars().all(|c| c == '0' || c == '.') {
        text[1..].to_string()
    } else {
        text
    }
}

/// `range` raised at the top by a quarter (in its own units: log for a log axis), so a legend
/// in the top right corner stands above the data.
fn headroom((lo, hi): (f64, f64), legend: bool) -> (f64, f64) {
    if legend {
        (lo, hi + 0.25 * (hi - lo))
    } else {
        (lo, hi)
    }
}

/// The range of the values with 5 % margins (a unit range around a single value).
fn padded(values: impl Iterator<Item = f64>) -> (f64, f64) {
    let (lo, hi) = values.fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
        (lo.min(v), hi.max(v))
    });
    if !lo.is_finite() {
        return (0.0, 1.0);
    }
    let pad = if hi > lo {
        0.05 * (hi - lo)
    } else {
        0.5 * lo.abs().max(1e-9)
    };
    (lo - pad, hi + pad)
}

#[cfg(test)]
mod tests {
    use super::{digits, tick};

    #[test]
    fn ticks_have_the_decimals_their_axis_needs() {
        // An axis of 0-250 kPa, or of 80 iterations: whole numbers.
        assert_eq!(digits(250.0), 0);
        assert_eq!(digits(80.0), 0);
        assert_eq!(tick(10.0, digits(80.0)), "10");
        // 0-0.12 mm: two decimals on every tick, more where a tick has them.
        assert_eq!(digits(0.12), 2);
        assert_eq!(tick(0.1, 2), "0.10");
        assert_eq!(tick(0.02, 2), "0.02");
        assert_eq!(tick(0.125, 2), "0.125");
        // No negative zero.
        assert_eq!(tick(-1e-12, 1), "0.0");
        assert_eq!(tick(-0.5, 1), "-0.5");
    }
}
