//! strand: the service binary. Today it loads and validates a configuration (config file, robot file,
//! URDF) and reports the chain it would drive; the cycle runner joins it with the controller issue.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand};
use strand::config::Config;

#[derive(Parser)]
#[command(name = "strand", version, about = "Real-time streaming motion controller for robot-arm additive manufacturing")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Load and validate a configuration and the robot it names; print what it describes.
    CheckConfig {
        /// The service configuration file.
        #[arg(default_value = "config/default.toml")]
        config: PathBuf,
    },
}

fn main() -> ExitCode {
    match Cli::parse().command {
        Command::CheckConfig { config } => match Config::load(&config).and_then(|c| c.robot.build_model().map(|m| (c, m))) {
            Ok((cfg, model)) => {
                println!("{}: ok", cfg.file.display());
                println!(
                    "robot {} from {}: {} → {}, {} joints",
                    model.name(),
                    model.source(),
                    model.root_link(),
                    model.tip_link(),
                    model.dof()
                );
                println!("clik: task {:?}, gains {:?} 1/s, damping below σ = {}", cfg.clik.task, cfg.clik.gains, cfg.clik.sigma_threshold);
                ExitCode::SUCCESS
            }
            Err(e) => {
                eprintln!("strand: {e}");
                ExitCode::from(2)
            }
        },
    }
}
