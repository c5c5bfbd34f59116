//! `strand calibrate`: a cell's calibration from touches to config. The joints at each touch come
//! from a snapshot file (`--snapshots`) or from the live `JointState` on a key press (Enter), the
//! solve from `strand-calibrate`, and the answer is printed with its residuals (text, or one JSON
//! object with `--json`) and written into the config with `--write`, comments kept.
//!
//! This module is the glue that needs the service's config and ports; the math, the file readers
//! and the config writer live in `strand-calibrate` (which depends on the core only).

use std::fmt::Write as _;
use std::io::{BufRead, Write};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use nalgebra::{Point3, Quaternion, Translation3, UnitQuaternion, Vector3};
use serde_json::json;
use strand_calibrate::snapshots::{self, Snapshot};
use strand_calibrate::write::{ConfigEdit, DECIMALS};
use strand_calibrate::{CalibrationError, extruder, frame, handeye, pairs, tool};
use strand_core::BaseMode;
use strand_core::kin::{Frame, RobotModel};
use strand_ipc as ipc;
use strand_ipc::ports::{ClientPorts, ClientRoles, PortError};

use crate::config::{Config, ConfigError, RobotConfig};
use crate::io::clock::monotonic_ns;

/// What `strand calibrate` measures.
#[derive(Clone, Debug, PartialEq)]
pub enum CalibrateVerb {
    /// The tool offset from ≥ 4 orientations touching one point; with `axis`, the nozzle axis from
    /// touches up the nozzle (`axis_snapshots` with `--snapshots`, else two more key presses).
    Tool {
        /// Also find the nozzle's axis (`[tool] rpy`).
        axis: bool,
        /// The axis touches' snapshot file (implies `axis`).
        axis_snapshots: Option<PathBuf>,
    },
    /// The bed frame from 3 or more touched points.
    Frame,
    /// The bed's surface (`[bed.mesh]`) from heights probed over it.
    Mesh(MeshOptions),
    /// The tracked base: hand–eye from pairs of arm and tracker poses (`--snapshots`: the pairs file).
    Base,
    /// The extruder drive from a commanded and a measured filament length.
    Extruder {
        /// Filament length to extrude (m).
        commanded: f64,
        /// The length that went in (m); `None`: extrude `commanded` through the service and ask.
        measured: Option<f64>,
        /// Filament speed of the live extrusion (m/s).
        speed: f64,
    },
}

/// What `strand calibrate mesh` takes beside the common options.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct MeshOptions {
    /// Probed points (x, y, z in the bed frame, m), as a probe's script writes them; `None`: the
    /// nozzle's touches (`--snapshots`, else live).
    pub points: Option<PathBuf>,
    /// Nodes along x and y; `None`: the config's `[bed.mesh]` grid.
    pub grid: Option<[usize; 2]>,
    /// The grid's corners (x, y) in the bed frame (m); `None`: the config's, else the touches' extent.
    pub bounds: Option<([f64; 2], [f64; 2])>,
    /// The interpolation (`bicubic`, `bilinear`); `None`: the config's, else bicubic.
    pub algorithm: Option<strand_core::MeshAlgorithm>,
}

/// What every verb takes.
#[derive(Clone, Debug, PartialEq)]
pub struct CalibrateOptions {
    /// The service configuration (resolved path).
    pub config: PathBuf,
    /// The snapshot (or pairs) file; `None`: live, on key presses.
    pub snapshots: Option<PathBuf>,
    /// One JSON object on stdout instead of the text.
    pub json: bool,
    /// The config file to write the answer into (a service config; `[tool]` goes to the robot file it names).
    pub write: Option<PathBuf>,
    /// The service prefix for the live reading (default: the config's `[service] prefix`).
    pub prefix: Option<String>,
}

