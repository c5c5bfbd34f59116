//! strand-replay: what a log says. `verify` re-runs every logged tick through `Controller::step`
//! and checks the outputs to the bit; `info` summarises a run; `export` writes one CSV per channel;
//! `plot` draws PNGs; `recover` rewrites a log that a crash cut short into a valid, indexed file.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand};
use strand::log::replay::{Verdict, verify};
use strand_tools::error::ToolError;
use strand_tools::replay::{self, open_all, plot as replay_plot};

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
    /// PNG plots: TCP path (top view), TCP error, speed and flow, joints against limits, lateness.
    Plot {
        /// The log, or its rotated parts in order.
        #[arg(required = true)]
        files: Vec<PathBuf>,
        /// Output folder.
        #[arg(long)]
        out: PathBuf,
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
        Command::Info { files } => match open_all(&files).and_then(|l| replay::analyse(&l)) {
            Ok((_, summary, _)) => {
                print!("{}", replay::info_text(&summary));
                ExitCode::SUCCESS
            }
            Err(e) => fail(e),
        },
        Command::Export { files, csv } => match open_all(&files).and_then(|l| replay::export_csv(&l, &csv)) {
            Ok(written) => {
                for (p, n) in written {
                    println!("{} ({n} rows)", p.display());
                }
                ExitCode::SUCCESS
            }
            Err(e) => fail(e),
        },
        Command::Plot { files, out } => {
            match open_all(&files).and_then(|l| replay::analyse(&l)).and_then(|(s, _, m)| replay_plot::plot_all(&s, &m, &out)) {
                Ok(written) => {
                    for p in written {
                        println!("{}", p.display());
                    }
                    ExitCode::SUCCESS
                }
                Err(e) => fail(e),
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
