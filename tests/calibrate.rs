//! `strand calibrate` end to end: snapshot and pairs files made with the project's own FK from known
//! answers, written to a scratch copy of a bundled config; the JSON answer parsed and compared with
//! the truth; `--write` keeps the file's comments and the config loads again; degenerate touches
//! and bad files end with their exit code and a reason. One live reading: joint states published on
//! the service's ports, the touches taken on Enter.

use std::io::{BufRead, BufReader, Write};
use std::path::PathBuf;
use std::process::{Command, Output, Stdio};

use nalgebra::{Point3, UnitQuaternion, Vector3};
use strand::config::Config;
use strand_core::kin::{Frame, JointVector, RobotModel, geom};

#[path = "../tools/calibrate/tests/common/mod.rs"]
mod common;

use common::frame;

/// A scratch copy of the KR 6 cell's config (the service config, its robot file and URDF).
fn kr6_cell(name: &str) -> PathBuf {
    let dir = strand_testkit::temp_dir("calibrate", name);
    std::fs::create_dir_all(dir.join("robots")).unwrap();
    let root = strand_testkit::root().join("config");
    for f in ["kr6r900.toml", "robots/kr6r900.toml", "robots/kr6r900.urdf"] {
        std::fs::copy(root.join(f), dir.join(f)).unwrap();
    }
    dir
}

fn strand(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_strand")).args(args).stdin(Stdio::null()).output().unwrap()
}

fn json(out: &Output) -> serde_json::Value {
    assert!(out.status.success(), "exit {:?}: {}", out.status.code(), String::from_utf8_lossy(&out.stderr));
    serde_json::from_slice(&out.stdout).unwrap()
}

fn f3(v: &serde_json::Value) -> Vector3<f64> {
    Vector3::new(v[0].as_f64().unwrap(), v[1].as_f64().unwrap(), v[2].as_f64().unwrap())
}

fn flange_model(cfg: &Config) -> RobotModel {
    RobotModel::from_urdf_str(&cfg.robot.urdf_text, "kr6r900.urdf", &cfg.robot.root_link, &cfg.robot.tip_link).unwrap()
}

fn home() -> JointVector {
    common::kr6_home()
}

/// Joints that put `model`'s TCP at `target` (from the KR 6's start pose).
fn ik(model: &RobotModel, target: &Frame) -> JointVector {
    common::ik(model, target, &home())
}

fn csv_line(q: &JointVector, dof: usize) -> String {
    (0..dof).map(|k| format!("{:.15}", q[k])).collect::<Vec<_>>().join(", ")
}

const TRUE_TOOL: [f64; 3] = [0.1034, 0.0042, -0.0031];

/// Six touches of one point with the tool at [`TRUE_TOOL`] (the configured rotation), tilted by
/// `angle` rad in different directions.
fn tool_touches(cfg: &Config, angle: f64) -> String {
    let model = flange_model(cfg).with_tool(frame(TRUE_TOOL, cfg.robot.tool.rpy)).unwrap();
    let at = model.forward_kinematics(&home());
    let ax = |x: f64, y: f64, a: f64| geom::axis_angle(&Vector3::new(x, y, 0.0).normalize(), a);
    let tilts =
        [ax(1.0, 0.0, angle), ax(1.0, 0.0, -angle), ax(0.0, 1.0, angle), ax(0.0, 1.0, -angle), ax(1.0, 1.0, angle), ax(-1.0, 1.0, angle)];
    let mut text = String::from("# strand calibrate tool: KR 6 A1..A6 (rad)\n");
    for r in tilts {
        let q = ik(&model, &Frame::from_parts(at.translation, r * at.rotation));
        text += &format!("{}  # a touch\n", csv_line(&q, 6));
    }
    text
}

