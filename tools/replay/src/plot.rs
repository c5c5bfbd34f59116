//! `strand-replay plot`: PNGs of a log with plotters — the planned and executed TCP path from
//! above, the TCP error, TCP speed and filament rate with their ratio, joint positions and velocities
//! against their limits, and the tick lateness histogram.

use std::path::{Path, PathBuf};

use plotters::prelude::*;
use strand_core::kin::RobotModel;

use super::Series;
use strand_cli::error::{Result, ToolError};

type PlotResult = Result<(), Box<dyn std::error::Error>>;

use strand::check::plot::register_font;

fn range(values: impl Iterator<Item = f64>) -> (f64, f64) {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in values.filter(|v| v.is_finite()) {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    if !lo.is_finite() {
        return (0.0, 1.0);
    }
    let pad = ((hi - lo) * 0.05).max(1e-9);
    (lo - pad, hi + pad)
}

/// Splits a series at NaN so lines do not bridge the gaps.
fn runs(points: impl Iterator<Item = (f64, f64)>) -> Vec<Vec<(f64, f64)>> {
    let mut out = vec![Vec::new()];
    for (x, y) in points {
        if x.is_finite() && y.is_finite() {
            out.last_mut().unwrap().push((x, y));
        } else if !out.last().unwrap().is_empty() {
            out.push(Vec::new());
        }
    }
    out.retain(|r| !r.is_empty());
    out
}

/// Keeps at most `n` points per series (plots of long logs stay quick and small).
fn stride(len: usize, n: usize) -> usize {
    len.div_ceil(n).max(1)
}

/// One picture drawn into the file it is given.
type Plotter<'a> = dyn Fn(&Path) -> PlotResult + 'a;

/// Draws every plot into `dir`; returns the files written.
pub fn plot_all(s: &Series, model: &RobotModel, dir: &Path) -> Result<Vec<PathBuf>> {
    register_font()?;
    std::fs::create_dir_all(dir).map_err(ToolError::file(dir))?;
    let mut files = Vec::new();
    let jobs: [(&str, &Plotter); 5] = [
        ("tcp_path_top.png", &|p| tcp_path(s, p)),
        ("tcp_error.png", &|p| tcp_error(s, p)),
        ("speed_flow.png", &|p| speed_flow(s, p)),
        ("joints.png", &|p| joints(s, model, p)),
        ("lateness.png", &|p| lateness(s, p)),
    ];
    for (name, draw) in jobs {
        let path = dir.join(name);
        draw(&path).map_err(ToolError::plot(&path))?;
        files.push(path);
    }
    Ok(files)
}

fn tcp_path(s: &Series, path: &Path) -> PlotResult {
    let root = BitMapBackend::new(path, (1000, 1000)).into_drawing_area();
    root.fill(&WHITE)?;
    let mm = |v: f64| v * 1e3;
    let xs =
        s.target.iter().map(|p| mm(p[0])).chain(s.actual.iter().zip(&s.target).filter(|(_, t)| t[0].is_finite()).map(|(a, _)| mm(a[0])));
    let ys =
        s.target.iter().map(|p| mm(p[1])).chain(s.actual.iter().zip(&s.target).filter(|(_, t)| t[0].is_finite()).map(|(a, _)| mm(a[1])));
    let (x0, x1) = range(xs);
    let (y0, y1) = range(ys);
    // Equal scales on both axes.
    let half = 0.5 * (x1 - x0).max(y1 - y0);
    let (cx, cy) = (0.5 * (x0 + x1), 0.5 * (y0 + y1));
    let mut chart = ChartBuilder::on(&root)
        .caption("TCP path, top view (world frame; while running)", ("sans-serif", 24))
        .margin(15)
        .x_label_area_size(45)
        .y_label_area_size(60)
        .build_cartesian_2d(cx - half..cx + half, cy - half..cy + half)?;
    chart.configure_mesh().x_desc("x (mm)").y_desc("y (mm)").draw()?;
    let k = stride(s.t.len(), 200_000);
    for (i, run) in runs(s.target.iter().step_by(k).map(|p| (mm(p[0]), mm(p[1])))).into_iter().enumerate() {
        let series = chart.draw_series(LineSeries::new(run, BLUE.stroke_width(2)))?;
        if i == 0 {
            series.label("planned (path target)").legend(|(x, y)| PathElement::new([(x, y), (x + 20, y)], BLUE.stroke_width(2)));
        }
    }
    let executed =
        s.actual.iter().zip(&s.target).step_by(k).map(|(a, t)| if t[0].is_finite() { (mm(a[0]), mm(a[1])) } else { (f64::NAN, f64::NAN) });
    for (i, run) in runs(executed).into_iter().enumerate() {
        let series = chart.draw_series(LineSeries::new(run, RED.stroke_width(1)))?;
        if i == 0 {
            series.label("executed (measured joints, FK)").legend(|(x, y)| PathElement::new([(x, y), (x + 20, y)], RED));
        }
    }
    chart.configure_series_labels().background_style(WHITE.mix(0.8)).border_style(BLACK).draw()?;
    root.present()?;
    Ok(())
}

fn tcp_error(s: &Series, path: &Path) -> PlotResult {
    let root = BitMapBackend::new(path, (1200, 500)).into_drawing_area();
    root.fill(&WHITE)?;
    let (t0, t1) = range(s.t.iter().copied());
    let (_, e1) = range(s.tcp_error.iter().map(|e| e * 1e3));
    let mut chart = ChartBuilder::on(&root)
        .caption("TCP error |target − executed| while running", ("sans-serif", 24))
        .margin(15)
        .x_label_area_size(45)
        .y_label_area_size(70)
        .build_cartesian_2d(t0..t1, 0.0..e1.max(1e-6))?;
    chart.configure_mesh().x_desc("time (s)").y_desc("error (mm)").draw()?;
    let k = stride(s.t.len(), 100_000);
    for run in runs(s.t.iter().zip(&s.tcp_error).step_by(k).map(|(t, e)| (*t, e * 1e3))) {
        chart.draw_series(LineSeries::new(run, RED))?;
    }
    root.present()?;
    Ok(())
}

fn speed_flow(s: &Series, path: &Path) -> PlotResult {
    let root = BitMapBackend::new(path, (1200, 900)).into_drawing_area();
    root.fill(&WHITE)?;
    let (upper, lower) = root.split_vertically(450);
    let (t0, t1) = range(s.t.iter().copied());
    let k = stride(s.t.len(), 100_000);
    let (_, v1) = range(s.path_speed.iter().map(|v| v * 1e3));
    let (_, f1) = range(s.filament_rate.iter().map(|v| v * 1e3));
    let mut chart = ChartBuilder::on(&upper)
        .caption("TCP path speed and filament rate", ("sans-serif", 24))
        .margin(15)
        .x_label_area_size(40)
        .y_label_area_size(70)
        .right_y_label_area_size(70)
        .build_cartesian_2d(t0..t1, 0.0..v1.max(1e-6))?
        .set_secondary_coord(t0..t1, 0.0..f1.max(1e-6));
    chart.configure_mesh().x_desc("time (s)").y_desc("path speed (mm/s)").draw()?;
    chart.configure_secondary_axes().y_desc("filament rate (mm/s)").draw()?;
    chart
        .draw_series(LineSeries::new(s.t.iter().zip(&s.path_speed).step_by(k).map(|(t, v)| (*t, v * 1e3)), BLUE))?
        .label("path speed")
        .legend(|(x, y)| PathElement::new([(x, y), (x + 20, y)], BLUE));
    chart
        .draw_secondary_series(LineSeries::new(s.t.iter().zip(&s.filament_rate).step_by(k).map(|(t, v)| (*t, v * 1e3)), GREEN))?
        .label("filament rate")
        .legend(|(x, y)| PathElement::new([(x, y), (x + 20, y)], GREEN));
    chart.configure_series_labels().background_style(WHITE.mix(0.8)).border_style(BLACK).draw()?;
    // Flow ratio: filament length per path length, where the path moves.
    let ratio: Vec<(f64, f64)> =
        s.t.iter()
            .zip(s.path_speed.iter().zip(&s.filament_rate))
            .step_by(k)
            .map(|(t, (v, f))| (*t, if *v > 1e-4 { f / v } else { f64::NAN }))
            .collect();
    let (r0, r1) = range(ratio.iter().map(|p| p.1));
    let mut chart = ChartBuilder::on(&lower)
        .caption("flow ratio: filament rate / path speed (where the path moves)", ("sans-serif", 20))
        .margin(15)
        .x_label_area_size(40)
        .y_label_area_size(70)
        .build_cartesian_2d(t0..t1, r0.min(0.0)..r1)?;
    chart.configure_mesh().x_desc("time (s)").y_desc("filament m per path m").draw()?;
    for run in runs(ratio.into_iter()) {
        chart.draw_series(LineSeries::new(run, MAGENTA))?;
    }
    root.present()?;
    Ok(())
}

fn joints(s: &Series, model: &RobotModel, path: &Path) -> PlotResult {
    let n = model.dof();
    let root = BitMapBackend::new(path, (1400, 220 * n as u32)).into_drawing_area();
    root.fill(&WHITE)?;
    let cells = root.split_evenly((n, 2));
    let (t0, t1) = range(s.t.iter().copied());
    let k = stride(s.t.len(), 50_000);
    for j in 0..n {
        let lim = model.limits(j);
        let name = &model.joints()[j].name;
        for (col, (values, lo, hi, what)) in
            [(&s.q[j], lim.lower, lim.upper, "position"), (&s.qd[j], -lim.velocity, lim.velocity, "velocity")].into_iter().enumerate()
        {
            let (mut y0, mut y1) = range(values.iter().copied());
            if lo.is_finite() && hi.is_finite() {
                y0 = y0.min(lo - 0.05 * (hi - lo));
                y1 = y1.max(hi + 0.05 * (hi - lo));
            }
            let mut chart = ChartBuilder::on(&cells[2 * j + col])
                .caption(format!("{name} {what} (limits dashed)"), ("sans-serif", 16))
                .margin(8)
                .x_label_area_size(25)
                .y_label_area_size(55)
                .build_cartesian_2d(t0..t1, y0..y1)?;
            chart.configure_mesh().max_light_lines(2).draw()?;
            chart.draw_series(LineSeries::new(s.t.iter().zip(values.iter()).step_by(k).map(|(t, v)| (*t, *v)), BLUE))?;
            for l in [lo, hi].into_iter().filter(|l| l.is_finite()) {
                chart.draw_series(DashedLineSeries::new([(t0, l), (t1, l)], 8, 5, RED.into()))?;
            }
        }
    }
    root.present()?;
    Ok(())
}

fn lateness(s: &Series, path: &Path) -> PlotResult {
    let root = BitMapBackend::new(path, (1100, 550)).into_drawing_area();
    root.fill(&WHITE)?;
    let timer = s.lateness_ns.iter().any(|v| *v > 0);
    let (values, what) = if timer { (&s.lateness_ns, "wake-up lateness") } else { (&s.step_ns, "step cost (no timer clock in this run)") };
    // Logarithmic bins from 0.1 µs to 100 ms, counts on a log axis.
    let bins = 60usize;
    let (lo, hi) = (1e-1f64, 1e5f64); // µs
    let mut counts = vec![0u64; bins];
    for v in values {
        let us = (*v as f64 / 1e3).max(lo);
        let b = (((us / lo).ln() / (hi / lo).ln()) * bins as f64) as usize;
        counts[b.min(bins - 1)] += 1;
    }
    let edge = |b: usize| lo * (hi / lo).powf(b as f64 / bins as f64);
    let max = counts.iter().copied().max().unwrap_or(1).max(1);
    let mut chart = ChartBuilder::on(&root)
        .caption(format!("tick {what}: {} ticks", values.len()), ("sans-serif", 22))
        .margin(15)
        .x_label_area_size(45)
        .y_label_area_size(70)
        .build_cartesian_2d((lo..hi).log_scale(), (0.5f64..(max as f64 * 2.0)).log_scale())?;
    chart.configure_mesh().x_desc("µs (log)").y_desc("ticks (log)").draw()?;
    chart.draw_series(
        counts
            .iter()
            .enumerate()
            .filter(|(_, c)| **c > 0)
            .map(|(b, c)| Rectangle::new([(edge(b), 0.5), (edge(b + 1), *c as f64)], BLUE.mix(0.6).filled())),
    )?;
    root.present()?;
    Ok(())
}
