//! `strand-bench clik`: our CLIK step against Pinocchio's damped-least-squares tick, in one run.
//!
//! Both sides track the same target table on the same robot: the iiwa7 (7 joints) and its 100 mm
//! tool, from q0 = [0.2, 0.6, −0.1, −1.3, 0.2, 0.9, 0.3] rad, a 20 mm circle in the world x-y plane
//! at 50 mm/s sampled at 1 kHz, orientation held (`benches/kin.rs` and `benches/pinocchio/` use the
//! same table). Ours is [`Clik::step`] in the 6-D task with the cell's settings — the SVD with its
//! singularity damping, the manipulability gradient in the null space, the joint-limit boxes; theirs
//! is Pinocchio's canonical DLS step (`benches/pinocchio/clik_dls.cpp`: FK, frame Jacobian, log6,
//! Jlog6, a 6 × 6 LDLT, integrate), which has none of those. Each tick is timed on its own with
//! `CLOCK_MONOTONIC` on both sides (the clock read is in both), after 10,000 warm-up ticks; the two
//! run in alternating rounds, so a noisy phase of a shared machine falls on both, and the ratio is
//! the median of the rounds' p50 ratios.

use std::path::PathBuf;
use std::process::Command;

use serde::{Deserialize, Serialize};
use strand::config::Config;
use strand::io::clock::monotonic_ns;
use strand_core::kin::{Clik, JointVector, RobotModel, Task, TcpTarget};

use super::Dist;
use super::circle::{IIWA_Q0, circle};
use strand_cli::error::{Result, ToolError};

/// Warm-up ticks before timing (count).
const WARM_UP: usize = 10_000;

/// What to run.
pub struct ClikOptions {
    /// The cell's service configuration (robot and `[clik]`); the robot must be a 7-joint arm.
    pub config: PathBuf,
    /// Timed ticks per round and side (count).
    pub ticks: usize,
    /// Rounds per side (count).
    pub rounds: usize,
    /// The Pinocchio bench binary (`benches/pinocchio/build.sh` builds it); none: ours alone.
    pub pinocchio: Option<PathBuf>,
}

/// One side's round.
#[derive(Debug, Serialize, Clone)]
pub struct Round {
    /// Per-tick cost (ns).
    #[serde(flatten)]
    pub cost: Dist,
    /// Mean per-tick cost (ns).
    pub mean_ns: f64,
    /// Largest distance between the tool point after a tick and that tick's target (m); ours leaves
    /// out the three ticks after the table wraps (see `strand_round`).
    pub max_position_error_m: f64,
    /// A baseline that times several of its library's solvers (KDL's): each one's p50 (ns); the
    /// figures above are the fastest's.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub solvers: Vec<(String, u64)>,
}

/// The report.
#[derive(Debug, Serialize)]
pub struct ClikReport {
    /// "clik".
    pub mode: &'static str,
    /// Our per-tick cost over all rounds (ns).
    #[serde(flatten)]
    pub total: Dist,
    /// The robot's name.
    pub robot: String,
    /// Joints (count).
    pub dof: usize,
    /// Timed ticks per round and side (count).
    pub ticks: usize,
    /// Our rounds.
    pub strand: Vec<Round>,
    /// Pinocchio's rounds (empty without `--pinocchio`).
    pub pinocchio: Vec<Round>,
    /// Pinocchio's version, as its bench reports it.
    pub pinocchio_version: Option<String>,
    /// Median over the rounds of (our p50 / Pinocchio's p50); none without `--pinocchio`.
    pub p50_ratio: Option<f64>,
    /// The same for the means.
    pub mean_ratio: Option<f64>,
}

/// The exact percentiles of `samples` (ns), sorted here.
fn dist(samples: &mut [u64]) -> (Dist, f64) {
    samples.sort_unstable();
    let at = |p: f64| samples[((p / 100.0 * samples.len() as f64).ceil() as usize).clamp(1, samples.len()) - 1];
    let mean = samples.iter().sum::<u64>() as f64 / samples.len() as f64;
    let d = Dist {
        samples: samples.len() as u64,
        p50_ns: at(50.0),
        p99_ns: at(99.0),
        p999_ns: at(99.9),
        p9999_ns: at(99.99),
        max_ns: at(100.0),
    };
    (d, mean)
}

