//! strand-feed: streams a job (a G-code program or a `strand_job::segfile` segment file) to the service
//! over iceoryx2. It never sends past the credit the controller announces in Status, so nothing is
//! ever dropped; it shows a progress bar
//! (segments, layer, ETA), turns Ctrl-C into a controlled stop (a second Ctrl-C into an emergency
//! stop), can resume from a segment number, and exits with a code that says how the job ended:
//! 0 finished, 1 no service, 2 a bad program or config, 3 refused by the job check, 4 faulted,
//! 5 a segment rejected, 6 stopped before the end.
//!
//! Before it streams, it runs the job through `strand check-job`'s check (the controller in virtual
//! time, `strand::check`) and refuses a job that would fault, leave its path or hit a limit, with
//! the report; `--no-check` skips that, with a warning.
//!
//! The loading, the check and the streaming are `strand_feed`; this main owns the command
//! line, the signals and the exit code.

use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::{AtomicU32, Ordering};
use std::time::Instant;

use clap::Parser;
use strand::config::{Config, locate};
use strand_feed::{Ending, Keys, LogResume, Reentry, StreamOptions, check, load_gcode, stream};
use strand_ipc as ipc;

#[derive(Parser)]
#[command(
    name = "strand-feed",
    version,
    about = "Stream a G-code program or segment file to the strand service (back-pressure from Status)"
)]
struct Cli {
    /// The job: a G-code program, or a segment file (JSON lines, see strand_job::segfile).
    file: PathBuf,
    /// Service configuration: its `[bed]` places the program in the world, its `[service] prefix`
    /// names the services. A file or a NAME (`iiwa7`); default: default.toml by the search order
    /// ($STRAND_CONFIG_DIR, ./config, <prefix>/share/strand/config, the built-in copy).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Override the service prefix.
    #[arg(long)]
    prefix: Option<String>,
    /// Start at this segment number (as shown in the progress and in Status.executing_seq), with a
    /// travel to where it starts.
    #[arg(long)]
    resume_from: Option<u64>,
    /// Start at the first segment of this layer (the layer number the progress line shows): a
    /// travel up to `[controller] resume_clearance` above the part, over the layer's start, straight
    /// down onto it, a prime of `[extruder] retract_length`, then the layer.
    #[arg(long, conflicts_with = "resume_from")]
    resume_layer: Option<i32>,
    /// Resume where the run that wrote this log stopped (a crash, a power cut, a fault or a stop;
    /// a log cut short is read up to its last closed chunk): at the point on the segment that was
    /// executing, over the part at `[controller] resume_clearance`, a prime, then the rest. Says
    /// the job's line, layer and position first.
    #[arg(long, value_name = "RUN.mcap", conflicts_with_all = ["resume_from", "resume_layer"])]
    resume_from_log: Option<PathBuf>,
    /// Filament to prime at the resume point (mm; --resume-layer and --resume-from-log). Default:
    /// `[extruder] retract_length` where the controller retracted (a layer resume, a log whose run
    /// the controller ended), 0 after a crash (a log cut short mid-job: nothing was retracted).
    #[arg(long, value_name = "MM")]
    prime: Option<f64>,
    /// Say what would be streamed (with --resume-from-log: where it resumes) and exit, sending nothing.
    #[arg(long)]
    dry_run: bool,
    /// Seconds to wait for the service's Status.
    #[arg(long, default_value_t = 10.0)]
    wait_service: f64,
    /// Stream only the program's first N layers (by its layer comments).
    #[arg(long)]
    layers: Option<usize>,
    /// Read keys from stdin even when it is not a terminal (p pause/resume, +/- feed override,
    /// s stop; on a terminal they are always read).
    #[arg(long)]
    keys: bool,
    /// No progress bar (one line per 10 % instead).
    #[arg(long)]
    quiet: bool,
    /// Stream without checking the job against the robot first (prints a warning).
    #[arg(long)]
    no_check: bool,
    /// The planned base trajectory for the check on a tracked base (CSV: t, base_x, base_y[, base_theta]).
    #[arg(long, value_name = "CSV")]
    base_trajectory: Option<PathBuf>,
    /// Override one config key (repeatable), as the service's `run --set`: give the feeder the
    /// service's overrides so that its check runs the service's controller.
    #[arg(long = "set", value_name = "SECTION.KEY=VALUE")]
    set: Vec<String>,
}

static INTERRUPTS: AtomicU32 = AtomicU32::new(0);

