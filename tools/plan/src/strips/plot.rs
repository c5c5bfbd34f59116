//! The `--png` figure like 000's Fig. 13: the nominal job from above beside the split job layer by layer.
//! Apart so that plotters is used in one place only.

use std::path::Path;

use plotters::prelude::*;

use super::{Axis, Job, Plan};
use strand_cli::error::{Result, ToolError};

type PlotResult = Result<(), Box<dyn std::error::Error>>;

/// Colour of strip `k`, shaded by path `j`: 000's blue, green, orange, then more hues.
fn colour(k: usize, j: usize) -> HSLColor {
    const HUES: [f64; 6] = [0.60, 0.33, 0.08, 0.0, 0.78, 0.50];
    let lightness = 0.28 + 0.08 * (j % 5) as f64;
    HSLColor(HUES[k % HUES.len()], 0.85, lightness)
}

/// Layers shown in the split view: all if there are at most four, else four spread from first to last.
fn shown_layers(n: usize) -> Vec<usize> {
    if n <= 4 { (0..n).collect() } else { (0..4).map(|i| i * (n - 1) / 3).collect() }
}

/// PNG like 000's Fig. 13: the nominal job from above (left), and the split job layer by layer
/// (right; one colour per strip, a shade per path, the nominal boundaries dashed).
pub fn plot_png(job: &Job, plan: &Plan, path: &Path) -> Result<()> {
    strand::check::plot::register_font()?;
    draw(job, plan, path).map_err(|e| ToolError::Plan(format!("{}: {e}", path.display())))
}

fn draw(job: &Job, plan: &Plan, path: &Path) -> PlotResult {
    let root = BitMapBackend::new(path, (1800, 1000)).into_drawing_area();
    root.fill(&WHITE)?;
    let (left, right) = root.split_horizontally(800);
    let (mut x0, mut x1, mut y0, mut y1) = (f64::INFINITY, f64::NEG_INFINITY, f64::INFINITY, f64::NEG_INFINITY);
    for l in job.lines() {
        for p in [l.a, l.b] {
            x0 = x0.min(p.x * 1e3);
            x1 = x1.max(p.x * 1e3);
            y0 = y0.min(p.y * 1e3);
            y1 = y1.max(p.y * 1e3);
        }
    }
    let pad = 0.04 * (x1 - x0).max(y1 - y0).max(1e-3);
    let (x0, x1, y0, y1) = (x0 - pad, x1 + pad, y0 - pad, y1 + pad);
    let boundary_lines = |k: usize| -> Vec<(f64, f64)> {
        let b = plan.bounds[k] * 1e3;
        match plan.axis {
            Axis::X => vec![(b, y0), (b, y1)],
            Axis::Y => vec![(x0, b), (x1, b)],
        }
    };
    let mut chart = ChartBuilder::on(&left)
        .caption(format!("nominal job: {} layers, {} lines", job.layers.len(), job.lines().count()), ("sans-serif", 22))
        .margin(15)
        .x_label_area_size(40)
        .y_label_area_size(55)
        .build_cartesian_2d(x0..x1, y0..y1)?;
    chart.configure_mesh().x_desc("x (mm)").y_desc("y (mm)").max_light_lines(0).draw()?;
    for layer in &job.layers {
        for l in &layer.lines {
            chart.draw_series(LineSeries::new([(l.a.x * 1e3, l.a.y * 1e3), (l.b.x * 1e3, l.b.y * 1e3)], RGBColor(30, 60, 160)))?;
        }
    }
    for k in 1..plan.bounds.len() - 1 {
        chart.draw_series(DashedLineSeries::new(boundary_lines(k), 8, 6, BLACK.into()))?;
    }
    let shown = shown_layers(plan.layers);
    let cols = if shown.len() > 1 { 2 } else { 1 };
    let rows = shown.len().div_ceil(cols);
    let cells = right.split_evenly((rows, cols));
    for (cell, &i) in cells.iter().zip(&shown) {
        let shift = (plan.layers - 1 - i) as f64 * plan.overlap * 1e3;
        let paths: usize = plan.strips.iter().flat_map(|s| s.layers.iter().filter(|l| l.layer == i)).map(|l| l.paths.len()).sum();
        let mut chart = ChartBuilder::on(cell)
            .caption(format!("split, layer {} of {}: boundaries +{shift:.1} mm, {paths} paths", i + 1, plan.layers), ("sans-serif", 18))
            .margin(10)
            .x_label_area_size(30)
            .y_label_area_size(45)
            .build_cartesian_2d(x0..x1, y0..y1)?;
        chart.configure_mesh().max_light_lines(0).draw()?;
        for (k, strip) in plan.strips.iter().enumerate() {
            for sl in strip.layers.iter().filter(|l| l.layer == i) {
                for (j, p) in sl.paths.iter().enumerate() {
                    let mut pts = vec![(p[0].a.x * 1e3, p[0].a.y * 1e3)];
                    pts.extend(p.iter().map(|l| (l.b.x * 1e3, l.b.y * 1e3)));
                    chart.draw_series(LineSeries::new(pts, colour(k, j).stroke_width(2)))?;
                }
            }
        }
        for k in 1..plan.bounds.len() - 1 {
            chart.draw_series(DashedLineSeries::new(boundary_lines(k), 6, 6, BLACK.into()))?;
        }
    }
    root.present()?;
    Ok(())
}