/// One round of ours: warm-up, then `ticks` timed steps; the error is checked on the timed ones.
fn strand_round(model: &RobotModel, solver: &mut Clik, targets: &[TcpTarget], q0: &JointVector, ticks: usize, all: &mut Vec<u64>) -> Round {
    let mut q = *q0;
    let mut k = 0usize;
    for _ in 0..WARM_UP {
        q = solver.step(model, &q, &targets[k], 1e-3).q;
        k = (k + 1) % targets.len();
    }
    let mut samples = vec![0u64; ticks];
    let mut worst: f64 = 0.0;
    for sample in samples.iter_mut() {
        let begin = monotonic_ns();
        let step = solver.step(model, std::hint::black_box(&q), &targets[k], 1e-3);
        *sample = monotonic_ns() - begin;
        q = step.q;
        // The table wraps with a jump of 0.27 tick (its period is 2513.27 ticks): our step holds
        // the joints' acceleration limits and takes three ticks to catch it (9 µm behind at most),
        // where Pinocchio's unlimited Newton step jumps. Those ticks are not tracking error.
        if k >= 3 {
            worst = worst.max((model.forward_kinematics(&q).translation.vector - targets[k].position).norm());
        }
        k = (k + 1) % targets.len();
    }
    all.extend_from_slice(&samples);
    let (cost, mean_ns) = dist(&mut samples);
    Round { cost, mean_ns, max_position_error_m: worst, solvers: Vec::new() }
}

/// A baseline bench's JSON line (`benches/pinocchio/`, `benches/kdl/`): its library's version and
/// its per-tick cost.
#[derive(Deserialize)]
struct BaselineLine {
    #[serde(alias = "pinocchio_version", alias = "kdl_version")]
    version: String,
    ticks: u64,
    p50_ns: u64,
    p99_ns: u64,
    p999_ns: u64,
    p9999_ns: u64,
    max_ns: u64,
    mean_ns: f64,
    max_position_error_m: f64,
    /// KDL's bench: its two solvers' p50s (ns).
    #[serde(default)]
    pinv_p50_ns: Option<u64>,
    #[serde(default)]
    wdls_p50_ns: Option<u64>,
}

/// One round of a baseline's CLIK bench (Pinocchio's, KDL's), as a child process given the URDF
/// and the tick count: its cost and its library's version.
pub(crate) fn baseline_round(bin: &std::path::Path, urdf: &std::path::Path, ticks: usize) -> Result<(Round, String)> {
    let out = Command::new(bin)
        .arg(urdf)
        .arg(ticks.to_string())
        .output()
        .map_err(|e| ToolError::Measurement(format!("cannot run the baseline bench {}: {e}", bin.display())))?;
    if !out.status.success() {
        return Err(ToolError::Measurement(format!(
            "the baseline bench {} failed ({}): {}",
            bin.display(),
            out.status,
            String::from_utf8_lossy(&out.stderr).trim()
        )));
    }
    let text = String::from_utf8_lossy(&out.stdout);
    let line: BaselineLine = text
        .lines()
        .find_map(|l| serde_json::from_str(l).ok())
        .ok_or_else(|| ToolError::Measurement(format!("the baseline bench printed no result line: {text}")))?;
    let cost = Dist {
        samples: line.ticks,
        p50_ns: line.p50_ns,
        p99_ns: line.p99_ns,
        p999_ns: line.p999_ns,
        p9999_ns: line.p9999_ns,
        max_ns: line.max_ns,
    };
    let solvers = [("pinv", line.pinv_p50_ns), ("wdls", line.wdls_p50_ns)]
        .into_iter()
        .filter_map(|(name, p50)| p50.map(|p| (name.to_string(), p)))
        .collect();
    Ok((Round { cost, mean_ns: line.mean_ns, max_position_error_m: line.max_position_error_m, solvers }, line.version))
}

pub(crate) fn median(mut v: Vec<f64>) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    let n = v.len();
    Some(if n % 2 == 1 { v[n / 2] } else { 0.5 * (v[n / 2 - 1] + v[n / 2]) })
}

