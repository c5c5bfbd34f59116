//! `strand check-job --png DIR`: the check's series as pictures — every joint's position inside
//! its limits over the job (normalised, so one chart shows them all), and the Cartesian following
//! error against `tcp_error_limit`. Also the one font lookup every strand plot uses.

use std::path::{Path, PathBuf};

use plotters::prelude::*;
use plotters::style::FontStyle;

use super::{CheckReport, CheckSeries, NoFont};
use strand_core::kin::JointLimits;

/// Font files tried in order (plotters draws text with ab_glyph from a TTF).
const FONT_PATHS: &[&str] = &[
    "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/dejavu/DejaVuSans.ttf",
    "/usr/share/fonts/TTF/DejaVuSans.ttf",
    "/usr/share/fonts/truetype/liberation/LiberationSans-Regular.ttf",
];

/// Registers the first TrueType font found (`$STRAND_PLOT_FONT`, then [`FONT_PATHS`]) as plotters'
/// "sans-serif"; an error names every file tried.
pub fn register_font() -> Result<(), NoFont> {
    let env = std::env::var("STRAND_PLOT_FONT").ok();
    for p in env.iter().map(String::as_str).chain(FONT_PATHS.iter().copied()) {
        if let Ok(bytes) = std::fs::read(p) {
            let bytes: &'static [u8] = Box::leak(bytes.into_boxed_slice());
            if plotters::style::register_font("sans-serif", FontStyle::Normal, bytes).is_ok() {
                return Ok(());
            }
        }
    }
    let tried = env.iter().map(String::as_str).chain(FONT_PATHS.iter().copied()).collect::<Vec<_>>().join(", ");
    Err(NoFont { tried })
}

/// A picture that could not be written.
#[derive(Debug, thiserror::Error)]
pub enum PlotError {
    /// No font for its text.
    #[error(transparent)]
    NoFont(#[from] NoFont),
    /// Its folder could not be created.
    #[error("{}: {source}", path.display())]
    Folder {
        /// The folder.
        path: PathBuf,
        /// What the system said.
        source: std::io::Error,
    },
    /// plotters could not draw or write it.
    #[error("{}: cannot draw: {why}", path.display())]
    Draw {
        /// The picture's file.
        path: PathBuf,
        /// What plotters said.
        why: String,
    },
}

/// Writes `joints.png` and `tcp_error.png` into `dir` (created if missing); returns their paths.
pub fn write(
    dir: &Path,
    report: &CheckReport,
    series: &CheckSeries,
    limits: &[JointLimits],
    names: &[String],
    tcp_limit: f64,
) -> Result<Vec<PathBuf>, PlotError> {
    register_font()?;
    std::fs::create_dir_all(dir).map_err(|source| PlotError::Folder { path: dir.to_path_buf(), source })?;
    let joints = dir.join("joints.png");
    let error = dir.join("tcp_error.png");
    let draw = |path: &Path, e: Box<dyn std::error::Error>| PlotError::Draw { path: path.to_path_buf(), why: e.to_string() };
    plot_joints(&joints, report, series, limits, names).map_err(|e| draw(&joints, e))?;
    plot_error(&error, report, series, tcp_limit).map_err(|e| draw(&error, e))?;
    Ok(vec![joints, error])
}

type PlotResult = Result<(), Box<dyn std::error::Error>>;

const COLOURS: [RGBColor; 8] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(23, 190, 207),
];

fn t_range(series: &CheckSeries) -> std::ops::Range<f64> {
    let end = series.t.last().copied().unwrap_or(1.0).max(1e-3);
    0.0..end
}

fn plot_joints(path: &Path, report: &CheckReport, series: &CheckSeries, limits: &[JointLimits], names: &[String]) -> PlotResult {
    let root = BitMapBackend::new(path, (1400, 700)).into_drawing_area();
    root.fill(&WHITE)?;
    let caption = format!("{} on {}: joint positions within their limits (0 = lower, 1 = upper)", report.file, report.robot);
    let mut chart = ChartBuilder::on(&root)
        .caption(caption, ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(t_range(series), -0.05f64..1.05f64)?;
    chart.configure_mesh().x_desc("time from Start (s)").y_desc("position in range").draw()?;
    for (i, q) in series.q.iter().enumerate() {
        let l = &limits[i];
        if !(l.lower.is_finite() && l.upper.is_finite()) {
            continue;
        }
        let span = l.upper - l.lower;
        let colour = COLOURS[i % COLOURS.len()];
        let name = names.get(i).cloned().unwrap_or_default();
        chart
            .draw_series(LineSeries::new(series.t.iter().zip(q).map(|(t, v)| (*t, (v - l.lower) / span)), colour.stroke_width(2)))?
            .label(format!("{} {name}", i + 1))
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], colour.stroke_width(2)));
    }
    let end = t_range(series).end;
    for edge in [0.0, 1.0] {
        chart.draw_series(LineSeries::new([(0.0, edge), (end, edge)], BLACK.stroke_width(2)))?;
    }
    chart.configure_series_labels().background_style(WHITE.mix(0.8)).border_style(BLACK).draw()?;
    root.present()?;
    Ok(())
}

fn plot_error(path: &Path, report: &CheckReport, series: &CheckSeries, tcp_limit: f64) -> PlotResult {
    let root = BitMapBackend::new(path, (1400, 500)).into_drawing_area();
    root.fill(&WHITE)?;
    let top = series.tcp_error.iter().copied().fold(tcp_limit, f64::max) * 1e3 * 1.1;
    let caption = format!("{}: Cartesian following error along the job (limit {:.2} mm)", report.file, tcp_limit * 1e3);
    let mut chart = ChartBuilder::on(&root)
        .caption(caption, ("sans-serif", 20))
        .margin(12)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(t_range(series), 0.0..top.max(1e-3))?;
    chart.configure_mesh().x_desc("time from Start (s)").y_desc("TCP error (mm)").draw()?;
    chart
        .draw_series(LineSeries::new(series.t.iter().zip(&series.tcp_error).map(|(t, e)| (*t, e * 1e3)), COLOURS[0].stroke_width(2)))?
        .label("TCP error")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], COLOURS[0].stroke_width(2)));
    let end = t_range(series).end;
    chart
        .draw_series(LineSeries::new([(0.0, tcp_limit * 1e3), (end, tcp_limit * 1e3)], RED.stroke_width(2)))?
        .label("tcp_error_limit")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], RED.stroke_width(2)));
    chart.configure_series_labels().background_style(WHITE.mix(0.8)).border_style(BLACK).draw()?;
    root.present()?;
    Ok(())
}