#[test]
fn tool_from_snapshots_written_into_the_robot_file() {
    let dir = kr6_cell("tool");
    let config = dir.join("kr6r900.toml");
    let cfg = Config::load(&config).unwrap();
    std::fs::write(dir.join("touches.csv"), tool_touches(&cfg, 0.5)).unwrap();
    let (c, s, w) = (config.to_str().unwrap(), dir.join("touches.csv"), config.to_str().unwrap());
    let v = json(&strand(&["calibrate", "tool", "--config", c, "--snapshots", s.to_str().unwrap(), "--json", "--write", w]));
    let xyz = f3(&v["xyz"]);
    assert!((xyz - Vector3::from(TRUE_TOOL)).norm() < 1e-9, "{xyz:?}");
    let point = f3(&v["point"]);
    let expected = flange_model(&cfg).with_tool(frame(TRUE_TOOL, cfg.robot.tool.rpy)).unwrap().forward_kinematics(&home());
    assert!((point - expected.translation.vector).norm() < 1e-9, "{point:?}");
    let residuals = v["residuals_mm"].as_array().unwrap();
    assert_eq!(residuals.len(), 6);
    assert!(residuals.iter().all(|r| r.as_f64().unwrap() < 1e-6), "{residuals:?}");
    let condition = v["condition"].as_f64().unwrap();
    assert!(condition > 1.0 && condition < 8.0, "{condition}");
    // Written into the robot file the config names, its comments kept, and it loads again.
    let robot = std::fs::read_to_string(dir.join("robots/kr6r900.toml")).unwrap();
    assert!(robot.contains("# Flange (tip link) -> TCP at the nozzle tip; TCP z points along the nozzle"), "{robot}");
    assert!(robot.contains("# rad/s^2, per joint in chain order"), "{robot}");
    assert!(robot.contains("xyz = [0.1034, 0.0042, -0.0031]"), "{robot}");
    let again = Config::load(&config).unwrap();
    assert_eq!(again.robot.tool.xyz, TRUE_TOOL);
    assert_eq!(again.robot.tool.rpy, cfg.robot.tool.rpy);
    // Text output says the same.
    let out = strand(&["calibrate", "tool", "--config", c, "--snapshots", s.to_str().unwrap()]);
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success() && text.contains("xyz = [0.103400, 0.004200, -0.003100]"), "{text}");
}

#[test]
fn tool_touches_from_one_orientation_are_refused_with_exit_3() {
    let dir = kr6_cell("tool-degenerate");
    let config = dir.join("kr6r900.toml");
    let cfg = Config::load(&config).unwrap();
    std::fs::write(dir.join("touches.csv"), tool_touches(&cfg, 0.0)).unwrap();
    let before = std::fs::read_to_string(dir.join("robots/kr6r900.toml")).unwrap();
    let s = dir.join("touches.csv");
    let c = config.to_str().unwrap();
    let out = strand(&["calibrate", "tool", "--config", c, "--snapshots", s.to_str().unwrap(), "--json", "--write", c]);
    assert_eq!(out.status.code(), Some(3));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("too alike") && err.contains("condition"), "{err}");
    assert!(out.stdout.is_empty());
    assert_eq!(std::fs::read_to_string(dir.join("robots/kr6r900.toml")).unwrap(), before);
}

#[test]
fn a_bad_snapshot_line_names_file_line_and_column() {
    let dir = kr6_cell("bad-csv");
    let c = dir.join("kr6r900.toml");
    let s = dir.join("touches.csv");
    std::fs::write(&s, "# ok\n0, -1.5, 1.5, 0, 1.5, 0\n0, -1.5, x1, 0, 1.5, 0\n").unwrap();
    let out = strand(&["calibrate", "tool", "--config", c.to_str().unwrap(), "--snapshots", s.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(2));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains(&format!("{}:3:10: \"x1\" is not a number", s.display())), "{err}");
    std::fs::write(&s, "0, -1.5, 1.5, 0, 1.5\n").unwrap();
    let out = strand(&["calibrate", "frame", "--config", c.to_str().unwrap(), "--snapshots", s.to_str().unwrap()]);
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains(":1:0: 5 fields, expected 6 joint angles"));
}

/// Touches (KR 6 joints) of the bed at `bed` (in W = B: the cell's mount is the identity) at `uv`.
fn bed_touches(cfg: &Config, bed: &Frame, uv: &[[f64; 2]]) -> Vec<JointVector> {
    let model = cfg.robot.build_model().unwrap();
    let down = bed.rotation * geom::axis_angle(&Vector3::y(), std::f64::consts::PI);
    uv.iter().map(|p| ik(&model, &Frame::from_parts((bed * Point3::new(p[0], p[1], 0.0)).coords.into(), down))).collect()
}

