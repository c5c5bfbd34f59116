//! The bead drawn: each 1 mm bin where it lies on the part (top view), coloured by its error, and
//! the histogram of the errors.

use std::path::{Path, PathBuf};

use plotters::prelude::*;

use super::{Bead, FLAW};
use strand_cli::error::{Result, ToolError};

type PlotResult = std::result::Result<(), Box<dyn std::error::Error>>;

/// Colour of a signed relative error: blue starved, green on the program, red over-extruded,
/// saturated at ±[`FLAW`] (10 %).
fn colour(error: f64) -> RGBColor {
    let x = (error / FLAW).clamp(-1.0, 1.0);
    let (green, end) = ([0.2, 0.7, 0.2], if x < 0.0 { [0.1, 0.2, 0.95] } else { [0.9, 0.1, 0.1] });
    let mix = |k: usize| ((green[k] + (end[k] - green[k]) * x.abs()) * 255.0) as u8;
    RGBColor(mix(0), mix(1), mix(2))
}

fn path_plot(bead: &Bead, file: &Path) -> PlotResult {
    let root = BitMapBackend::new(file, (1000, 1000)).into_drawing_area();
    root.fill(&WHITE)?;
    let xs = bead.bins.iter().map(|b| b.at.x * 1e3);
    let ys = bead.bins.iter().map(|b| b.at.y * 1e3);
    let (x0, x1) = xs.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| (a.min(v), b.max(v)));
    let (y0, y1) = ys.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| (a.min(v), b.max(v)));
    let span = (x1 - x0).max(y1 - y0).max(1.0) * 1.05;
    let (cx, cy) = (0.5 * (x0 + x1), 0.5 * (y0 + y1));
    let mut chart = ChartBuilder::on(&root)
        .caption(
            format!(
                "bead error per 1 mm bin (blue −10 %, green 0, red +10 %): p95 {:.1} %, {:.2} % beyond ±10 %",
                bead.all.p95 * 100.0,
                bead.all.beyond_10pct * 100.0
            ),
            ("sans-serif", 20),
        )
        .margin(15)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d((cx - span / 2.0)..(cx + span / 2.0), (cy - span / 2.0)..(cy + span / 2.0))?;
    chart.configure_mesh().x_desc("x (mm, W)").y_desc("y (mm, W)").draw()?;
    // The worst on top.
    let mut bins: Vec<_> = bead.bins.iter().collect();
    bins.sort_by(|a, b| a.error.abs().total_cmp(&b.error.abs()));
    chart.draw_series(bins.iter().map(|b| Circle::new((b.at.x * 1e3, b.at.y * 1e3), 3, colour(b.error).filled())))?;
    root.present()?;
    Ok(())
}

fn histogram(bead: &Bead, file: &Path) -> PlotResult {
    let root = BitMapBackend::new(file, (1000, 600)).into_drawing_area();
    root.fill(&WHITE)?;
    // 0.5 % buckets from −20 % to +20 %; beyond into the end buckets.
    let buckets = 80usize;
    let mut counts = vec![0u32; buckets];
    for b in &bead.bins {
        let k = ((b.error * 100.0 + 20.0) / 0.5).floor().clamp(0.0, (buckets - 1) as f64) as usize;
        counts[k] += 1;
    }
    let top = counts.iter().copied().max().unwrap_or(1).max(1);
    let mut chart = ChartBuilder::on(&root)
        .caption(format!("bead error, {} bins of 1 mm (ends hold everything beyond ±20 %)", bead.bins.len()), ("sans-serif", 20))
        .margin(15)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(-20.0..20.0, 0u32..(top + top / 10 + 1))?;
    chart.configure_mesh().x_desc("deposited against the program (%)").y_desc("bins").draw()?;
    chart.draw_series(counts.iter().enumerate().map(|(k, &n)| {
        let x = -20.0 + k as f64 * 0.5;
        Rectangle::new([(x, 0), (x + 0.5, n)], colour((x + 0.25) / 100.0).filled())
    }))?;
    root.present()?;
    Ok(())
}

/// Draws `bead_path.png` and `bead_histogram.png` into `dir`.
pub fn plot(bead: &Bead, dir: &Path) -> Result<Vec<PathBuf>> {
    strand::check::plot::register_font()?;
    std::fs::create_dir_all(dir).map_err(ToolError::file(dir))?;
    let mut files = Vec::new();
    for (name, draw) in [("bead_path.png", path_plot as fn(&Bead, &Path) -> PlotResult), ("bead_histogram.png", histogram)] {
        let file = dir.join(name);
        draw(bead, &file).map_err(ToolError::plot(&file))?;
        files.push(file);
    }
    Ok(files)
}
