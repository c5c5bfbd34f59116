//! The `--png` figure: each path drawn in the (u, v) plane side by side with its self-intersections marked.
//! Apart so that plotters is used in one place only.

use std::path::Path;

use plotters::prelude::*;

use super::{Contact, ContactKind, PlannedPath, PointCloud};
use strand_cli::error::{Result, ToolError};

/// One panel of the figure.
pub struct Panel<'a> {
    /// The path.
    pub path: &'a PlannedPath,
    /// Its self-intersections.
    pub contacts: &'a [Contact],
}

/// Draws each path in the (u, v) plane side by side, samples as dots, the start as a green dot, proper
/// crossings as red circles and touchings as orange ones.
pub fn plot_png(file: &Path, title: &str, labels: (&str, &str), cloud: &PointCloud, panels: &[Panel]) -> Result<()> {
    strand::check::plot::register_font()?;
    draw(file, title, labels, cloud, panels).map_err(|e| ToolError::Plan(format!("{}: {e}", file.display())))
}

fn draw(file: &Path, title: &str, labels: (&str, &str), cloud: &PointCloud, panels: &[Panel]) -> Result<(), Box<dyn std::error::Error>> {
    let k = panels.len().max(1);
    let root = BitMapBackend::new(file, (560 * k as u32, 640)).into_drawing_area();
    root.fill(&WHITE)?;
    let root = root.titled(title, ("sans-serif", 24))?;
    let cells = root.split_evenly((1, k));
    let (mut u0, mut u1, mut v0, mut v1) = (f64::INFINITY, f64::NEG_INFINITY, f64::INFINITY, f64::NEG_INFINITY);
    for s in &cloud.samples {
        (u0, u1, v0, v1) = (u0.min(s.u), u1.max(s.u), v0.min(s.v), v1.max(s.v));
    }
    if !u0.is_finite() {
        (u0, u1, v0, v1) = (0.0, 1.0, 0.0, 1.0);
    }
    let (pu, pv) = (0.04 * (u1 - u0).max(1e-9), 0.04 * (v1 - v0).max(1e-9));
    for (area, panel) in cells.iter().zip(panels) {
        let p = panel.path;
        let proper = panel.contacts.iter().filter(|c| c.kind == ContactKind::Proper).count();
        let caption = format!(
            "{}: {:.3} m, {} self-int. ({} crossing), {:.3} s",
            p.algorithm.name(),
            p.length,
            panel.contacts.len(),
            proper,
            p.compute_s
        );
        let mut chart = ChartBuilder::on(area)
            .caption(caption, ("sans-serif", 16))
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(60)
            .build_cartesian_2d(u0 - pu..u1 + pu, v0 - pv..v1 + pv)?;
        chart.configure_mesh().x_desc(labels.0).y_desc(labels.1).light_line_style(WHITE).draw()?;
        // One line per run between steps across a periodic seam (those would span the plot).
        let mut start = 0;
        for k in 1..=p.order.len() {
            if k == p.order.len() || cloud.crosses_seam(p.order[k - 1], p.order[k]) {
                let run = p.order[start..k].iter().map(|&i| (cloud.samples[i].u, cloud.samples[i].v));
                chart.draw_series(LineSeries::new(run, BLUE.stroke_width(1)))?;
                start = k;
            }
        }
        chart.draw_series(cloud.samples.iter().map(|s| Circle::new((s.u, s.v), 2, BLACK.filled())))?;
        if let Some(&first) = p.order.first() {
            let s = &cloud.samples[first];
            chart.draw_series(std::iter::once(Circle::new((s.u, s.v), 6, GREEN.filled())))?;
        }
        chart.draw_series(panel.contacts.iter().map(|c| {
            let colour = if c.kind == ContactKind::Proper { RED } else { RGBColor(255, 140, 0) };
            Circle::new(c.at, 7, colour.stroke_width(2))
        }))?;
    }
    root.present()?;
    Ok(())
}
