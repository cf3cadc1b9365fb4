//! The report's plots, drawn with `plotters` into SVG: time on x with ticks and units, the safety
//! state machine's phases shaded behind every time plot, limits as dashed lines.

use plotters::prelude::*;
use plotters::style::FontStyle;

/// One phase of the safety state machine: from, to (s), mode.
#[derive(Debug, Clone)]
pub(super) struct Phase {
    pub from: f64,
    pub to: f64,
    pub mode: String,
}

/// One line: label, colour, points (time s, value); NaN values break the line.
pub(super) struct Line<'a> {
    pub label: &'a str,
    pub color: RGBColor,
    pub points: Vec<(f64, f64)>,
}

/// A time plot.
pub(super) struct TimePlot<'a> {
    pub title: &'a str,
    /// The y axis's quantity and unit, e.g. "position (rad)".
    pub y_desc: &'a str,
    pub lines: Vec<Line<'a>>,
    /// Horizontal lines drawn dashed, e.g. a joint's limits.
    pub limits: Vec<f64>,
    pub size: (u32, u32),
    /// Show the legend (small multiples leave it to the page's key).
    pub legend: bool,
}

/// Colours of the report's series.
pub(super) const REFERENCE: RGBColor = RGBColor(120, 120, 120);
pub(super) const MEASURED: RGBColor = RGBColor(205, 45, 45);
pub(super) const BLUE: RGBColor = RGBColor(40, 100, 200);
pub(super) const GREEN: RGBColor = RGBColor(40, 150, 60);
pub(super) const ORANGE: RGBColor = RGBColor(220, 120, 20);
const LIMIT: RGBColor = RGBColor(200, 30, 30);

/// The shade of a safety mode, and its legend name.
pub(super) fn mode_color(mode: &str) -> Option<RGBColor> {
    Some(match mode {
        "Ready" => RGBColor(200, 200, 200),
        "SoftStart" => RGBColor(120, 170, 240),
        "Running" => RGBColor(130, 210, 130),
        "Stopping" => RGBColor(245, 190, 90),
        "Damped" => RGBColor(235, 110, 110),
        _ => return None,
    })
}

/// Why a plot could not be drawn.
#[derive(Debug, Clone, thiserror::Error)]
pub enum PlotError {
    /// No font to measure labels with.
    #[error(
        "the report's plots need a TrueType font: none of DejaVu Sans, Liberation Sans or FreeSans is \
         installed (Debian: apt-get install fonts-dejavu-core)"
    )]
    NoFont,
    /// The font file found is not one plotters reads.
    #[error("the installed font could not be read")]
    BadFont,
    /// plotters failed drawing (its message).
    #[error("drawing failed: {0}")]
    Draw(String),
}

impl PlotError {
    fn draw(e: impl std::error::Error) -> Self {
        Self::Draw(e.to_string())
    }
}

/// Finds a TrueType font on the machine for plotters to measure its labels with (the SVG names
/// the family; the viewer draws it). Registered once.
fn fonts() -> Result<(), PlotError> {
    static FONT: std::sync::OnceLock<Result<(), PlotError>> = std::sync::OnceLock::new();
    FONT.get_or_init(|| {
        let candidates = [
            "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf",
            "/usr/share/fonts/dejavu/DejaVuSans.ttf",
            "/usr/share/fonts/TTF/DejaVuSans.ttf",
            "/usr/share/fonts/truetype/liberation/LiberationSans-Regular.ttf",
            "/usr/share/fonts/liberation/LiberationSans-Regular.ttf",
            "/usr/share/fonts/truetype/freefont/FreeSans.ttf",
        ];
        let bytes = candidates
            .iter()
            .find_map(|p| std::fs::read(p).ok())
            .ok_or(PlotError::NoFont)?;
        // Registered for the life of the process (plotters keeps a 'static reference).
        let bytes: &'static [u8] = Box::leak(bytes.into_boxed_slice());
        for style in [FontStyle::Normal, FontStyle::Bold] {
            plotters::style::register_font("sans-serif", style, bytes).map_err(|_| PlotError::BadFont)?;
        }
        Ok(())
    })
    .clone()
}

/// The x and y ranges of `lines` and `limits` (a flat series gets a unit of room).
fn ranges(plot: &TimePlot<'_>, phases: &[Phase]) -> Option<((f64, f64), (f64, f64))> {
    let (mut x0, mut x1, mut y0, mut y1) =
        (f64::INFINITY, f64::NEG_INFINITY, f64::INFINITY, f64::NEG_INFINITY);
    for &(x, y) in plot.lines.iter().flat_map(|l| &l.points) {
        if x.is_finite() && y.is_finite() {
            (x0, x1, y0, y1) = (x0.min(x), x1.max(x), y0.min(y), y1.max(y));
        }
    }
    for &y in &plot.limits {
        (y0, y1) = (y0.min(y), y1.max(y));
    }
    if let (Some(first), Some(last)) = (phases.first(), phases.last()) {
        (x0, x1) = (x0.min(first.from), x1.max(last.to));
    }
    if !(x0.is_finite() && y0.is_finite()) {
        return None;
    }
    if x1 - x0 < 1e-6 {
        x1 = x0 + 1.0;
    }
    let pad = ((y1 - y0) * 0.06).max(1e-3);
    Some(((x0, x1), (y0 - pad, y1 + pad)))
}

