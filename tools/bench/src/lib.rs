//! strand-bench's measurement kit: every figure is a distribution (p50, p99, p99.9, p99.99, max) and,
//! where there is one, it stands next to a baseline measured in the same run on the same machine,
//! because absolute times on a shared machine mean little. The modes live in their own modules:
//! [`jitter`] (wake-up lateness of the cycle runner against a bare `clock_nanosleep` loop and
//! cyclictest), [`latency`] (state in → command out against an iceoryx2 ping-pong), [`tick`] (cost
//! per stage of one controller tick, allocations counted), [`log`] (the MCAP logger at a control
//! rate). `strand-bench`'s main only parses the command line and prints.

pub mod circle;
pub mod clik;
pub mod driver;
pub mod jitter;
pub mod latency;
pub mod log;
pub mod tick;

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};

use plotters::prelude::*;
use serde::Serialize;
use strand::config::Config;
use strand::io::histogram::Histogram;
use strand_ipc as ipc;
use strand_ipc::ServiceNames;
use strand_ipc::ports::{ClientPorts, ClientRoles};

use strand_cli::error::{Result, ToolError};
use strand_feed::{Job, batch, credit, load_gcode};

/// The job a loaded controller prints in `jitter` and `latency`: 004's 35 mm box (PrusaSlicer),
/// 16 k segments, 21 minutes of printing, far longer than any benchmark run.
pub(crate) fn bench_job(root: &Path, cfg: &Config) -> Result<Job> {
    load_gcode(&root.join(BENCH_JOB), cfg, None)
}

/// [`bench_job`]'s program, relative to the repository root.
pub(crate) const BENCH_JOB: &str = "tests/data/gcode/prusaslicer/box35.gcode";

/// The folder [`BENCH_JOB`] is relative to: the repository root when the working directory is
/// one, else the built-in copy ([`strand_cli::jobs::root`]).
pub fn repo_root() -> Result<PathBuf> {
    Ok(strand_cli::jobs::root()?)
}

/// Streams `job` to the service under `prefix` within its Status credit (a feeder, as strand-feed
/// is), sends Start after the first batch, and returns when `stop` is set: the segments sent.
pub(crate) fn stream_job(prefix: &str, job: &Job, stop: &AtomicBool) -> Result<usize> {
    let ports = ClientPorts::open(
        &ServiceNames::new(prefix),
        &format!("strand-bench-feed-{}", std::process::id()),
        ClientRoles { feeder: true, monitor: true, ..Default::default() },
    )?;
    let (first, last) = (job.segments[0].seq, job.segments[job.segments.len() - 1].seq);
    let (mut sent, mut started, mut batch_seq) = (0usize, false, 0u64);
    while !stop.load(Ordering::Relaxed) {
        let _ = ports.wait_status(10_000_000);
        let Some(status) = ports.latest_status() else { continue };
        let allowed = (credit(&status, first, last, started) as usize).min(job.segments.len());
        while sent < allowed {
            let n = (allowed - sent).min(ipc::SEGMENT_BATCH_CAPACITY);
            batch_seq += 1;
            if ports.send_segments(&batch(&job.segments[sent..sent + n], batch_seq))? == 0 {
                break; // nobody subscribed yet: not delivered, so resend later
            }
            sent += n;
        }
        if !started && sent > 0 {
            let start = ipc::Control {
                seq: 1,
                stamp_ns: strand::io::clock::monotonic_ns(),
                command: ipc::Command::Start as u32,
                value: 0.0,
                _reserved: 0,
            };
            ports.send_control(&start)?;
            started = true;
        }
    }
    Ok(sent)
}

/// A distribution of durations (ns), as `--json` prints it.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct Dist {
    /// Number of samples.
    pub samples: u64,
    /// Median (ns).
    pub p50_ns: u64,
    /// 99th percentile (ns).
    pub p99_ns: u64,
    /// 99.9th percentile (ns).
    pub p999_ns: u64,
    /// 99.99th percentile (ns).
    pub p9999_ns: u64,
    /// Largest sample (ns).
    pub max_ns: u64,
}

impl Dist {
    /// The percentiles of a histogram (bucket upper bounds: within the histogram's 1/64 relative
    /// resolution, never below the true value).
    pub fn of(h: &Histogram) -> Dist {
        Dist {
            samples: h.count(),
            p50_ns: h.percentile(50.0),
            p99_ns: h.percentile(99.0),
            p999_ns: h.percentile(99.9),
            p9999_ns: h.percentile(99.99),
            max_ns: h.max(),
        }
    }

    /// Samples exist, the percentiles are positive and in order, and none passes the max.
    pub(crate) fn is_sane(&self) -> bool {
        self.samples > 0
            && self.p50_ns > 0
            && self.p50_ns <= self.p99_ns
            && self.p99_ns <= self.p999_ns
            && self.p999_ns <= self.p9999_ns
            && self.p9999_ns <= self.max_ns
    }

    /// An error naming `what` unless [`Dist::is_sane`].
    pub fn check(&self, what: &str) -> Result<()> {
        if self.is_sane() { Ok(()) } else { Err(ToolError::Measurement(format!("{what}: implausible distribution {self:?}"))) }
    }