/// Runs the rounds, ours first in each.
pub fn run(opts: &ClikOptions) -> Result<ClikReport> {
    let cfg = Config::load(&opts.config)?;
    let model = cfg.robot.build_model()?;
    if model.dof() != IIWA_Q0.len() {
        return Err(ToolError::Measurement(format!("{}: the CLIK bench wants a 7-joint arm, this one has {}", model.name(), model.dof())));
    }
    let mut q0 = JointVector::zeros();
    q0.as_mut_slice()[..IIWA_Q0.len()].copy_from_slice(&IIWA_Q0);
    let targets = circle(&model, &q0);
    let settings = cfg.controller_settings();
    let clik_config = strand_core::kin::ClikConfig { task: Task::Pose6, ..settings.clik };
    let urdf = cfg.robot.urdf_path();
    let (mut strand, mut pinocchio, mut version, mut all) = (Vec::new(), Vec::new(), None, Vec::new());
    for _ in 0..opts.rounds.max(1) {
        let mut solver = Clik::new(clik_config)?;
        strand.push(strand_round(&model, &mut solver, &targets, &q0, opts.ticks.max(1), &mut all));
        if let Some(bin) = &opts.pinocchio {
            let (round, v) = baseline_round(bin, &urdf, opts.ticks.max(1))?;
            pinocchio.push(round);
            version = Some(v);
        }
    }
    let ratios = |f: fn(&Round) -> f64| median(strand.iter().zip(&pinocchio).map(|(a, b)| f(a) / f(b)).collect());
    Ok(ClikReport {
        mode: "clik",
        total: dist(&mut all).0,
        robot: model.name().to_string(),
        dof: model.dof(),
        ticks: opts.ticks,
        p50_ratio: ratios(|r| r.cost.p50_ns as f64),
        mean_ratio: ratios(|r| r.mean_ns),
        strand,
        pinocchio,
        pinocchio_version: version,
    })
}

/// Writes the report as a table.
pub fn print(r: &ClikReport) {
    println!("CLIK tick, {} ({} joints), 6-D task, {} timed ticks a round after {WARM_UP} warm-up (ns)", r.robot, r.dof, r.ticks);
    println!("{:<34} {:>8} {:>8} {:>9} {:>14}", "round", "p50", "p99", "mean", "max error (m)");
    for (k, s) in r.strand.iter().enumerate() {
        println!(
            "{:<34} {:>8} {:>8} {:>9.1} {:>14.2e}",
            format!("strand Clik::step, round {}", k + 1),
            s.cost.p50_ns,
            s.cost.p99_ns,
            s.mean_ns,
            s.max_position_error_m
        );
        if let Some(p) = r.pinocchio.get(k) {
            let name = format!("Pinocchio {} DLS, round {}", r.pinocchio_version.as_deref().unwrap_or("?"), k + 1);
            println!("{:<34} {:>8} {:>8} {:>9.1} {:>14.2e}", name, p.cost.p50_ns, p.cost.p99_ns, p.mean_ns, p.max_position_error_m);
        }
    }
    if let (Some(p50), Some(mean)) = (r.p50_ratio, r.mean_ratio) {
        println!("strand / Pinocchio: {p50:.2}× at p50, {mean:.2}× in the mean (median of the rounds)");
    }
}

impl ClikReport {
    /// Sane distributions, and both sides tracking their targets (within 1 µm).
    pub fn check(&self) -> Result<()> {
        for (side, rounds) in [("strand", &self.strand), ("Pinocchio", &self.pinocchio)] {
            for round in rounds {
                if round.cost.samples == 0 || round.cost.p50_ns == 0 || round.cost.p50_ns > round.cost.p99_ns {
                    return Err(ToolError::Measurement(format!("{side}: implausible distribution {:?}", round.cost)));
                }
                if round.max_position_error_m.is_nan() || round.max_position_error_m >= 1e-6 {
                    return Err(ToolError::Measurement(format!("{side} does not track: error {:e} m", round.max_position_error_m)));
                }
            }
        }
        Ok(())
    }
}
