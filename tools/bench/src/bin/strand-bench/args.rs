//! strand-bench's command line: the clap types, nothing else (the measurements are
//! `strand_bench`).

use std::path::PathBuf;

use clap::{Parser, Subcommand};

#[derive(Parser)]
#[command(name = "strand-bench", version, about = "Benchmarks: distributions of cost, jitter and throughput")]
pub(crate) struct Cli {
    #[command(subcommand)]
    pub command: Mode,
}

#[derive(Subcommand)]
pub(crate) enum Mode {
    /// Wake-up lateness of the cycle runner (timer mode), idle or with a controller printing, next
    /// to an empty TimerClock loop and (with --cyclictest) cyclictest at the same period.
    Jitter {
        /// Tick rate (Hz).
        #[arg(long, default_value_t = 1000.0)]
        rate: f64,
        /// Duration of each run (s).
        #[arg(long, default_value_t = 10.0)]
        seconds: f64,
        /// SCHED_FIFO (at --priority) and mlockall for the runner and the baselines.
        #[arg(long)]
        rt: bool,
        /// SCHED_FIFO priority with --rt.
        #[arg(long, default_value_t = 80)]
        priority: u32,
        /// Run the controller of this robot (a name under config/, or a config file), printing 004's box.
        #[arg(long, value_name = "ROBOT")]
        with_controller: Option<String>,
        /// Also run cyclictest (rt-tests) with the same period, priority and memory locking.
        #[arg(long)]
        cyclictest: bool,
        /// Print one JSON object instead of the table.
        #[arg(long)]
        json: bool,
        /// Draw the histograms (log-scale counts) into this PNG.
        #[arg(long)]
        png: Option<PathBuf>,
    },
    /// State in → command out on the robot clock (a driver here, the service as its own process
    /// printing the box), next to an iceoryx2 ping-pong between two processes.
    Latency {
        /// Robot rate (Hz).
        #[arg(long, default_value_t = 1000.0)]
        rate: f64,
        /// Duration of each run (s).
        #[arg(long, default_value_t = 10.0)]
        seconds: f64,
        /// The robot (a name under config/, or a config file).
        #[arg(long, default_value = "iiwa7")]
        robot: String,
        /// Print one JSON object instead of the table.
        #[arg(long)]
        json: bool,
        /// Draw the histograms (log-scale counts) into this PNG.
        #[arg(long)]
        png: Option<PathBuf>,
        /// Through a robot driver instead: `egm` (strand-egm, irb140), `rsi` (strand-rsi, kr6r900),
        /// `fri` (strand-fri, iiwa7), `bcap` (strand-bcap, vp6242), `meca` (strand-meca, meca500)
        /// or `ur` (strand-ur, ur5e) against the fake robot controller, at the robot's cycle (4 ms;
        /// FRI 1 ms; b-CAP the RC8's 8 ms; UR RTDE's 2 ms).
        #[arg(long, value_parser = ["egm", "rsi", "fri", "bcap", "meca", "ur"])]
        driver: Option<String>,
        /// With --driver: run the driver with SCHED_FIFO at this priority. Without: the service and
        /// the ping-pong at this priority (memory locked, PM QoS 0) and this driver one above.
        #[arg(long)]
        rt: Option<u32>,
        /// Without --driver: pin the service's tick thread, the ping-pong and this driver to this CPU.
        #[arg(long, conflicts_with = "driver")]
        cpu: Option<usize>,
    },
    /// Cost per stage of a controller tick printing the box (every stage of `Controller::step`, timed
    /// inside it, and the remainder), of the whole step and of the log enqueue; allocations counted
    /// (must be 0); with `--kdl` and `--pinocchio`, their CLIK ticks between rounds of ours.
    Tick {
        /// The robot (a name under config/, or a config file).
        #[arg(long, default_value = "iiwa7")]
        robot: String,
        /// Ticks to measure.
        #[arg(long, default_value_t = 100_000)]
        iterations: u64,
        /// Rounds the ticks are split into, the baselines' benches run between them.
        #[arg(long, default_value_t = 3)]
        rounds: usize,
        /// Pinocchio's DLS CLIK bench (benches/pinocchio/build.sh): the CLIK stage against its tick.
        #[arg(long)]
        pinocchio: Option<PathBuf>,
        /// KDL's CLIK bench (benches/kdl/build.sh): the whole step against its tick.
        #[arg(long)]
        kdl: Option<PathBuf>,
        /// Print one JSON object instead of the table.
        #[arg(long)]
        json: bool,
        /// Draw the histograms (log-scale counts) of the whole step and the stages into this PNG.
        #[arg(long)]
        png: Option<PathBuf>,
        /// Also time the shell: the runner's receives, publishes and log push over real iceoryx2
        /// ports (a feeder and a driver in this process), per stage, with `runner_allocations`.
        #[arg(long)]
        shell: bool,
        /// Pace the shell's ticks at this rate (Hz), sleeping between them as the runner does (cold
        /// caches after each sleep); 0: back to back.
        #[arg(long, default_value_t = 0.0)]
        shell_rate: f64,
    },
    /// Our CLIK step (6-D task, null-space gradient, limits) on a 7-joint arm tracking a 20 mm circle,
    /// per tick, in alternating rounds with Pinocchio's DLS tick on the same targets
    /// (`benches/pinocchio/build.sh` builds its bench).
    Clik {
        /// The robot (a name under config/, or a config file); a 7-joint arm.
        #[arg(long, default_value = "iiwa7")]
        robot: String,
        /// Timed ticks per round and side.
        #[arg(long, default_value_t = 200_000)]
        ticks: usize,
        /// Rounds per side.
        #[arg(long, default_value_t = 3)]
        rounds: usize,
        /// The Pinocchio bench binary (e.g. target/pinocchio/clik_dls); without it, ours alone.
        #[arg(long)]
        pinocchio: Option<PathBuf>,
        /// Print one JSON object instead of the table.
        #[arg(long)]
        json: bool,
    },
    /// The ping-pong end of `latency` (started by it).
    #[command(hide = true)]
    Pong {
        #[arg(long)]
        prefix: String,
        #[arg(long, default_value_t = 60.0)]
        seconds: f64,
        #[arg(long)]
        rt: Option<u32>,
        #[arg(long)]
        cpu: Option<usize>,
    },
    /// Logger throughput at a control rate: enqueue cost, drops, writer CPU share, bytes/s.
    Log {
        /// Tick rate (Hz).
        #[arg(long, default_value_t = 4000.0)]
        rate: f64,
        /// Duration (s).
        #[arg(long, default_value_t = 60.0)]
        seconds: f64,
        /// Service configuration (robot, controller, `[log]`): a file or a NAME; default:
        /// default.toml by the search order ($STRAND_CONFIG_DIR, ./config,
        /// <prefix>/share/strand/config, the built-in copy).
        #[arg(long)]
        config: Option<PathBuf>,
        /// Log file (default: a temporary file, removed afterwards).
        #[arg(long)]
        out: Option<PathBuf>,
        /// Print one JSON object instead of the table.
        #[arg(long)]
        json: bool,
        /// Draw the enqueue-cost histogram (log-scale counts) into this PNG.
        #[arg(long)]
        png: Option<PathBuf>,
    },
}
