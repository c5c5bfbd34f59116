//! strand-replay: what a log says. `verify` re-runs every logged tick through `Controller::step`
//! and checks the outputs to the bit; `info` summarises a run; `export` writes one CSV per channel;
//! `plot` draws PNGs; `recover` rewrites a log that a crash cut short into a valid, indexed file;
//! `regenerate` writes a log's derived channels at every tick again.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand};
use strand::log::replay::{Verdict, verify};
use strand_cli::error::ToolError;
use strand_replay::bead;
use strand_replay::{open_all, plot as replay_plot};

#[derive(Parser)]
#[command(name = "strand-replay", version, about = "Replay, summarise, export, plot and recover strand MCAP logs")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Re-run every logged tick and compare with the logged outputs: prints `identical (N ticks)` or
    /// the first divergent tick and field; exit 0 if identical, 1 if not, 2 if the log cannot be read.
    Verify {
        /// The log, or its rotated parts in order.
        #[arg(required = true)]
        files: Vec<PathBuf>,
    },
    /// Duration, ticks, rate, drops, overruns, faults, segments, job outcome, TCP error.
    Info {
        /// The log, or its rotated parts in order.
        #[arg(required = true)]
        files: Vec<PathBuf>,
    },
    /// One CSV per channel.
    Export {
        /// The log, or its rotated parts in order.
        #[arg(required = true)]
        files: Vec<PathBuf>,
        /// Output folder.
        #[arg(long)]
        csv: PathBuf,
    },
    /// PNG plots: TCP path (top view), TCP error, speed and flow, joints against limits, lateness;
    /// with `--truth`, the bead along the path (colour = error per 1 mm bin) and its histogram.
    Plot {
        /// The log, or its rotated parts in order.
        #[arg(required = true)]
        files: Vec<PathBuf>,
        /// Output folder.
        #[arg(long)]
        out: PathBuf,
        /// The run's truth (`strand-sim --truth`, or a measurement with the same columns): adds the
        /// bead plots and prints the bead figures.
        #[arg(long)]
        truth: Option<PathBuf>,
        /// The G-code the run printed, for the bead per feature (`;TYPE:` tags).
        #[arg(long, requires = "truth")]
        gcode: Option<PathBuf>,
    },
    /// The hot end's lag and the arm's delay from a run and its truth (or a measurement of the melt
    /// flow and the nozzle): prints the `[extruder]` values to set.
    Calibrate {
        /// The log.
        file: PathBuf,
        /// The run's truth (`strand-sim --truth`), or a measurement with the same columns.
        #[arg(long)]
        truth: PathBuf,
        /// One JSON object instead of the TOML lines.
        #[arg(long)]
        json: bool,
    },
    /// Rewrite a run's log (its rotated parts in order) into one file with every channel at every
    /// tick and the full replay record (`/strand/tick`, every output whole): the service writes the
    /// derived channels (`/joint_states`, `/tcp/*`, `/extruder`, `/status`...) at `[log]
    /// derived_rate_hz`, and they all follow from the replay record (replayed, every digest checked).
    Regenerate {
        /// The log, or its rotated parts in order.
        #[arg(required = true)]
        files: Vec<PathBuf>,
        /// Output file.
        #[arg(long, short)]
        output: PathBuf,
    },
    /// Rewrite a log cut short by a crash into a valid, indexed file (everything in closed chunks).
    Recover {
        /// The damaged log.
        file: PathBuf,
        /// Output file (default: FILE with `.recovered.mcap`).
        #[arg(long, short)]
        output: Option<PathBuf>,
    },
}