/// Why a calibration ended without an answer. The exit code says which kind.
#[derive(Debug, thiserror::Error)]
pub enum CalibrateError {
    /// The config could not be loaded or written.
    #[error("{0}")]
    Config(#[from] ConfigError),
    /// The input could not be read, or cannot determine the answer.
    #[error("{0}")]
    Calibration(#[from] CalibrationError),
    /// The service's ports could not be opened or used.
    #[error("{0}")]
    Port(#[from] PortError),
    /// The live reading failed (no service, no joint state, the operator's input ended).
    #[error("{0}")]
    Live(String),
}

impl CalibrateError {
    /// The process exit code: 1 the service or the live reading, 2 bad input or config, 3 refused
    /// (the measurements cannot determine the answer, or a value is out of range).
    pub fn exit_code(&self) -> u8 {
        match self {
            CalibrateError::Port(_) | CalibrateError::Live(_) => 1,
            CalibrateError::Config(_) => 2,
            CalibrateError::Calibration(CalibrationError::Degenerate { .. } | CalibrationError::BadValue { .. })
            | CalibrateError::Calibration(CalibrationError::TooFew { .. }) => 3,
            CalibrateError::Calibration(_) => 2,
        }
    }
}

type Result<T> = std::result::Result<T, CalibrateError>;

/// Runs one calibration: reads the touches (file or live; key presses from `input`, prompts on
/// stderr), solves, writes with `--write`, and returns what to print on stdout.
pub fn run(verb: &CalibrateVerb, opts: &CalibrateOptions, input: &mut dyn BufRead) -> Result<String> {
    let cfg = Config::load(&opts.config)?;
    let prefix = opts.prefix.clone().unwrap_or_else(|| cfg.service.prefix.clone());
    match verb {
        CalibrateVerb::Tool { axis, axis_snapshots } => {
            tool_verb(&cfg, opts, &prefix, *axis || axis_snapshots.is_some(), axis_snapshots.as_deref(), input)
        }
        CalibrateVerb::Frame => frame_verb(&cfg, opts, &prefix, input),
        CalibrateVerb::Mesh(mesh) => mesh_verb(&cfg, opts, mesh, &prefix, input),
        CalibrateVerb::Base => base_verb(&cfg, opts, &prefix, input),
        CalibrateVerb::Extruder { commanded, measured, speed } => extruder_verb(&cfg, opts, &prefix, *commanded, *measured, *speed, input),
    }
}

/// The arm's chain without the tool: FK gives the flange.
fn flange_model(robot: &RobotConfig) -> Result<RobotModel> {
    let file = robot.urdf_path().display().to_string();
    RobotModel::from_urdf_str(&robot.urdf_text, &file, &robot.root_link, &robot.tip_link)
        .map_err(|e| CalibrateError::Config(ConfigError { file: robot.file.display().to_string(), message: format!("urdf: {e}") }))
}

fn vec3(v: &Vector3<f64>) -> [f64; 3] {
    [v.x, v.y, v.z]
}

fn mm(v: &[f64]) -> String {
    v.iter().map(|x| format!("{x:.3}")).collect::<Vec<_>>().join(", ")
}

fn m6(v: &[f64; 3]) -> String {
    format!("[{:.6}, {:.6}, {:.6}]", v[0], v[1], v[2])
}

// ---------------------------------------------------------------------------------------------
// The live reading.

/// The ports of a live calibration and the operator's key presses.
struct Live<'a> {
    ports: ClientPorts,
    prefix: String,
    input: &'a mut dyn BufRead,
}

/// What the operator answered to a prompt.
enum Press {
    /// Enter: take the joints now.
    Take,
    /// `u`: drop the last one.
    Undo,
    /// `d`: done.
    Done,
    /// The input ended.
    End,
}

impl<'a> Live<'a> {
    fn open(prefix: &str, roles: ClientRoles, input: &'a mut dyn BufRead) -> Result<Self> {
        let ports = ClientPorts::open(&ipc::ServiceNames::new(prefix), &format!("strand-calibrate-{}", std::process::id()), roles)?;
        Ok(Live { ports, prefix: prefix.to_string(), input })
    }

    fn press(&mut self, prompt: &str) -> Result<Press> {
        eprint!("{prompt} ");
        let _ = std::io::stderr().flush();
        let mut line = String::new();
        let n = self.input.read_line(&mut line).map_err(|e| CalibrateError::Live(format!("reading the keyboard: {e}")))?;
        if n == 0 {
            return Ok(Press::End);
        }
        Ok(match line.trim() {
            "u" | "U" => Press::Undo,
            "d" | "D" | "q" | "Q" => Press::Done,
            _ => Press::Take,
        })
    }

    /// The newest joint state (the first `dof` joints), waiting up to a second for one.
    fn joints(&self, dof: usize) -> Result<Vec<f64>> {
        let s = wait_for(
            Duration::from_secs(1),
            || self.ports.latest_joint_state(),
            || format!("no JointState under {} within 1 s: is the robot driver (or the sim) running with this prefix?", self.prefix),
        )?;
        if (s.dof as usize) < dof {
            return Err(CalibrateError::Live(format!("the JointState has {} joints, the arm {dof}", s.dof)));
        }
        Ok(s.position[..dof].to_vec())
    }

    /// The newest base pose (B in W as the tracker publishes it), waiting up to a second.
    fn base_pose(&self) -> Result<Frame> {
        let p = wait_for(
            Duration::from_secs(1),
            || self.ports.latest_base_pose(),
            || format!("no BasePose under {} within 1 s: is the tracker (strand-natnet) running with this prefix?", self.prefix),
        )?;
        Ok(pose_frame(&p))
    }

    /// Snapshots on key presses until `d` (at least `min`), each with the base pose if `with_pose`.
    fn touches(
        &mut self,
        what: &str,
        dof: usize,
        min: usize,
        max: Option<usize>,
        with_pose: bool,
    ) -> Result<Vec<(Snapshot, Option<Frame>)>> {
        let mut taken: Vec<(Snapshot, Option<Frame>)> = Vec::new();
        loop {
            if max.is_some_and(|m| taken.len() >= m) {
                return Ok(taken);
            }
            let prompt = format!(
                "{what} {}: Enter to take the joints{}, u to drop the last, d when done ({} taken, at least {min})",
                taken.len() + 1,
                if with_pose { " and the tracker's pose" } else { "" },
                taken.len()
            );
            match self.press(&prompt)? {
                Press::Undo => {
                    taken.pop();
                }
                Press::Done | Press::End if taken.len() >= min => return Ok(taken),
                Press::Done => eprintln!("  {} taken, at least {min} needed", taken.len()),
                Press::End => {
                    return Err(CalibrateError::Live(format!("the input ended with {} of at least {min} {what}s taken", taken.len())));
                }
                Press::Take => {
                    let joints = self.joints(dof)?;
                    let pose = if with_pose { Some(self.base_pose()?) } else { None };
                    eprintln!("  joints [{}] rad", joints.iter().map(|x| format!("{x:.5}")).collect::<Vec<_>>().join(", "));
                    taken.push((Snapshot { line: 0, joints }, pose));
                }
            }
        }
    }
}

/// The first `Some` of `poll` within `timeout` (polled every 5 ms); else the error `why` says.
fn wait_for<T>(timeout: Duration, mut poll: impl FnMut() -> Option<T>, why: impl FnOnce() -> String) -> Result<T> {
    let deadline = Instant::now() + timeout;
    loop {
        if let Some(v) = poll() {
            return Ok(v);
        }
        if Instant::now() >= deadline {
            return Err(CalibrateError::Live(why()));
        }
        std::thread::sleep(Duration::from_millis(5));
    }
}

/// A tracker's `BasePose` as a frame (m, unit rotation).
fn pose_frame(p: &ipc::BasePose) -> Frame {
    let [w, x, y, z] = p.orientation;
    Frame::from_parts(
        Translation3::from(Vector3::from(p.position)),
        UnitQuaternion::from_quaternion(Quaternion::new(w, x, y, z)).to_rotation_matrix(),
    )
}

/// Reads snapshots from the file, or live.
fn read_touches(
    opts: &CalibrateOptions,
    prefix: &str,
    what: &str,
    dof: usize,
    min: usize,
    input: &mut dyn BufRead,
) -> Result<Vec<Snapshot>> {
    match &opts.snapshots {
        Some(path) => Ok(snapshots::read_snapshots(path, dof)?),
        None => {
            let mut live = Live::open(prefix, ClientRoles { measurements: true, ..Default::default() }, input)?;
            Ok(live.touches(what, dof, min, None, false)?.into_iter().map(|(s, _)| s).collect())
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Writing.

/// The file that holds `[tool]`: the robot file a service config names, or `path` itself if it is a
/// robot file.
fn tool_file(path: &Path) -> Result<PathBuf> {
    let edit = ConfigEdit::open(path)?;
    Ok(match edit.top_string("robot") {
        Some(robot) => path.parent().unwrap_or(Path::new(".")).join(robot),
        None => path.to_path_buf(),
    })
}

/// Saves `edit`, then loads `config` again (the service config the edit belongs to); if it no
/// longer loads, the file is put back as it was and the error returned.
fn save_checked(edit: &ConfigEdit, config: &Path) -> Result<()> {
    let before = std::fs::read_to_string(edit.file())
        .map_err(|e| CalibrationError::Config { file: edit.file().display().to_string(), message: format!("cannot read: {e}") })?;
    edit.save()?;
    if let Err(e) = Config::load(config) {
        let _ = std::fs::write(edit.file(), before);
        return Err(CalibrateError::Config(ConfigError {
            file: e.file,
            message: format!("{} (not written: the file is as it was)", e.message),
        }));
    }
    Ok(())
}

// ---------------------------------------------------------------------------------------------
// The verbs.

fn tool_verb(
    cfg: &Config,
    opts: &CalibrateOptions,
    prefix: &str,
    axis: bool,
    axis_file: Option<&Path>,
    input: &mut dyn BufRead,
) -> Result<String> {
    let model = flange_model(&cfg.robot)?;
    let dof = model.dof();
    let (touches, axis_touches) = match &opts.snapshots {
        Some(path) => {
            let touches = snapshots::read_snapshots(path, dof)?;
            let axis_touches = match axis_file {
                Some(f) => snapshots::read_snapshots(f, dof)?,
                None if axis => {
                    return Err(CalibrateError::Calibration(CalibrationError::BadValue {
                        what: "--axis",
                        reason: "with --snapshots, give the axis touches as --axis-snapshots FILE".into(),
                    }));
                }
                None => Vec::new(),
            };
            (touches, axis_touches)
        }
        None => {
            let mut live = Live::open(prefix, ClientRoles { measurements: true, ..Default::default() }, input)?;
            eprintln!(
                "strand calibrate tool: put the nozzle tip on one fixed point (a cone's tip) from 4 or more orientations, tilted 20-40° in different directions"
            );
            let touches: Vec<Snapshot> = live.touches("touch", dof, tool::MIN_TOUCHES, None, false)?.into_iter().map(|(s, _)| s).collect();
            let axis_touches = if axis {
                eprintln!(
                    "strand calibrate tool: now touch the same point with points further up the nozzle, on its axis (10 mm or more up)"
                );
                live.touches("axis touch", dof, 2, Some(2), false)?.into_iter().map(|(s, _)| s).collect()
            } else {
                Vec::new()
            };
            (touches, axis_touches)
        }
    };
    let flanges = snapshots::poses(&model, &touches)?;
    let fit = tool::solve_tcp(&flanges)?;
    let current = cfg.robot.tool.frame().rotation;
    let axis_fit =
        if axis_touches.is_empty() { None } else { Some(tool::solve_axis(&fit, &snapshots::poses(&model, &axis_touches)?, &current)?) };
    let mut written = None;
    if let Some(w) = &opts.write {
        let file = tool_file(w)?;
        let mut edit = ConfigEdit::open(&file)?;
        edit.set_array("tool", "xyz", &vec3(&fit.xyz), DECIMALS)?;
        if let Some(a) = &axis_fit {
            edit.set_array("tool", "rpy", &a.rpy, DECIMALS)?;
        }
        if file == *w {
            // A robot file: it must load again on its own.
            let before = std::fs::read_to_string(&file)
                .map_err(|e| CalibrationError::Config { file: file.display().to_string(), message: format!("cannot read: {e}") })?;
            edit.save()?;
            if let Err(e) = RobotConfig::load(&file) {
                let _ = std::fs::write(&file, before);
                return Err(e.into());
            }
        } else {
            save_checked(&edit, w)?;
        }
        written = Some(file);
    }
    if opts.json {
        let mut v = json!({
            "xyz": vec3(&fit.xyz),
            "point": vec3(&fit.point),
            "residuals_mm": fit.residuals_mm,
            "condition": fit.condition,
            "warnings": fit.warnings,
        });
        if let Some(a) = &axis_fit {
            v["rpy"] = json!(a.rpy);
            v["axis"] = json!(vec3(&a.z));
            v["axis_residuals_mm"] = json!(a.residuals_mm);
        }
        if let Some(f) = &written {
            v["written"] = json!(f.display().to_string());
        }
        return Ok(format!("{v}\n"));
    }
    let mut out = String::new();
    let _ = writeln!(out, "tool from {} touches (flange frame, m):", touches.len());
    let _ = writeln!(out, "[tool]\nxyz = {}", m6(&vec3(&fit.xyz)));
    if let Some(a) = &axis_fit {
        let _ = writeln!(out, "rpy = {}", m6(&a.rpy));
    }
    let _ = writeln!(out, "touched point (robot base frame, m): {}", m6(&vec3(&fit.point)));
    let _ = writeln!(out, "residuals (mm): {}  (max {:.3})", mm(&fit.residuals_mm), fit.residuals_mm.iter().copied().fold(0.0, f64::max));
    let _ = writeln!(out, "condition: {:.2}", fit.condition);
    if let Some(a) = &axis_fit {
        let _ = writeln!(
            out,
            "nozzle axis (flange frame): {}; {:.2}° from the configured one; axis residuals (mm): {}",
            m6(&vec3(&a.z)),
            a.change_deg,
            mm(&a.residuals_mm)
        );
    }
    for w in &fit.warnings {
        let _ = writeln!(out, "warning: {w}");
    }
    if let Some(f) = &written {
        let _ = writeln!(out, "written to {}", f.display());
    }
    Ok(out)
}

/// The base pose B in W this config assumes (the mount), for mapping touched points into W.
fn base_in_world(cfg: &Config) -> Frame {
    cfg.base.mount()
}

fn frame_verb(cfg: &Config, opts: &CalibrateOptions, prefix: &str, input: &mut dyn BufRead) -> Result<String> {
    let model = cfg.robot.build_model()?;
    if cfg.robot.external_axes().is_some() {
        eprintln!("strand calibrate frame: the snapshots hold the arm's joints only; a positioner or track is taken at 0");
    }
    let touches = read_touches(opts, prefix, "point", model.dof(), frame::MIN_POINTS, input)?;
    let mount = base_in_world(cfg);
    let tcps: Vec<Frame> = snapshots::poses(&model, &touches)?.into_iter().map(|t| mount * t).collect();
    let points: Vec<Vector3<f64>> = tcps.iter().map(|t| t.translation.vector).collect();
    let nozzle: Vector3<f64> = tcps.iter().map(|t| t.rotation * Vector3::z()).sum();
    let fit = frame::solve_frame(&points, Some(nozzle))?;
    let mut written = None;
    if let Some(w) = &opts.write {
        let mut edit = ConfigEdit::open(w)?;
        edit.set_pose("bed", "frame", &fit.xyz, &fit.rpy, &["tilt", "offset"])?;
        save_checked(&edit, w)?;
        written = Some(w.clone());
    }
    let mut notes = Vec::new();
    if cfg.base.mode == BaseMode::Tracked {
        notes.push("the base is tracked: the points were mapped into W with [base] mount, the pose assumed before tracking".to_string());
    }
    if opts.json {
        let mut v = json!({
            "xyz": fit.xyz,
            "rpy": fit.rpy,
            "flatness_mm": fit.flatness_mm,
            "residuals_mm": fit.residuals_mm,
            "points": points.iter().map(vec3).collect::<Vec<_>>(),
            "notes": notes,
        });
        if let Some(f) = &written {
            v["written"] = json!(f.display().to_string());
        }
        return Ok(format!("{v}\n"));
    }
    let mut out = String::new();
    let _ = writeln!(out, "bed frame from {} points (W; m, rad):", points.len());
    let _ = writeln!(out, "[bed]\nframe = {{ xyz = {}, rpy = {} }}", m6(&fit.xyz), m6(&fit.rpy));
    let _ = writeln!(out, "flatness (peak to valley from the plane): {:.3} mm", fit.flatness_mm);
    let _ = writeln!(out, "distances from the plane (mm): {}", mm(&fit.residuals_mm));
    for n in &notes {
        let _ = writeln!(out, "note: {n}");
    }
    if let Some(f) = &written {
        let _ = writeln!(out, "written to {} (tilt and offset replaced)", f.display());
    }
    Ok(out)
}

fn mesh_verb(cfg: &Config, opts: &CalibrateOptions, mesh: &MeshOptions, prefix: &str, input: &mut dyn BufRead) -> Result<String> {
    let current = cfg.bed.mesh.as_ref();
    let grid = mesh.grid.or_else(|| current.map(|m| m.counts().into())).ok_or_else(|| CalibrationError::BadValue {
        what: "grid",
        reason: "the config has no [bed.mesh] to take the grid from: say --grid NXxNY (nodes along x and y)".into(),
    })?;
    let bounds = mesh.bounds.or_else(|| if mesh.grid.is_none() { current.map(|m| (m.min, m.max)) } else { None });
    let algorithm = mesh.algorithm.or_else(|| current.map(|m| m.algorithm)).unwrap_or_default();
    let bed = cfg.bed_transform()?;
    let (points, source) = match &mesh.points {
        Some(file) => (strand_calibrate::mesh::read_points(file)?, format!("probed points from {}", file.display())),
        None => {
            let model = cfg.robot.build_model()?;
            if let Some((lo, hi)) = bounds
                && opts.snapshots.is_none()
            {
                eprintln!(
                    "touch the bed with the nozzle near each node of the {}×{} grid (bed frame, mm), in any order:",
                    grid[0], grid[1]
                );
                for j in 0..grid[1] {
                    let y = lo[1] + (hi[1] - lo[1]) * j as f64 / (grid[1] - 1) as f64;
                    let row: Vec<String> = (0..grid[0])
                        .map(|i| format!("({:.1}, {:.1})", (lo[0] + (hi[0] - lo[0]) * i as f64 / (grid[0] - 1) as f64) * 1e3, y * 1e3))
                        .collect();
                    eprintln!("  {}", row.join(" "));
                }
            }
            let touches = read_touches(opts, prefix, "point", model.dof(), strand_calibrate::mesh::MIN_POINTS, input)?;
            let mount = base_in_world(cfg);
            let tcps: Vec<Frame> = snapshots::poses(&model, &touches)?.into_iter().map(|t| mount * t).collect();
            (tcps.iter().map(|t| bed.to_bed(&t.translation.vector)).collect(), format!("{} nozzle touches", tcps.len()))
        }
    };
    let fit = strand_calibrate::mesh::solve_mesh(&points, strand_calibrate::mesh::MeshGrid { algorithm, counts: grid, bounds })?;
    let algorithm_name = match algorithm {
        strand_core::MeshAlgorithm::Bilinear => "bilinear",
        strand_core::MeshAlgorithm::Bicubic => "bicubic",
    };
    let mut written = None;
    if let Some(w) = &opts.write {
        let mut edit = ConfigEdit::open(w)?;
        edit.set_bed_mesh(&fit.min, &fit.max, &fit.points, Some(algorithm_name))?;
        save_checked(&edit, w)?;
        written = Some(w.clone());
    }
    let mut notes = Vec::new();
    let tilt = fit.tilt_mrad[0].hypot(fit.tilt_mrad[1]);
    if tilt > 1.0 {
        notes.push(format!(
            "the touches' mean plane is tilted {tilt:.2} mrad against the bed frame: the mesh takes it out, but `strand calibrate frame` first keeps the layers above the fade level"
        ));
    }
    let rms = (fit.residuals_mm.iter().map(|r| r * r).sum::<f64>() / fit.residuals_mm.len() as f64).sqrt();
    if rms > 0.02 {
        notes.push(format!("the touches depart from the fitted surface by {rms:.3} mm RMS: a finer --grid, or touch again"));
    }
    if opts.json {
        let mut v = json!({
            "min": fit.min,
            "max": fit.max,
            "points": fit.points,
            "grid": grid,
            "algorithm": algorithm_name,
            "range_mm": fit.range_mm,
            "tilt_mrad": fit.tilt_mrad,
            "residuals_mm": fit.residuals_mm,
            "notes": notes,
        });
        if let Some(f) = &written {
            v["written"] = json!(f.display().to_string());
        }
        return Ok(format!("{v}\n"));
    }
    let mut out = String::new();
    let _ = writeln!(out, "bed mesh from {source} (bed frame; m):");
    let _ = writeln!(out, "[bed.mesh]\nmin = {}\nmax = {}\nalgorithm = \"{algorithm_name}\"\npoints = [", m6_2(&fit.min), m6_2(&fit.max));
    for row in &fit.points {
        let _ = writeln!(out, "    [{}],", row.iter().map(|z| format!("{z:.6}")).collect::<Vec<_>>().join(", "));
    }
    let _ = writeln!(out, "]");
    let _ = writeln!(out, "range (highest minus lowest node): {:.3} mm", fit.range_mm);
    let _ = writeln!(out, "mean plane slope: x {:.3} mrad, y {:.3} mrad", fit.tilt_mrad[0], fit.tilt_mrad[1]);
    let _ = writeln!(out, "each point minus the surface (mm): {}", mm(&fit.residuals_mm));
    for n in &notes {
        let _ = writeln!(out, "note: {n}");
    }
    if let Some(f) = &written {
        let _ = writeln!(out, "written to {} ([bed.mesh]; its fade kept)", f.display());
    }
    Ok(out)
}

fn m6_2(v: &[f64; 2]) -> String {
    format!("[{:.6}, {:.6}]", v[0], v[1])
}

fn base_verb(cfg: &Config, opts: &CalibrateOptions, prefix: &str, input: &mut dyn BufRead) -> Result<String> {
    let model = flange_model(&cfg.robot)?;
    let dof = model.dof();
    let (touches, markers, bodies): (Vec<Snapshot>, Vec<Frame>, Vec<Option<Frame>>) = match &opts.snapshots {
        Some(path) => {
            let pairs = pairs::read_pairs(path, dof)?;
            let touches = pairs.iter().map(|p| p.snapshot.clone()).collect();
            let markers = pairs.iter().map(|p| p.marker).collect();
            let bodies = pairs.iter().map(|p| p.base_body).collect();
            (touches, markers, bodies)
        }
        None => {
            let mut live = Live::open(prefix, ClientRoles { measurements: true, ..Default::default() }, input)?;
            eprintln!(
                "strand calibrate base: the tracker publishes the flange's marker body as the BasePose; move the arm to 4 or more poses, \
                 turning the wrist about different axes, and take each"
            );
            let taken = live.touches("pose", dof, handeye::MIN_POSES, None, true)?;
            let markers = taken.iter().filter_map(|(_, p)| *p).collect();
            let touches = taken.into_iter().map(|(s, _)| s).collect::<Vec<_>>();
            let bodies = vec![None; touches.len()];
            (touches, markers, bodies)
        }
    };
    let relative = bodies.iter().any(Option::is_some);
    let markers: Vec<Frame> = markers.iter().zip(&bodies).map(|(m, b)| b.map_or(*m, |b| b.inverse() * *m)).collect();
    let flanges = snapshots::poses(&model, &touches)?;
    let fit = handeye::solve_hand_eye(&flanges, &markers)?;
    let frame_of = if relative { "the base body's frame" } else { "the tracker's frame" };
    // Where the answer lives: B in the tracker's frame (the cell's W) is the mount; B in the base
    // body's frame is the transform strand-natnet applies to the body it tracks (for a tracked base
    // the service takes each BasePose as B in W, the mount being only the pose before the first).
    let home = if relative { "[tracker] body_xyz / body_rpy" } else { "[base] mount" };
    let mut written = None;
    if let Some(w) = &opts.write {
        let mut edit = ConfigEdit::open(w)?;
        if relative {
            if !edit.has_section("tracker") {
                return Err(CalibrateError::Calibration(CalibrationError::Config {
                    file: w.display().to_string(),
                    message: "the answer is B in the base body's frame, which strand-natnet applies as [tracker] body_xyz / body_rpy, \
                              and this file has no [tracker] section: add it (config/default.toml shows it) and write again"
                        .into(),
                }));
            }
            edit.set_array("tracker", "body_xyz", &fit.mount_xyz, DECIMALS)?;
            edit.set_array("tracker", "body_rpy", &fit.mount_rpy, DECIMALS)?;
        } else {
            edit.set_pose("base", "mount", &fit.mount_xyz, &fit.mount_rpy, &["mount_xyz", "mount_rpy"])?;
        }
        save_checked(&edit, w)?;
        written = Some(w.clone());
    }
    let hand_xyz = vec3(&fit.hand.translation.vector);
    let (r, p, y) = fit.hand.rotation.euler_angles();
    if opts.json {
        let mut v = json!({
            "method": handeye::METHOD,
            "xyz": fit.mount_xyz,
            "rpy": fit.mount_rpy,
            "frame": if relative { "base-body" } else { "tracker" },
            "key": home,
            "marker_xyz": hand_xyz,
            "marker_rpy": [r, p, y],
            "residuals_mm": fit.residuals_mm,
            "residuals_deg": fit.residuals_deg,
            "condition": fit.condition,
            "warnings": fit.warnings,
        });
        if let Some(f) = &written {
            v["written"] = json!(f.display().to_string());
        }
        return Ok(format!("{v}\n"));
    }
    let mut out = String::new();
    let _ = writeln!(out, "base frame B in {frame_of}, from {} poses (hand–eye AX = XB, Park–Martin):", touches.len());
    if relative {
        let _ = writeln!(out, "[tracker]\nbody_xyz = {}\nbody_rpy = {}", m6(&fit.mount_xyz), m6(&fit.mount_rpy));
    } else {
        let _ = writeln!(out, "[base]\nmount = {{ xyz = {}, rpy = {} }}", m6(&fit.mount_xyz), m6(&fit.mount_rpy));
    }
    let _ = writeln!(out, "marker body in the flange frame: xyz {} m, rpy {} rad", m6(&hand_xyz), m6(&[r, p, y]));
    let _ = writeln!(out, "residuals (mm): {}", mm(&fit.residuals_mm));
    let _ = writeln!(out, "residuals (deg): {}", mm(&fit.residuals_deg));
    let _ = writeln!(out, "rotation condition: {:.2}", fit.condition);
    for w in &fit.warnings {
        let _ = writeln!(out, "warning: {w}");
    }
    if let Some(f) = &written {
        let _ = writeln!(out, "written to {} ({home})", f.display());
    }
    Ok(out)
}

fn extruder_verb(
    cfg: &Config,
    opts: &CalibrateOptions,
    prefix: &str,
    commanded: f64,
    measured: Option<f64>,
    speed: f64,
    input: &mut dyn BufRead,
) -> Result<String> {
    let radius = cfg.extruder.drive_wheel_radius;
    let measured = match measured {
        Some(m) => m,
        None => {
            extrude(cfg, prefix, commanded, speed)?;
            eprint!("strand calibrate extruder: {:.1} mm commanded; how many mm went in? ", commanded * 1e3);
            let _ = std::io::stderr().flush();
            let mut line = String::new();
            input.read_line(&mut line).map_err(|e| CalibrateError::Live(format!("reading the answer: {e}")))?;
            let mm: f64 = line.trim().parse().map_err(|_| {
                CalibrateError::Calibration(CalibrationError::BadValue {
                    what: "measured",
                    reason: format!("{:?} is not a length in mm", line.trim()),
                })
            })?;
            mm * 1e-3
        }
    };
    let fit = extruder::rescale(radius, commanded, measured)?;
    let mut written = None;
    if let Some(w) = &opts.write {
        let mut edit = ConfigEdit::open(w)?;
        edit.set_number("extruder", "drive_wheel_radius", fit.drive_wheel_radius, 9)?;
        save_checked(&edit, w)?;
        written = Some(w.clone());
    }
    if opts.json {
        let mut v = json!({
            "drive_wheel_radius": fit.drive_wheel_radius,
            "previous": fit.previous,
            "ratio": fit.ratio,
            "commanded_mm": commanded * 1e3,
            "measured_mm": measured * 1e3,
        });
        if let Some(f) = &written {
            v["written"] = json!(f.display().to_string());
        }
        return Ok(format!("{v}\n"));
    }
    let mut out = String::new();
    let _ = writeln!(out, "{:.2} mm measured for {:.2} mm commanded (× {:.4}):", measured * 1e3, commanded * 1e3, fit.ratio);
    let _ = writeln!(out, "[extruder]\ndrive_wheel_radius = {:.9}  # m, was {:.9}", fit.drive_wheel_radius, fit.previous);
    if let Some(f) = &written {
        let _ = writeln!(out, "written to {}", f.display());
    }
    Ok(out)
}

/// Extrudes `length` (m) of filament at `speed` (m/s) through the service, the arm standing where it
/// is: a one-segment job, a dwell that moves filament at the TCP's present pose (the core's
/// approach is skipped, the arm is already there). Returns when the job has ended.
fn extrude(cfg: &Config, prefix: &str, length: f64, speed: f64) -> Result<()> {
    if !(length.is_finite() && length > 0.0 && speed.is_finite() && speed > 0.0) {
        return Err(CalibrateError::Calibration(CalibrationError::BadValue {
            what: "--commanded / --speed",
            reason: "must be finite and > 0".into(),
        }));
    }
    let roles = ClientRoles { feeder: true, monitor: true, measurements: true, ..Default::default() };
    let ports = ClientPorts::open(&ipc::ServiceNames::new(prefix), &format!("strand-calibrate-{}", std::process::id()), roles)?;
    let status = wait_for(
        Duration::from_secs(3),
        || ports.latest_status(),
        || format!("no Status from a service under {prefix} within 3 s: is `strand run` running?"),
    )?;
    if status.job_outcome == ipc::JobOutcome::InProgress as u32 || status.fault != 0 {
        return Err(CalibrateError::Live("the service has a job in progress or a fault: stop or clear it first".into()));
    }
    let model = cfg.robot.build_model()?;
    let joints = wait_for(
        Duration::from_secs(1),
        || ports.latest_joint_state(),
        || format!("no JointState under {prefix} within 1 s: is the robot driver running?"),
    )?;
    let mut q = strand_core::kin::JointVector::zeros();
    for k in 0..model.dof().min(joints.dof as usize) {
        q[k] = joints.position[k];
    }
    let base = match (cfg.base.mode, ports.latest_base_pose()) {
        (BaseMode::Tracked, Some(p)) => pose_frame(&p),
        _ => cfg.base.mount(),
    };
    let tcp = base * model.forward_kinematics(&q);
    let at = tcp * Point3::origin();
    let o = UnitQuaternion::from_rotation_matrix(&tcp.rotation);
    let duration = length / speed;
    let now = monotonic_ns();
    let segment = ipc::Segment {
        seq: 1,
        stamp_ns: now,
        kind: ipc::SegmentKind::Dwell as u32,
        flags: ipc::segment_flags::EXTRUDE | ipc::segment_flags::LAYER_START | ipc::segment_flags::LAST,
        end: [at.x, at.y, at.z],
        orientation: [o.w, o.i, o.j, o.k],
        filament: length,
        duration,
        ..Default::default()
    };
    let mut batch = ipc::SegmentBatch { seq: 1, stamp_ns: now, len: 1, ..Default::default() };
    batch.segments[0] = segment;
    let control =
        |seq: u64, command: ipc::Command| ipc::Control { seq, stamp_ns: monotonic_ns(), command: command as u32, value: 0.0, _reserved: 0 };
    let sent_at = Instant::now();
    while ports.send_segments(&batch)? == 0 {
        if sent_at.elapsed() > Duration::from_secs(1) {
            return Err(CalibrateError::Live("the service does not subscribe to segments".into()));
        }
        std::thread::sleep(Duration::from_millis(10));
    }
    ports.send_control(&control(1, ipc::Command::Start))?;
    eprintln!("strand calibrate extruder: extruding {:.1} mm at {:.2} mm/s ({duration:.0} s)", length * 1e3, speed * 1e3);
    let end = Instant::now() + Duration::from_secs_f64(duration + 30.0);
    let mut seen = false;
    loop {
        if let Some(s) = ports.latest_status() {
            let outcome = ipc::JobOutcome::from_u32(s.job_outcome);
            seen |= outcome == Some(ipc::JobOutcome::InProgress);
            let idle = matches!(ipc::RunState::from_u32(s.run_state), Some(ipc::RunState::Idle | ipc::RunState::Fault));
            if s.last_rejected_seq == 1 && s.rejected > status.rejected {
                return Err(CalibrateError::Live(format!(
                    "the service refused the extrusion: {:?}",
                    ipc::RejectReason::from_u32(s.last_reject_reason).unwrap_or_default()
                )));
            }
            if seen && idle {
                return match outcome {
                    Some(ipc::JobOutcome::Finished) => Ok(()),
                    other => {
                        Err(CalibrateError::Live(format!("the extrusion ended {other:?} (fault {:?})", ipc::FaultCode::from_u32(s.fault))))
                    }
                };
            }
        }
        if Instant::now() > end {
            let _ = ports.send_control(&control(2, ipc::Command::Stop));
            return Err(CalibrateError::Live("the extrusion did not end in time: stopped".into()));
        }
        let _ = ports.wait_status(20_000_000);
    }
}
