//! strand-kin's work: check a robot's kinematic chain (joints, limits, tool, reach, manipulability,
//! warnings) and evaluate FK, the Jacobian and manipulability for joint vectors given as JSON lines.
//! [`robot`] says how a tool is told which robot to use.

pub mod robot;

use std::io::{BufRead, Write};
use std::path::Path;

use nalgebra::{UnitQuaternion, Vector3};
use serde_json::{Value, json};
use strand_core::kin::{ChainState, JointKind, JointVector, RobotModel, Task, TaskJacobian, manipulability_gradient};

use robot::LoadedRobot;
use strand_cli::error::{Result, ToolError};

/// An angle in degrees for the table (∞ for an unlimited joint).
fn deg(x: f64) -> String {
    if x.is_finite() {
        format!("{:.1}", x.to_degrees())
    } else if x > 0.0 {
        "∞".into()
    } else {
        "-∞".into()
    }
}

/// Deterministic samples of the joint space (SplitMix64), for the reach estimate.
fn samples(model: &RobotModel, count: usize) -> impl Iterator<Item = JointVector> + '_ {
    let mut state = 0x5EED_u64;
    (0..count).map(move |_| {
        let mut q = JointVector::zeros();
        for (i, j) in model.joints().iter().enumerate() {
            state = state.wrapping_add(0x9E3779B97F4A7C15);
            let mut z = state;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58476D1CE4E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D049BB133111EB);
            let u = ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64;
            let (lo, hi) =
                if j.limits.lower.is_finite() { (j.limits.lower, j.limits.upper) } else { (-std::f64::consts::PI, std::f64::consts::PI) };
            q[i] = lo + (hi - lo) * u;
        }
        q
    })
}

/// Prints the chain of `robot`: its joints and limits, its tool, its reach and manipulability over
/// sampled configurations, and every warning about how it is given.
pub fn check(robot: &LoadedRobot) {
    let m = &robot.model;
    let mut warnings = Vec::new();
    println!("robot   {} ({})", m.name(), m.source());
    println!("chain   {} → {}: {} joints", m.root_link(), m.tip_link(), m.dof());
    println!();
    println!("  #  joint                  type        lower°    upper°   vel°/s  acc°/s²  jerk°/s³  axis  (prismatic: mm, mm/s, …)");
    for (i, j) in m.joints().iter().enumerate() {
        let kind = match j.kind {
            JointKind::Revolute => "revolute",
            JointKind::Continuous => "continuous",
            JointKind::Prismatic => "prismatic",
        };
        let a = j.axis.into_inner();
        // Rotating joints in degrees; a prismatic joint in millimetres (marked "mm").
        let unit = |x: f64| {
            if j.kind.rotates() {
                deg(x)
            } else if x.is_finite() {
                format!("{:.1}mm", x * 1e3)
            } else {
                deg(x)
            }
        };
        println!(
            "  {}  {:<22} {:<10} {:>8} {:>9} {:>8} {:>8} {:>9}  [{:.3} {:.3} {:.3}]",
            i + 1,
            j.name,
            kind,
            unit(j.limits.lower),
            unit(j.limits.upper),
            unit(j.limits.velocity),
            unit(j.limits.acceleration),
            unit(j.limits.jerk),
            a.x,
            a.y,
            a.z
        );
        if j.kind.rotates() && j.limits.lower.is_finite() && j.limits.upper - j.limits.lower > 2.0 * std::f64::consts::PI + 1e-3 {
            warnings.push(format!("{}: its range {}°…{}° is more than one turn", j.name, deg(j.limits.lower), deg(j.limits.upper)));
        }
        if j.limits.lower > 0.0 || j.limits.upper < 0.0 {
            warnings.push(format!("{}: q = 0 lies outside its limits (the zero pose is not reachable)", j.name));
        }
    }
    let v0 = m.joints()[0].limits.velocity;
    if m.dof() > 1 && m.joints().iter().all(|j| j.limits.velocity == v0) {
        warnings.push(format!("every joint has the same velocity limit ({} rad/s): likely a placeholder, not the maker's data", v0));
    }
    if !robot.from_config {
        warnings.push(
            "bare URDF: no tool (the TCP is the flange) and no acceleration or jerk limits; pass a robot file from config/robots for both"
                .into(),
        );
    }
    let t = m.tool();
    let rpy = t.rotation.euler_angles();
    println!();
    println!(
        "tool    xyz [{:.4} {:.4} {:.4}] m, rpy [{:.4} {:.4} {:.4}] rad (flange → TCP; TCP z along the nozzle)",
        t.translation.x, t.translation.y, t.translation.z, rpy.0, rpy.1, rpy.2
    );
    let (mut reach, mut radius) = (0.0f64, 0.0f64);
    let mut state = ChainState::new(m.dof());
    let axis_point = m.joints()[0].origin.translation.vector;
    let axis_dir = m.joints()[0].origin.rotation * m.joints()[0].axis.into_inner();
    let mut w = [Vec::new(), Vec::new()];
    for q in samples(m, 20_000) {
        m.kinematics(&q, &mut state);
        let p = state.tcp.translation.vector;
        reach = reach.max(p.norm());
        let rel = p - axis_point;
        radius = radius.max((rel - axis_dir * rel.dot(&axis_dir)).norm());
        for (k, task) in [Task::Pose6, Task::Print5].into_iter().enumerate() {
            w[k].push(TaskJacobian::new(&state, task).svd().manipulability());
        }
    }
    println!("reach   {reach:.3} m from the base origin, {radius:.3} m from the first joint axis (max over 20,000 sampled configurations)");
    for (k, task) in [Task::Pose6, Task::Print5].into_iter().enumerate() {
        w[k].sort_by(f64::total_cmp);
        let (median, best) = (w[k][w[k].len() / 2], w[k][w[k].len() - 1]);
        println!("manipulability ({task:?}) over the same samples: median {median:.4e}, max {best:.4e}");
        if best < 1e-9 {
            warnings.push(format!("the chain is singular everywhere for the {task:?} task: it has too few joints for it"));
        }
    }
    if !m.off_chain_links().is_empty() {
        println!("links off the chain (ignored): {}", m.off_chain_links().join(", "));
    }
    println!();
    if warnings.is_empty() {
        println!("no warnings");
    } else {
        for w in &warnings {
            println!("warning: {w}");
        }
    }
}

