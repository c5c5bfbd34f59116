//! What a tool's library code can fail on, as one enum: the `bin/` mains are the only place an error
//! becomes text and an exit code (the CLI edge), so every function in the tools' library crates returns a
//! [`ToolError`] that still says which file, option, process or measurement went wrong.
//!
//! The variants wrap the library crates' own errors (config, job, check, log, ports) unchanged, so
//! their messages — which name the file, line, key or field — reach the user as they were written.

use std::path::{Path, PathBuf};

use strand::check::CheckError;
use strand::config::ConfigError;
use strand::log::reader::ReadError;
use strand::log::replay::ReplayError;
use strand::log::writer::LogError;
use strand_core::ControllerError;
use strand_ipc::ports::PortError;
use strand_job::JobError;
use strand_job::gcode::GcodeError;
use strand_job::timing::TimingError;

/// A tool's failure.
#[derive(Debug, thiserror::Error)]
pub enum ToolError {
    /// A file or folder that could not be read, written or created.
    #[error("{}: {source}", path.display())]
    File {
        /// The file or folder.
        path: PathBuf,
        /// What the system said.
        source: std::io::Error,
    },
    /// A file that was read but holds something wrong: the message names the file and where.
    #[error("{0}")]
    Content(String),
    /// A command-line value (or a combination of them) the tool cannot use: the message names the
    /// option.
    #[error("{0}")]
    Usage(String),
    /// A planner's input it cannot plan (out of reach, no path...): the message says why.
    #[error("{0}")]
    Plan(String),
    /// A path the pre-flight check (`strand check-job`'s) refused: the report was printed; the message
    /// names the file and the robot.
    #[error("{0}")]
    Refused(String),
    /// No font for a picture's text.
    #[error(transparent)]
    Font(#[from] strand::check::NoFont),
    /// A picture plotters could not draw.
    #[error("{}: cannot draw: {why}", path.display())]
    Plot {
        /// The picture's file.
        path: PathBuf,
        /// What plotters said.
        why: String,
    },
    /// A helper process (the service, the sim, the feeder, cyclictest) that could not start or
    /// failed: the message names it and quotes its last words.
    #[error("{0}")]
    Process(String),
    /// A measurement that broke its own rule (an implausible distribution, an allocating tick,
    /// dropped log records) or a run that did not come about (no service, a timeout).
    #[error("{0}")]
    Measurement(String),
    /// A service configuration.
    #[error(transparent)]
    Config(#[from] ConfigError),
    /// A plant configuration for strand-sim (`strand_sim::config::SimConfigError`, boxed: the sim's
    /// crate depends on this one, not the reverse).
    #[error(transparent)]
    SimConfig(Box<dyn std::error::Error + Send + Sync>),
    /// A job, segment file or base trajectory.
    #[error(transparent)]
    Job(#[from] JobError),
    /// A G-code program.
    #[error(transparent)]
    Gcode(#[from] GcodeError),
    /// Timing a program through the path engine.
    #[error(transparent)]
    Timing(#[from] TimingError),
    /// The job check.
    #[error(transparent)]
    Check(#[from] CheckError),
    /// A robot chain that could not be built from its URDF.
    #[error(transparent)]
    Model(#[from] strand_core::kin::ModelError),
    /// A controller that could not be built from its settings.
    #[error(transparent)]
    Controller(#[from] ControllerError),
    /// A configuration value out of its range (a section's `validate`).
    #[error(transparent)]
    Setting(#[from] strand_core::InvalidSetting),
    /// A `[path]` value out of its range.
    #[error("[path] {0}")]
    PathSetting(#[from] strand_core::InvalidPathConfig),
    /// A `[clik]` value out of its range.
    #[error("[clik] {0}")]
    ClikSetting(#[from] strand_core::kin::InvalidClikConfig),
    /// The service's cycle runner.
    #[error(transparent)]
    Run(#[from] strand::io::runner::RunError),
    /// A CSV file that could not be written.
    #[error("{}: cannot write: {why}", path.display())]
    Write {
        /// The file.
        path: PathBuf,
        /// What went wrong.
        why: String,
    },
    /// The shared-memory ports to the service.
    #[error(transparent)]
    Ports(#[from] PortError),
    /// The MCAP logger.
    #[error(transparent)]
    Log(#[from] LogError),
    /// Reading an MCAP log.
    #[error(transparent)]
    ReadLog(#[from] ReadError),
    /// Replaying a log.
    #[error(transparent)]
    Replay(#[from] ReplayError),
}

impl ToolError {
    /// A read or write of `path` that failed: for `map_err(ToolError::file(path))`.
    pub fn file(path: &Path) -> impl FnOnce(std::io::Error) -> ToolError + '_ {
        move |source| ToolError::File { path: path.to_path_buf(), source }
    }

    /// A write to `path` that failed (a CSV writer's error): for `map_err(ToolError::write(path))`.
    pub fn write<E: std::fmt::Display>(path: &Path) -> impl Fn(E) -> ToolError + '_ {
        move |e| ToolError::Write { path: path.to_path_buf(), why: e.to_string() }
    }

    /// A picture of `path` that plotters could not draw: for `map_err(ToolError::plot(path))`.
    pub fn plot<E: std::fmt::Display>(path: &Path) -> impl Fn(E) -> ToolError + '_ {
        move |e| ToolError::Plot { path: path.to_path_buf(), why: e.to_string() }
    }
}

/// The tools' result.
pub type Result<T, E = ToolError> = std::result::Result<T, E>;