fn main() -> ExitCode {
    // A closed pipe (`… | head`) ends the process quietly instead of a panic in println!.
    // SAFETY: setting a signal's disposition to the default before any thread starts.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    let fail = |e: ToolError| {
        eprintln!("strand-replay: {e}");
        ExitCode::from(2)
    };
    match Cli::parse().command {
        Command::Verify { files } => {
            let logs = match open_all(&files) {
                Ok(l) => l,
                Err(e) => return fail(e),
            };
            match verify(&logs) {
                Ok(Verdict::Identical { ticks }) => {
                    println!("identical ({ticks} ticks)");
                    ExitCode::SUCCESS
                }
                Ok(Verdict::Diverged { tick, field, logged, replayed }) => {
                    println!("diverged at tick {tick}: {field}: logged {logged}, replayed {replayed}");
                    ExitCode::from(1)
                }
                Err(e) => fail(e.into()),
            }
        }
        Command::Info { files } => match open_all(&files).and_then(|l| strand_replay::analyse(&l)) {
            Ok((_, summary, _)) => {
                print!("{}", strand_replay::info_text(&summary));
                ExitCode::SUCCESS
            }
            Err(e) => fail(e),
        },
        Command::Export { files, csv } => match open_all(&files).and_then(|l| strand_replay::export_csv(&l, &csv)) {
            Ok(written) => {
                for (p, n) in written {
                    println!("{} ({n} rows)", p.display());
                }
                ExitCode::SUCCESS
            }
            Err(e) => fail(e),
        },
        Command::Plot { files, out, truth, gcode } => {
            let bead = |logs: &[strand::log::reader::LogFile]| -> Result<Option<(bead::Bead, Vec<PathBuf>)>, ToolError> {
                let Some(truth) = &truth else { return Ok(None) };
                let rows = strand_replay::truth::read_truth(truth)?;
                let features = gcode.as_deref().map(bead::Features::of_gcode).transpose()?;
                let b = bead::measure(&logs[0], &rows, features.as_ref())?;
                let files = bead::plot::plot(&b, &out)?;
                Ok(Some((b, files)))
            };
            let run = open_all(&files).and_then(|l| {
                let (s, _, m) = strand_replay::analyse(&l)?;
                let mut written = replay_plot::plot_all(&s, &m, &out)?;
                let b = bead(&l)?;
                if let Some((_, files)) = &b {
                    written.extend(files.iter().cloned());
                }
                Ok((written, b.map(|(b, _)| b)))
            });
            match run {
                Ok((written, b)) => {
                    for p in written {
                        println!("{}", p.display());
                    }
                    if let Some(b) = b {
                        println!(
                            "bead: {} bins, error p50 {:.1} %, p95 {:.1} %, p99 {:.1} %, {:.2} % beyond ±10 %; blobs {:.3} %, strings {:.3} % of the melt",
                            b.all.bins,
                            b.all.p50 * 100.0,
                            b.all.p95 * 100.0,
                            b.all.p99 * 100.0,
                            b.all.beyond_10pct * 100.0,
                            b.blob_share() * 100.0,
                            b.string_share() * 100.0
                        );
                    }
                    ExitCode::SUCCESS
                }
                Err(e) => fail(e),
            }
        }
        Command::Calibrate { file, truth, json } => {
            let run = strand::log::reader::LogFile::open(&file)
                .map_err(ToolError::from)
                .and_then(|log| bead::calibrate::calibrate_log(&log, &strand_replay::truth::read_truth(&truth)?));
            match run {
                Ok(c) if json => {
                    println!("{}", serde_json::to_string(&c).expect("a calibration serialises"));
                    ExitCode::SUCCESS
                }
                Ok(c) => {
                    println!(
                        "hot end: melt lag {:.1} ms, motor lag {:.1} ms (model misfit {:.2} % of the mean flow); arm {:.1} ms behind its target",
                        c.hot_end.melt_lag_s * 1e3,
                        c.hot_end.motor_lag_s * 1e3,
                        c.hot_end.rms_relative * 100.0,
                        c.arm_delay_s * 1e3
                    );
                    print!("{}", c.toml());
                    ExitCode::SUCCESS
                }
                Err(e) => fail(e),
            }
        }
        Command::Regenerate { files, output } => {
            let logs = match open_all(&files) {
                Ok(l) => l,
                Err(e) => return fail(e),
            };
            match strand::log::regenerate::regenerate(&logs, &output) {
                Ok(r) => {
                    println!("{}: {} ticks, every channel at every tick ({:.1} MB)", output.display(), r.ticks, r.bytes as f64 / 1e6);
                    ExitCode::SUCCESS
                }
                Err(e) => fail(ToolError::Content(e.to_string())),
            }
        }
        Command::Recover { file, output } => {
            let output = output.unwrap_or_else(|| file.with_extension("recovered.mcap"));
            match strand::log::recover::recover(&file, &output) {
                Ok(r) => {
                    println!(
                        "{}: {} messages recovered ({}), {} attachments{}",
                        output.display(),
                        r.messages,
                        r.per_topic.iter().map(|(t, n)| format!("{t} {n}")).collect::<Vec<_>>().join(", "),
                        r.attachments,
                        if r.was_finished { "; the input was already finished" } else { "" }
                    );
                    ExitCode::SUCCESS
                }
                Err(e) => fail(e.into()),
            }
        }
    }
}