/// `plot` as an SVG document, with `phases` shaded behind it.
pub(super) fn time_plot(plot: &TimePlot<'_>, phases: &[Phase]) -> Result<String, PlotError> {
    fonts()?;
    let Some(((x0, x1), (y0, y1))) = ranges(plot, phases) else {
        return Ok(format!("<p>{}: no data</p>", plot.title));
    };
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, plot.size).into_drawing_area();
        root.fill(&WHITE).map_err(PlotError::draw)?;
        let mut chart = ChartBuilder::on(&root)
            .caption(plot.title, ("sans-serif", 14))
            .margin(6)
            .x_label_area_size(30)
            .y_label_area_size(52)
            .build_cartesian_2d(x0..x1, y0..y1)
            .map_err(PlotError::draw)?;
        chart
            .configure_mesh()
            .x_desc("time (s)")
            .y_desc(plot.y_desc)
            .x_labels(6)
            .y_labels(5)
            .label_style(("sans-serif", 11))
            .max_light_lines(2)
            .light_line_style(RGBColor(238, 238, 238))
            .draw()
            .map_err(PlotError::draw)?;
        chart
            .draw_series(phases.iter().filter_map(|p| {
                mode_color(&p.mode).map(|c| Rectangle::new([(p.from, y0), (p.to, y1)], c.mix(0.18).filled()))
            }))
            .map_err(PlotError::draw)?;
        for &limit in &plot.limits {
            chart
                .draw_series(DashedLineSeries::new(
                    [(x0, limit), (x1, limit)],
                    5,
                    4,
                    LIMIT.stroke_width(1),
                ))
                .map_err(PlotError::draw)?;
        }
        for line in &plot.lines {
            let style = line.color.stroke_width(2);
            // NaN breaks the line into runs.
            let mut runs: Vec<Vec<(f64, f64)>> = vec![Vec::new()];
            for &(x, y) in &line.points {
                if y.is_finite() && x.is_finite() {
                    runs.last_mut().expect("one run at least").push((x, y));
                } else if !runs.last().is_some_and(Vec::is_empty) {
                    runs.push(Vec::new());
                }
            }
            let mut first = true;
            for run in runs.into_iter().filter(|r| !r.is_empty()) {
                let drawn = chart
                    .draw_series(LineSeries::new(run, style))
                    .map_err(PlotError::draw)?;
                if first && plot.legend {
                    let color = line.color;
                    drawn
                        .label(line.label)
                        .legend(move |(x, y)| PathElement::new([(x, y), (x + 16, y)], color.stroke_width(2)));
                }
                first = false;
            }
        }
        if plot.legend {
            chart
                .configure_series_labels()
                .background_style(WHITE.mix(0.85))
                .border_style(RGBColor(200, 200, 200))
                .label_font(("sans-serif", 11))
                .position(SeriesLabelPosition::UpperRight)
                .draw()
                .map_err(PlotError::draw)?;
        }
        root.present().map_err(PlotError::draw)?;
    }
    Ok(svg)
}

/// The safety timeline: each phase of the state machine as a coloured band, named.
pub(super) fn timeline(phases: &[Phase], size: (u32, u32)) -> Result<String, PlotError> {
    fonts()?;
    let (Some(first), Some(last)) = (phases.first(), phases.last()) else {
        return Ok("<p>no safety transitions recorded</p>".into());
    };
    let (x0, x1) = (first.from, last.to.max(first.from + 1e-3));
    let mut svg = String::new();
    {
        let root = SVGBackend::with_string(&mut svg, size).into_drawing_area();
        root.fill(&WHITE).map_err(PlotError::draw)?;
        let mut chart = ChartBuilder::on(&root)
            .margin(6)
            .x_label_area_size(30)
            .y_label_area_size(52)
            .build_cartesian_2d(x0..x1, 0.0..1.0)
            .map_err(PlotError::draw)?;
        chart
            .configure_mesh()
            .disable_y_mesh()
            .disable_y_axis()
            .x_desc("time (s)")
            .x_labels(8)
            .label_style(("sans-serif", 11))
            .draw()
            .map_err(PlotError::draw)?;
        for p in phases {
            let Some(c) = mode_color(&p.mode) else { continue };
            chart
                .draw_series([Rectangle::new([(p.from, 0.0), (p.to, 1.0)], c.filled())])
                .map_err(PlotError::draw)?;
            // The name where it fits.
            let px_per_s = f64::from(size.0.saturating_sub(64)) / (x1 - x0);
            if (p.to - p.from) * px_per_s > 7.0 * p.mode.len() as f64 {
                chart
                    .draw_series([Text::new(p.mode.clone(), (p.from, 0.62), ("sans-serif", 12))])
                    .map_err(PlotError::draw)?;
            }
        }
        root.present().map_err(PlotError::draw)?;
    }
    Ok(svg)
}
