//! How a tool is told which robot to use: a robot by NAME (`iiwa7`: `robots/iiwa7.toml` found by
//! `strand::config::locate`'s search order), a robot file (`config/robots/NAME.toml`: URDF, chain,
//! tool, limits) or a bare URDF with `--root` and `--tip` (flange as TCP, no acceleration or jerk
//! limits).

use std::path::Path;

use strand::config::{RobotConfig, locate};
use strand_core::kin::RobotModel;

use strand_cli::error::{Result, ToolError};

/// A loaded robot and what the tool should warn about how it was given.
pub struct LoadedRobot {
    /// The chain.
    pub model: RobotModel,
    /// True when a robot file gave the tool and the acceleration/jerk limits.
    pub from_config: bool,
}

/// Loads `arg`: a robot NAME, a `.toml` robot file, or a URDF with `root` and `tip`.
pub fn load_robot(arg: &Path, root: Option<&str>, tip: Option<&str>) -> Result<LoadedRobot> {
    let path = &locate::robot_file(arg)?;
    if path.extension().is_some_and(|e| e == "toml") {
        if root.is_some() || tip.is_some() {
            return Err(ToolError::Usage(format!("{}: a robot file names its own root and tip links; drop --root/--tip", path.display())));
        }
        let cfg = RobotConfig::load(path)?;
        let model = cfg.build_model()?;
        return Ok(LoadedRobot { model, from_config: true });
    }
    let (Some(root), Some(tip)) = (root, tip) else {
        return Err(ToolError::Usage(format!(
            "{}: a URDF needs --root LINK and --tip LINK (or pass a robot .toml from config/robots)",
            path.display()
        )));
    };
    let model = strand::config::robot_model_from_urdf_file(path, root, tip)?;
    Ok(LoadedRobot { model, from_config: false })
}