/// A `{"q":[...]}` line as a joint vector; the error says what is wrong with it.
fn parse_q(model: &RobotModel, line: &str) -> std::result::Result<JointVector, String> {
    let v: Value = serde_json::from_str(line).map_err(|e| format!("not JSON: {e}"))?;
    let q = v.get("q").ok_or("no \"q\" field")?.as_array().ok_or("\"q\" is not an array")?;
    if q.len() != model.dof() {
        return Err(format!("\"q\" has {} values, the chain has {} joints", q.len(), model.dof()));
    }
    let mut out = JointVector::zeros();
    for (i, x) in q.iter().enumerate() {
        let x = x.as_f64().ok_or_else(|| format!("q[{i}] is not a number"))?;
        if !x.is_finite() {
            return Err(format!("q[{i}] is not finite"));
        }
        out[i] = x;
    }
    Ok(out)
}

/// FK, the Jacobian and the manipulability (with gradients) of both tasks at `q`, as JSON.
pub fn evaluate(model: &RobotModel, q: &JointVector) -> Value {
    let mut s = ChainState::new(model.dof());
    model.kinematics(q, &mut s);
    let p: Vector3<f64> = s.tcp.translation.vector;
    let quat = UnitQuaternion::from_rotation_matrix(&s.tcp.rotation);
    let jac: Vec<Vec<f64>> = (0..6).map(|r| (0..model.dof()).map(|c| s.jacobian[(r, c)]).collect()).collect();
    let mut out = json!({
        "pos": [p.x, p.y, p.z],
        "quat": [quat.w, quat.i, quat.j, quat.k],
        "jacobian": jac,
    });
    for (task, w_key, g_key) in [(Task::Pose6, "manipulability", "grad"), (Task::Print5, "manipulability_5d", "grad_5d")] {
        let tj = TaskJacobian::new(&s, task);
        let svd = tj.svd();
        let g = manipulability_gradient(&s, &tj, &svd);
        out[w_key] = json!(svd.manipulability());
        out[g_key] = json!(g.as_slice()[..model.dof()].to_vec());
    }
    if !model.within_limits(q) {
        out["warning"] = json!("q is outside the joint limits");
    }
    out
}

/// Reads `{"q":[...]}` lines from `input` and writes one JSON line per line to `output`: the
/// [`evaluate`]d values, or `{"error": "line N: ..."}` for a line that is not a joint vector of
/// this chain. Ends quietly when the reader of `output` goes away; an error when `input` fails.
pub fn eval(model: &RobotModel, input: impl BufRead, output: impl Write) -> Result<()> {
    let mut out = std::io::BufWriter::new(output);
    for (n, line) in input.lines().enumerate() {
        let line = line.map_err(ToolError::file(Path::new("<stdin>")))?;
        if line.trim().is_empty() {
            continue;
        }
        let value = match parse_q(model, &line) {
            Ok(q) => evaluate(model, &q),
            Err(e) => json!({ "error": format!("line {}: {e}", n + 1) }),
        };
        if writeln!(out, "{value}").and_then(|_| out.flush()).is_err() {
            return Ok(()); // reader went away
        }
    }
    Ok(())
}