extern "C" fn on_interrupt(_: libc::c_int) {
    INTERRUPTS.fetch_add(1, Ordering::Relaxed);
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let cfg = match locate::service_config(cli.config.as_deref()).and_then(|c| Config::load_with(&c, &cli.set)) {
        Ok(c) => c,
        Err(e) => {
            eprintln!("strand-feed: {e}");
            return ExitCode::from(2);
        }
    };
    let reentry = Reentry {
        clearance: cfg.controller.resume_clearance,
        prime: cfg.extruder.retract_length,
        prime_speed: cfg.extruder.retract_speed,
        travel_feed: strand_job::gcode::GcodeOptions::default().rapid_feed,
    };
    let loaded = load_gcode(&cli.file, &cfg, cli.resume_from).and_then(|j| match (cli.resume_layer, &cli.resume_from_log) {
        (Some(layer), _) => j.from_layer(layer, &Reentry { prime: cli.prime.map_or(reentry.prime, |mm| mm * 1e-3), ..reentry }),
        (None, Some(log)) => {
            let prefix = cli.prefix.clone().unwrap_or_else(|| cfg.service.prefix.clone());
            let prime = cli.prime.map(|mm| mm * 1e-3);
            j.from_log(&LogResume { program: &cli.file, log, cfg: &cfg, prefix: &prefix, reentry, prime }, &mut |line| eprintln!("{line}"))
        }
        (None, None) => Ok(j),
    });
    let job = match loaded {
        Ok(j) => match cli.layers {
            Some(n) => j.first_layers(n),
            None => j,
        },
        Err(e) => {
            eprintln!("strand-feed: {e}");
            return ExitCode::from(2);
        }
    };
    for w in &job.warnings {
        eprintln!("strand-feed: note: {w}");
    }
    if cli.dry_run {
        let extruding = job.segments.iter().filter(|s| s.flags & ipc::segment_flags::EXTRUDE != 0).count();
        eprintln!(
            "strand-feed: dry run: {} segments ({extruding} extruding, {:.3} m of path) from segment {}; nothing sent",
            job.segments.len(),
            job.lengths.iter().sum::<f64>(),
            job.segments.first().map_or(0, |s| s.seq)
        );
        return ExitCode::SUCCESS;
    }
    // SAFETY: the handler only increments an atomic.
    unsafe {
        libc::signal(libc::SIGINT, on_interrupt as *const () as libc::sighandler_t);
        libc::signal(libc::SIGTERM, on_interrupt as *const () as libc::sighandler_t);
    }
    if cli.no_check {
        eprintln!("strand-feed: WARNING: --no-check: the job was not checked against the robot (reach, joint limits, bed)");
    } else {
        let started = Instant::now();
        match check(&job, &cli.file, cli.base_trajectory.as_deref(), &cfg) {
            Ok(report) if report.clean => eprintln!(
                "strand-feed: check-job: clean ({} segments, predicted {:.1} s, max TCP error {:.3} mm; checked in {:.1} s)",
                report.segments,
                report.time.total_s,
                report.max_tcp_error_m * 1e3,
                started.elapsed().as_secs_f64()
            ),
            Ok(report) => {
                eprintln!("{}", report.summary());
                eprintln!("strand-feed: refused: the job check fails (stream it anyway with --no-check)");
                return ExitCode::from(3);
            }
            Err(e) => {
                eprintln!("strand-feed: {e}");
                return ExitCode::from(2);
            }
        }
    }
    if INTERRUPTS.load(Ordering::Relaxed) > 0 {
        eprintln!("strand-feed: interrupted before streaming: nothing was sent");
        return ExitCode::from(6);
    }
    let opts = StreamOptions {
        prefix: cli.prefix.clone().unwrap_or_else(|| cfg.service.prefix.clone()),
        wait_service: cli.wait_service,
        quiet: cli.quiet,
        name: cli.file.file_name().map_or_else(|| cli.file.display().to_string(), |n| n.to_string_lossy().into_owned()),
    };
    let keys = Keys::start(cli.keys);
    let streamed = stream(&job, &opts, &INTERRUPTS, keys.as_ref());
    drop(keys);
    match streamed {
        Ok(ending) => {
            let text = match ending {
                Ending::Finished => "finished".to_string(),
                Ending::Stopped => "stopped".to_string(),
                Ending::Faulted { code, seq, line } => {
                    let code = ipc::FaultCode::from_u32(code).map_or(format!("fault {code}"), |c| format!("{c:?}"));
                    format!("FAULTED: {code} at segment {seq} ({}:{line})", cli.file.display())
                }
                Ending::Rejected { seq, reason } => {
                    let line = job.segments.iter().find(|s| s.seq == seq).map_or(0, |s| s.source_line);
                    format!("segment {seq} ({}:{line}) rejected: {:?}", cli.file.display(), ipc::RejectReason::from_u32(reason))
                }
            };
            eprintln!("strand-feed: job {text}");
            ExitCode::from(ending.exit_code())
        }
        Err(e) => {
            eprintln!("strand-feed: {e}");
            ExitCode::from(1)
        }
    }
}