#[test]
fn frame_from_snapshots_replaces_tilt_and_offset() {
    let dir = kr6_cell("frame");
    let config = dir.join("kr6r900.toml");
    let cfg = Config::load(&config).unwrap();
    let truth = frame([0.42, -0.1, 0.24], [0.02, -0.015, 0.3]);
    let qs = bed_touches(&cfg, &truth, &[[0.0, 0.0], [0.15, 0.0], [0.03, 0.1], [0.15, 0.12]]);
    let text: String = qs.iter().map(|q| csv_line(q, 6) + "\n").collect();
    let s = dir.join("bed.csv");
    std::fs::write(&s, text).unwrap();
    let c = config.to_str().unwrap();
    let v = json(&strand(&["calibrate", "frame", "--config", c, "--snapshots", s.to_str().unwrap(), "--json", "--write", c]));
    let xyz = f3(&v["xyz"]);
    let rpy = f3(&v["rpy"]);
    assert!((xyz - truth.translation.vector).norm() < 1e-9, "{xyz:?}");
    assert!(geom::rpy(rpy.x, rpy.y, rpy.z).angle_to(&truth.rotation) < 1e-9, "{rpy:?}");
    assert!(v["flatness_mm"].as_f64().unwrap() < 1e-6);
    let written = std::fs::read_to_string(&config).unwrap();
    assert!(written.contains("# replaced by `strand calibrate`: tilt = 0.0, offset = [0.375, -0.125, 0.25]"), "{written}");
    assert!(written.contains("frame = { xyz = [0.42, -0.1, 0.24], rpy = [0.02, -0.015, 0.3] }"), "{written}");
    assert!(!written.contains("\ntilt = "), "{written}");
    assert!(written.contains("# strand check-job (src/check/): what the job check flags before printing."));
    let again = Config::load(&config).unwrap();
    let bed = again.bed_transform().unwrap();
    assert!((bed.point(&Vector3::new(0.01, 0.02, 0.0)) - (truth * Point3::new(0.01, 0.02, 0.0)).coords).norm() < 1e-6);
    // Three collinear points: refused, the file untouched.
    let qs = bed_touches(&cfg, &truth, &[[0.0, 0.0], [0.1, 0.0], [0.2, 0.0]]);
    std::fs::write(&s, qs.iter().map(|q| csv_line(q, 6) + "\n").collect::<String>()).unwrap();
    let out = strand(&["calibrate", "frame", "--config", c, "--snapshots", s.to_str().unwrap(), "--write", c]);
    assert_eq!(out.status.code(), Some(3));
    assert!(String::from_utf8_lossy(&out.stderr).contains("collinear"));
    assert_eq!(std::fs::read_to_string(&config).unwrap(), written);
}