    /// One table row: the name, then p50 … max in µs.
    pub fn row(&self, name: &str) -> String {
        let us = |v: u64| v as f64 * 1e-3;
        format!(
            "{name:<40} {:>9.2} {:>9.2} {:>9.2} {:>9.2} {:>9.2} {:>10}",
            us(self.p50_ns),
            us(self.p99_ns),
            us(self.p999_ns),
            us(self.p9999_ns),
            us(self.max_ns),
            self.samples
        )
    }

    /// The table's header, matching [`Dist::row`].
    pub fn header(title: &str) -> String {
        format!("{title:<40} {:>9} {:>9} {:>9} {:>9} {:>9} {:>10}", "p50 µs", "p99 µs", "p99.9 µs", "p99.99 µs", "max µs", "samples")
    }
}

/// `a / b` for a figure against its baseline (0 when the baseline is 0).
pub fn ratio(a: u64, b: u64) -> f64 {
    if b == 0 { 0.0 } else { a as f64 / b as f64 }
}

/// Draws the histograms of `series` (name, histogram) into a PNG: x the duration (µs, log scale), y the
/// count per bucket (log scale), one line per series, so a measurement and its baseline overlay.
pub(crate) fn plot_histograms(path: &Path, title: &str, series: &[(&str, &Histogram)]) -> Result<()> {
    let buckets: Vec<Vec<(f64, f64)>> = series
        .iter()
        .map(|(_, h)| h.iter_buckets().map(|(lo, hi, c)| (((lo + hi) as f64 * 0.5 * 1e-3).max(1e-3), c as f64)).collect())
        .collect();
    let all = buckets.iter().flatten();
    let x_max = all.clone().map(|p| p.0).fold(1.0, f64::max) * 1.5;
    let x_min = all.clone().map(|p| p.0).fold(f64::INFINITY, f64::min).min(x_max / 10.0) / 1.5;
    let y_max = all.map(|p| p.1).fold(1.0, f64::max) * 2.0;
    strand::check::plot::register_font()?;
    let root = BitMapBackend::new(path, (1000, 560)).into_drawing_area();
    let err = |e: &dyn std::fmt::Display| ToolError::Plot { path: path.to_path_buf(), why: e.to_string() };
    root.fill(&WHITE).map_err(|e| err(&e))?;
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 22))
        .margin(12)
        .x_label_area_size(44)
        .y_label_area_size(64)
        .build_cartesian_2d((x_min..x_max).log_scale(), (0.5..y_max).log_scale())
        .map_err(|e| err(&e))?;
    chart.configure_mesh().x_desc("duration (µs)").y_desc("count per bucket").draw().map_err(|e| err(&e))?;
    let colours = [RED, BLUE, GREEN, MAGENTA, CYAN, BLACK];
    for (k, ((name, _), points)) in series.iter().zip(&buckets).enumerate() {
        let colour = colours[k % colours.len()];
        chart
            .draw_series(LineSeries::new(points.iter().copied(), colour.stroke_width(2)))
            .map_err(|e| err(&e))?
            .label(*name)
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], colour.stroke_width(2)));
    }
    chart.configure_series_labels().background_style(WHITE.mix(0.8)).border_style(BLACK).draw().map_err(|e| err(&e))?;
    root.present().map_err(|e| err(&e))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Against known distributions: uniform 1..=100 000 ns and an exponential with mean 10 µs.
    #[test]
    fn dist_matches_known_distributions() {
        let mut h = Histogram::new();
        for v in 1..=100_000u64 {
            h.record(v);
        }
        let d = Dist::of(&h);
        assert_eq!(d.samples, 100_000);
        let near = |got: u64, want: f64| (got as f64 - want).abs() <= want / 32.0;
        assert!(near(d.p50_ns, 50_000.0), "{d:?}");
        assert!(near(d.p99_ns, 99_000.0), "{d:?}");
        assert!(near(d.p999_ns, 99_900.0), "{d:?}");
        assert_eq!(d.max_ns, 100_000);
        assert!(d.is_sane());
        // Exponential, mean 10 µs: the p-quantile is −10 µs · ln(1 − p).
        let mut h = Histogram::new();
        let n = 1_000_000u64;
        for k in 0..n {
            let u = (k as f64 + 0.5) / n as f64;
            h.record((-10_000.0 * (1.0 - u).ln()) as u64 + 1);
        }
        let d = Dist::of(&h);
        for (got, p) in [(d.p50_ns, 0.5), (d.p99_ns, 0.99), (d.p999_ns, 0.999), (d.p9999_ns, 0.9999)] {
            let want = -10_000.0 * (1.0f64 - p).ln();
            assert!(near(got, want), "p{p}: {got} vs {want}");
        }
        assert!(d.is_sane());
        assert!(!Dist::default().is_sane());
        assert!(!Dist { samples: 3, p50_ns: 5, p99_ns: 4, p999_ns: 6, p9999_ns: 7, max_ns: 8 }.is_sane());
    }

    #[test]
    fn histogram_plot_writes_a_png() {
        let mut a = Histogram::new();
        let mut b = Histogram::new();
        for v in 0..10_000u64 {
            a.record(1_000 + v % 500);
            b.record(2_000 + v % 900);
        }
        let path = std::env::temp_dir().join(format!("strand-bench-plot-{}.png", std::process::id()));
        plot_histograms(&path, "test", &[("a", &a), ("b", &b)]).unwrap();
        assert!(std::fs::metadata(&path).unwrap().len() > 1000);
        let _ = std::fs::remove_file(&path);
    }
}
