//! strand-kin: inspect a robot's kinematic chain, and evaluate FK, the Jacobian and manipulability for
//! joint vectors streamed as JSON lines. The work is `strand_kin`; this main owns the
//! command line.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand};
use strand_cli::error::ToolError;
use strand_kin::robot::load_robot;
use strand_kin::{check, eval};

#[derive(Parser)]
#[command(name = "strand-kin", version, about = "Kinematics of a robot chain: check it, evaluate FK/Jacobian/manipulability")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Print the chain, its joint limits, its reach and any warning.
    Check {
        /// A robot by NAME (`iiwa7`: robots/iiwa7.toml by the search order — $STRAND_CONFIG_DIR,
        /// ./config, <prefix>/share/strand/config, the built-in copy), a robot file, or a URDF
        /// (then --root and --tip).
        robot: PathBuf,
        /// Root link (the base frame), for a URDF.
        #[arg(long)]
        root: Option<String>,
        /// Tip link (the flange), for a URDF.
        #[arg(long)]
        tip: Option<String>,
    },
    /// Read {"q":[...]} lines on stdin; write one JSON line of FK, Jacobian and manipulability per input.
    Eval {
        /// A URDF (with --root and --tip).
        #[arg(long, conflicts_with = "config", required_unless_present = "config")]
        urdf: Option<PathBuf>,
        /// A robot by NAME (`iiwa7`) or a robot file, instead of --urdf/--root/--tip.
        #[arg(long)]
        config: Option<PathBuf>,
        /// Root link (the base frame).
        #[arg(long)]
        root: Option<String>,
        /// Tip link (the flange).
        #[arg(long)]
        tip: Option<String>,
    },
}

fn main() -> ExitCode {
    // A closed pipe (`… | head`) ends the process quietly instead of a panic in println!.
    // SAFETY: setting a signal's disposition to the default before any thread starts.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    let cli = Cli::parse();
    let result = match cli.command {
        Command::Check { robot, root, tip } => load_robot(&robot, root.as_deref(), tip.as_deref()).map(|r| check(&r)),
        Command::Eval { urdf, config, root, tip } => match config.or(urdf) {
            Some(path) => load_robot(&path, root.as_deref(), tip.as_deref())
                .and_then(|r| eval(&r.model, std::io::stdin().lock(), std::io::stdout().lock())),
            None => Err(ToolError::Usage("give --config ROBOT or --urdf FILE".to_string())),
        },
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("strand-kin: {e}");
            ExitCode::from(2)
        }
    }
}