/// The bed mesh from nozzle touches (KR 6 joints) on a warped bed near the nodes of a 4 × 3 grid:
/// the heights come back within the IK's precision, `--write` adds `[bed.mesh]` at the end of the
/// file, the config loads with it and `check-job` names it; a node without a touch is refused.
#[test]
fn mesh_from_snapshots_written_into_bed_mesh() {
    let dir = kr6_cell("mesh");
    let config = dir.join("kr6r900.toml");
    let cfg = Config::load(&config).unwrap();
    let bed = cfg.bed_transform().unwrap();
    let surface = |x: f64, y: f64| 2e-3 * (x - 0.05) + 0.2e-3 * ((x - 0.06) / 0.06).powi(2) - 0.1e-3 * (y / 0.05);
    // Touches up to 1 mm off the nodes, inside the grid, the tip on the surface; bed frame (m).
    let nodes: Vec<[f64; 2]> = (0..3).flat_map(|j| (0..4).map(move |i| [0.04 * i as f64, 0.05 * j as f64])).collect();
    let inward = |v: f64, top: f64, d: f64| if v + d > top || v + d < 0.0 { v - d } else { v + d };
    let touched: Vec<Vector3<f64>> = nodes
        .iter()
        .enumerate()
        .map(|(k, n)| (inward(n[0], 0.12, 1e-3 * (k % 2) as f64), inward(n[1], 0.1, -0.5e-3 * (k % 3) as f64)))
        .map(|(x, y)| Vector3::new(x, y, surface(x, y)))
        .collect();
    let model = cfg.robot.build_model().unwrap();
    let down = bed.tool_orientation().to_rotation_matrix();
    let text: String = touched.iter().map(|p| csv_line(&ik(&model, &Frame::from_parts(bed.point(p).into(), down)), 6) + "\n").collect();
    let s = dir.join("mesh.csv");
    std::fs::write(&s, &text).unwrap();
    let c = config.to_str().unwrap();
    let v = json(&strand(&[
        "calibrate",
        "mesh",
        "--config",
        c,
        "--snapshots",
        s.to_str().unwrap(),
        "--grid",
        "4x3",
        "--min",
        "0,0",
        "--max",
        "120,100",
        "--json",
        "--write",
        c,
    ]));
    assert_eq!(v["grid"], serde_json::json!([4, 3]));
    let points = v["points"].as_array().unwrap();
    for (k, n) in nodes.iter().enumerate() {
        let z = points[k / 4][k % 4].as_f64().unwrap();
        // Bicubic through the nodes, fitted to touches 1 mm off them: the surface's curvature
        // over 1 mm is a fraction of a µm.
        assert!((z - surface(n[0], n[1])).abs() < 5e-6, "node {k}: {z} vs {}", surface(n[0], n[1]));
    }
    let written = std::fs::read_to_string(&config).unwrap();
    let at = written.find("[bed.mesh]").expect("a [bed.mesh] table");
    assert!(written[at..].contains("algorithm = \"bicubic\""), "{written}");
    assert!(written.rfind("\n[").unwrap() <= at, "[bed.mesh] is the file's last table: {written}");
    let again = Config::load(&config).unwrap();
    let mesh = again.bed_transform().unwrap().mesh().cloned().expect("the mesh loads");
    assert!((mesh.height(0.07, 0.03) - surface(0.07, 0.03)).abs() < 20e-6);
    let job = dir.join("line.gcode");
    std::fs::write(&job, "G21\nG90\nM83\nG1 Z0.3 F3000\nG1 X20 Y20 F3000\nG1 X60 Y40 E1.5 F1200\n").unwrap();
    let out = strand(&["check-job", "--config", c, job.to_str().unwrap()]);
    let report = String::from_utf8_lossy(&out.stdout);
    assert!(report.contains("bed mesh   4×3 over x 0.0…120.0 mm, y 0.0…100.0 mm"), "{report}");
    // Touches that leave a node far away: refused naming it, nothing written.
    std::fs::write(&s, text.lines().take(11).map(|l| format!("{l}\n")).collect::<String>()).unwrap();
    let out = strand(&["calibrate", "mesh", "--config", c, "--snapshots", s.to_str().unwrap(), "--grid", "4x3", "--write", c]);
    assert_eq!(out.status.code(), Some(3), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(String::from_utf8_lossy(&out.stderr).contains("no touch near node (4, 3)"), "{}", String::from_utf8_lossy(&out.stderr));
    assert_eq!(Config::load(&config).unwrap().bed.mesh, again.bed.mesh);
}

fn pose_columns(f: &Frame) -> String {
    let q = UnitQuaternion::from_rotation_matrix(&f.rotation);
    let t = f.translation.vector;
    format!("{:.15}, {:.15}, {:.15}, {:.15}, {:.15}, {:.15}, {:.15}", t.x, t.y, t.z, q.w, q.i, q.j, q.k)
}

#[test]
fn base_from_pairs_by_hand_eye_into_the_mount_or_the_tracker_body() {
    let dir = kr6_cell("base");
    let config = dir.join("kr6r900.toml");
    let cfg = Config::load(&config).unwrap();
    let model = flange_model(&cfg);
    let z = frame([1.2, -0.4, 0.1], [0.01, 0.02, 1.9]);
    let x = frame([0.02, 0.03, 0.05], [0.3, 0.5, -0.7]);
    let mut plain = String::from("# q1..q6, marker x y z qw qx qy qz\n");
    let mut with_body = String::new();
    let zb = frame([0.1, -0.05, -0.3], [0.0, 0.0, 0.5]);
    for k in 0..8 {
        // Every joint moved by a different pseudo-random amount within ±0.5 rad.
        let mut q = home();
        for j in 0..6 {
            let h = (((k * 6 + j) as f64 + 1.0) * 12.9898).sin() * 43758.5453;
            q[j] += (h - h.floor() - 0.5) * 1.0;
        }
        let f = model.forward_kinematics(&q);
        plain += &format!("{}, {}\n", csv_line(&q, 6), pose_columns(&(z * f * x)));
        // The base moved between pairs: its body seen at b, B at b·zb.
        let b = frame([0.3 * k as f64, 0.1, 0.0], [0.0, 0.0, 0.2 * k as f64]);
        with_body += &format!("{}, {}, {}\n", csv_line(&q, 6), pose_columns(&(b * zb * f * x)), pose_columns(&b));
    }
    let c = config.to_str().unwrap();
    let solve = |text: &str, extra: &[&str]| {
        let s = dir.join("pairs.csv");
        std::fs::write(&s, text).unwrap();
        let mut args = vec!["calibrate", "base", "--config", c, "--snapshots", s.to_str().unwrap()];
        args.extend(extra);
        strand(&args)
    };
    for (text, truth, key) in [(&plain, z, "[base] mount"), (&with_body, zb, "[tracker] body_xyz / body_rpy")] {
        let v = json(&solve(text, &["--json"]));
        assert_eq!((v["method"].as_str(), v["key"].as_str()), (Some("park-martin"), Some(key)));
        let (xyz, rpy) = (f3(&v["xyz"]), f3(&v["rpy"]));
        assert!((xyz - truth.translation.vector).norm() < 1e-8, "{xyz:?}");
        assert!(geom::rpy(rpy.x, rpy.y, rpy.z).angle_to(&truth.rotation) < 1e-8, "{rpy:?}");
        assert!(v["residuals_mm"].as_array().unwrap().iter().all(|r| r.as_f64().unwrap() < 1e-6));
    }
    // In the tracker's frame: the mount, as one pose replacing mount_xyz / mount_rpy (left as a comment).
    json(&solve(&plain, &["--json", "--write", c]));
    let again = Config::load(&config).unwrap();
    assert!((Vector3::from(again.base.mount_xyz) - z.translation.vector).norm() < 1e-6);
    assert!(geom::rpy(again.base.mount_rpy[0], again.base.mount_rpy[1], again.base.mount_rpy[2]).angle_to(&z.rotation) < 1e-6);
    let written = std::fs::read_to_string(&config).unwrap();
    assert!(written.contains("# replaced by `strand calibrate`: mount_xyz = [0.0, 0.0, 0.0], mount_rpy = [0.0, 0.0, 0.0]\nmount = { xyz = [1.2, -0.4, 0.1], rpy = ["), "{written}");
    // In the base body's frame: strand-natnet's body transform, which needs a [tracker] to go in.
    let out = solve(&with_body, &["--write", c]);
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("has no [tracker] section"), "{}", String::from_utf8_lossy(&out.stderr));
    assert_eq!(std::fs::read_to_string(&config).unwrap(), written, "nothing written");
    std::fs::write(
        &config,
        format!("{written}\n[tracker]\nrigid_body = \"base\"  # Motive's name\nbody_xyz = [0.0, 0.0, 0.0]  # m, kept comment\n"),
    )
    .unwrap();
    json(&solve(&with_body, &["--json", "--write", c]));
    let again = Config::load(&config).unwrap();
    let tracker = again.tracker.expect("[tracker]");
    assert!((Vector3::from(tracker.body_xyz) - zb.translation.vector).norm() < 1e-6, "{:?}", tracker.body_xyz);
    assert!(std::fs::read_to_string(&config).unwrap().contains("# m, kept comment"));
}

#[test]
fn extruder_rescaled_from_commanded_and_measured() {
    let dir = kr6_cell("extruder");
    let config = dir.join("kr6r900.toml");
    let c = config.to_str().unwrap();
    let v = json(&strand(&["calibrate", "extruder", "--config", c, "--commanded", "100", "--measured", "95", "--json", "--write", c]));
    assert!((v["drive_wheel_radius"].as_f64().unwrap() - 5.225e-3).abs() < 1e-12, "{v}");
    assert!((v["previous"].as_f64().unwrap() - 5.5e-3).abs() < 1e-15);
    let again = Config::load(&config).unwrap();
    assert!((again.extruder.drive_wheel_radius - 5.225e-3).abs() < 1e-12);
    assert!(std::fs::read_to_string(&config).unwrap().contains("drive_wheel_radius = 0.005225  # m (002 Eq. 19)"));
    let out = strand(&["calibrate", "extruder", "--config", c, "--commanded", "100", "--measured", "10"]);
    assert_eq!(out.status.code(), Some(3));
    assert!(String::from_utf8_lossy(&out.stderr).contains("factor"));
}

#[test]
fn frame_from_live_joint_states_on_enter() {
    use strand_ipc::ports::{ClientPorts, ClientRoles};
    let dir = kr6_cell("live");
    let config = dir.join("kr6r900.toml");
    let cfg = Config::load(&config).unwrap();
    let truth = frame([0.45, 0.05, 0.22], [0.0, 0.01, -0.2]);
    let qs = bed_touches(&cfg, &truth, &[[0.0, 0.0], [0.12, 0.0], [0.02, 0.09]]);
    let prefix = format!("strand/test-calibrate-{}", std::process::id());
    let names = strand_ipc::ServiceNames::new(&prefix);
    let driver = ClientPorts::open(&names, "test-driver", ClientRoles { driver: true, ..Default::default() }).unwrap();
    let mut child = Command::new(env!("CARGO_BIN_EXE_strand"))
        .args(["calibrate", "frame", "--config", config.to_str().unwrap(), "--prefix", &prefix, "--json"])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut stdin = child.stdin.take().unwrap();
    let stderr = BufReader::new(child.stderr.take().unwrap());
    // The calibration prints the joints it took; every other line (the prompts) is passed over.
    let (tx, rx) = std::sync::mpsc::channel::<String>();
    let reader = std::thread::spawn(move || {
        for line in stderr.lines().map_while(Result::ok) {
            if (line.contains("joints [") || line.contains("strand calibrate:")) && tx.send(line).is_err() {
                return;
            }
        }
    });
    let publish = |q: &JointVector, seq: &mut u64| {
        *seq += 1;
        let mut s = strand_ipc::JointState { seq: *seq, dof: 6, ..Default::default() };
        s.position[..6].copy_from_slice(&q.as_slice()[..6]);
        driver.send_joint_state(&s).unwrap();
    };
    let mut seq = 0;
    for q in &qs {
        // This touch is the newest state before Enter, and stays published until it is taken.
        for _ in 0..3 {
            publish(q, &mut seq);
        }
        writeln!(stdin).unwrap();
        stdin.flush().unwrap();
        let line = loop {
            publish(q, &mut seq);
            match rx.recv_timeout(std::time::Duration::from_millis(5)) {
                Ok(line) => break line,
                Err(std::sync::mpsc::RecvTimeoutError::Timeout) => {}
                Err(e) => panic!("strand calibrate ended before taking the touch: {e}"),
            }
        };
        assert!(line.contains("joints ["), "{line}");
    }
    writeln!(stdin, "d").unwrap();
    drop(stdin);
    let out = child.wait_with_output().unwrap();
    let v = json(&out);
    assert!((f3(&v["xyz"]) - truth.translation.vector).norm() < 1e-9, "{v}");
    let rpy = f3(&v["rpy"]);
    assert!(geom::rpy(rpy.x, rpy.y, rpy.z).angle_to(&truth.rotation) < 1e-9, "{v}");
    reader.join().unwrap();
}
