//! The robot as a serial chain read from URDF: joint frames, axes and limits, root → tip, plus the tool.
//!
//! Loading is the only place that allocates; the hot per-tick data (joint origins, axes, kinds) is copied
//! into fixed arrays of [`MAX_JOINTS`] so that FK, Jacobian and CLIK run on the stack.
//!
//! Folding rule: a fixed joint on the path is merged into the origin of the next movable joint, and
//! fixed joints after the last movable one become the constant `tip_offset`. The tool transform (tip link
//! → TCP at the nozzle tip) comes from config, because the URDF describes the arm, not the extruder.

use std::collections::BTreeMap;

use nalgebra::{IsometryMatrix3, SVector, Translation3, Unit, Vector3};
use thiserror::Error;

use super::geom;

/// The most joints a chain may have. Fixed capacity keeps every per-tick array on the stack.
pub const MAX_JOINTS: usize = 8;

/// Joint-space vector: entry i is joint i in chain order (rad for revolute, m for prismatic); entries at
/// and past the chain's `dof()` are zero.
pub type JointVector = SVector<f64, MAX_JOINTS>;

/// A rigid transform (rotation matrix + translation in m).
pub type Frame = IsometryMatrix3<f64>;

/// How a joint moves.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum JointKind {
    /// Rotates about its axis, with position limits.
    Revolute,
    /// Rotates about its axis without position limits.
    Continuous,
    /// Slides along its axis.
    Prismatic,
}

impl JointKind {
    /// True for revolute and continuous joints.
    pub fn rotates(self) -> bool {
        !matches!(self, JointKind::Prismatic)
    }
}

/// Limits of one joint (the shared `strand-limits` crate: the drivers' reply guard keeps the same).
pub use strand_limits::JointLimits;

/// One movable joint of the chain.
#[derive(Clone, Debug)]
pub struct Joint {
    /// Name as written in the URDF.
    pub name: String,
    /// Revolute, continuous or prismatic.
    pub kind: JointKind,
    /// Transform from the previous joint's moving frame (or the root link) to this joint's frame at
    /// q = 0, with any fixed joints in between folded in.
    pub origin: Frame,
    /// Unit axis in this joint's own frame.
    pub axis: Unit<Vector3<f64>>,
    /// Position, velocity, acceleration and jerk limits.
    pub limits: JointLimits,
}

/// Why a URDF could not be turned into a chain. Every variant names the file and the element; its
/// message (the `#[error]` line) is its documentation.
#[allow(missing_docs)]
#[derive(Debug, Error)]
pub enum ModelError {
    #[error("{file}: cannot read URDF: {reason}")]
    Read { file: String, reason: String },
    #[error("{file}: {role} link \"{link}\" is not a <link> of this robot")]
    UnknownLink { file: String, role: &'static str, link: String },
    #[error(
        "{file}: no chain of joints leads from root link \"{root}\" to tip link \"{tip}\" (walking up from the tip ended at \"{reached}\")"
    )]
    NoPath { file: String, root: String, tip: String, reached: String },
    #[error("{file}: link \"{link}\" on the chain has two parent joints, \"{first}\" and \"{second}\": the chain branches")]
    Branch { file: String, link: String, first: String, second: String },
    #[error(
        "{file}: joint \"{joint}\" has type {kind}, which a serial arm chain cannot use (revolute, continuous, prismatic or fixed only)"
    )]
    UnsupportedJoint { file: String, joint: String, kind: String },
    #[error("{file}: joint \"{joint}\" ({kind}) has no <limit> element (or its velocity is 0)")]
    MissingLimit { file: String, joint: String, kind: &'static str },
    #[error("{file}: joint \"{joint}\": <limit> {problem}")]
    BadLimit { file: String, joint: String, problem: String },
    #[error("{file}: joint \"{joint}\": <axis xyz> is not a usable direction ({axis:?})")]
    BadAxis { file: String, joint: String, axis: [f64; 3] },
    #[error("{file}: joint \"{joint}\": <origin> holds a non-finite number")]
    BadOrigin { file: String, joint: String },
    #[error("{file}: the chain \"{root}\" → \"{tip}\" has {count} movable joints; strand supports 1 to {max}")]
    JointCount { file: String, root: String, tip: String, count: usize, max: usize },
    #[error("{what}: {got} values given, the chain has {expected} joints")]
    LimitCount { what: String, expected: usize, got: usize },
    #[error("{what}: joint {index} (\"{joint}\") has {value}, which must be finite and > 0")]
    LimitValue { what: String, index: usize, joint: String, value: f64 },
    #[error("tool transform: {0}")]
    BadTool(String),
}

/// A serial chain from the root link to the tip link, with the tool (tip → TCP) attached.
#[derive(Clone, Debug)]
pub struct RobotModel {
    name: String,
    source: String,
    root_link: String,
    tip_link: String,
    joints: Vec<Joint>,
    off_chain_links: Vec<String>,
    tip_offset: Frame,
    tool: Frame,
    // Hot copies used every tick.
    n: usize,
    origins: [Frame; MAX_JOINTS],
    axes: [Vector3<f64>; MAX_JOINTS],
    kinds: [JointKind; MAX_JOINTS],
    tcp_offset: Frame,
}

fn finite3(v: &[f64; 3]) -> bool {
    v.iter().all(|x| x.is_finite())
}

fn pose_to_frame(pose: &urdf_rs::Pose) -> Option<Frame> {
    let (xyz, rpy) = (pose.xyz.0, pose.rpy.0);
    if !finite3(&xyz) || !finite3(&rpy) {
        return None;
    }
    Some(Frame::from_parts(Translation3::new(xyz[0], xyz[1], xyz[2]), geom::rpy(rpy[0], rpy[1], rpy[2])))
}

impl RobotModel {
    /// Builds the chain from URDF text; `file` is only used to name the source in errors.
    pub fn from_urdf_str(text: &str, file: &str, root_link: &str, tip_link: &str) -> Result<Self, ModelError> {
        let robot = urdf_rs::read_from_string(text).map_err(|e| match incomplete_limit(text) {
            // urdf-rs rejects a <limit> without velocity with a bare serde message; name the joint.
            Some((joint, kind)) => {
                ModelError::BadLimit { file: file.into(), joint, problem: format!("of this {kind} joint has no velocity attribute ({e})") }
            }
            None => ModelError::Read { file: file.into(), reason: e.to_string() },
        })?;
        let err_file = || file.to_string();
        for (role, link) in [("root", root_link), ("tip", tip_link)] {
            if !robot.links.iter().any(|l| l.name == link) {
                return Err(ModelError::UnknownLink { file: err_file(), role, link: link.into() });
            }
        }
        // child link → joint, refusing a link with two parents (the URDF is then not a tree).
        let mut parent_joint: BTreeMap<&str, &urdf_rs::Joint> = BTreeMap::new();
        let mut second_parent: BTreeMap<&str, (&str, &str)> = BTreeMap::new();
        for j in &robot.joints {
            if let Some(prev) = parent_joint.insert(&j.child.link, j) {
                second_parent.insert(&j.child.link, (&prev.name, &j.name));
                parent_joint.insert(&j.child.link, prev);
            }
        }
        // Walk up from the tip.
        let mut path: Vec<&urdf_rs::Joint> = Vec::new();
        let mut link = tip_link;
        while link != root_link {
            if let Some((first, second)) = second_parent.get(link) {
                return Err(ModelError::Branch { file: err_file(), link: link.into(), first: (*first).into(), second: (*second).into() });
            }
            match parent_joint.get(link) {
                Some(j) if path.len() <= robot.joints.len() => {
                    path.push(j);
                    link = &j.parent.link;
                }
                _ => {
                    return Err(ModelError::NoPath {
                        file: err_file(),
                        root: root_link.into(),
                        tip: tip_link.into(),
                        reached: link.into(),
                    });
                }
            }
        }
        path.reverse();

        let mut joints = Vec::new();
        let mut pending = Frame::identity();
        for j in path {
            let origin = pose_to_frame(&j.origin).ok_or_else(|| ModelError::BadOrigin { file: err_file(), joint: j.name.clone() })?;
            let kind = match j.joint_type {
                urdf_rs::JointType::Fixed => {
                    pending *= origin;
                    continue;
                }
                urdf_rs::JointType::Revolute => JointKind::Revolute,
                urdf_rs::JointType::Continuous => JointKind::Continuous,
                urdf_rs::JointType::Prismatic => JointKind::Prismatic,
                ref other => {
                    return Err(ModelError::UnsupportedJoint {
                        file: err_file(),
                        joint: j.name.clone(),
                        kind: format!("{other:?}").to_lowercase(),
                    });
                }
            };
            if j.mimic.is_some() {
                return Err(ModelError::UnsupportedJoint { file: err_file(), joint: j.name.clone(), kind: "mimic".into() });
            }
            let a = j.axis.xyz.0;
            let axis_vec = Vector3::new(a[0], a[1], a[2]);
            if !finite3(&a) || axis_vec.norm() < 1e-9 {
                return Err(ModelError::BadAxis { file: err_file(), joint: j.name.clone(), axis: a });
            }
            let lim = &j.limit;
            let kind_name = match kind {
                JointKind::Revolute => "revolute",
                JointKind::Continuous => "continuous",
                JointKind::Prismatic => "prismatic",
            };
            let (lower, upper) = if kind == JointKind::Continuous {
                (f64::NEG_INFINITY, f64::INFINITY)
            } else {
                if lim.velocity == 0.0 && lim.lower == 0.0 && lim.upper == 0.0 {
                    return Err(ModelError::MissingLimit { file: err_file(), joint: j.name.clone(), kind: kind_name });
                }
                if !(lim.lower.is_finite() && lim.upper.is_finite()) {
                    return Err(ModelError::BadLimit {
                        file: err_file(),
                        joint: j.name.clone(),
                        problem: format!(
                            "lower={} upper={}: a {kind_name} joint needs finite position limits (use type=\"continuous\" for an unlimited one)",
                            lim.lower, lim.upper
                        ),
                    });
                }
                if lim.lower >= lim.upper {
                    return Err(ModelError::BadLimit {
                        file: err_file(),
                        joint: j.name.clone(),
                        problem: format!("lower={} is not below upper={}", lim.lower, lim.upper),
                    });
                }
                (lim.lower, lim.upper)
            };
            if !(lim.velocity.is_finite() && lim.velocity > 0.0) {
                return Err(if kind == JointKind::Continuous && lim.velocity == 0.0 {
                    ModelError::MissingLimit { file: err_file(), joint: j.name.clone(), kind: kind_name }
                } else {
                    ModelError::BadLimit {
                        file: err_file(),
                        joint: j.name.clone(),
                        problem: format!("velocity={} must be finite and > 0", lim.velocity),
                    }
                });
            }
            for (what, v) in [("acceleration", lim.acceleration), ("jerk", lim.jerk)] {
                // URDF 1.2 may carry these; infinity means "not given" (config sets them later).
                if v.is_nan() || v <= 0.0 {
                    return Err(ModelError::BadLimit {
                        file: err_file(),
                        joint: j.name.clone(),
                        problem: format!("{what}={v} must be > 0"),
                    });
                }
            }
            joints.push(Joint {
                name: j.name.clone(),
                kind,
                origin: pending * origin,
                axis: Unit::new_normalize(axis_vec),
                limits: JointLimits { lower, upper, velocity: lim.velocity, acceleration: lim.acceleration, jerk: lim.jerk },
            });
            pending = Frame::identity();
        }
        if joints.is_empty() || joints.len() > MAX_JOINTS {
            return Err(ModelError::JointCount {
                file: err_file(),
                root: root_link.into(),
                tip: tip_link.into(),
                count: joints.len(),
                max: MAX_JOINTS,
            });
        }
        let mut chain_links: Vec<&str> = vec![root_link];
        let mut l = tip_link;
        while l != root_link {
            chain_links.push(l);
            l = &parent_joint[l].parent.link;
        }
        let off_chain_links = robot.links.iter().filter(|l| !chain_links.contains(&l.name.as_str())).map(|l| l.name.clone()).collect();
        let mut model = RobotModel {
            name: robot.name.clone(),
            source: file.to_string(),
            root_link: root_link.into(),
            tip_link: tip_link.into(),
            joints,
            off_chain_links,
            tip_offset: pending,
            tool: Frame::identity(),
            n: 0,
            origins: [Frame::identity(); MAX_JOINTS],
            axes: [Vector3::zeros(); MAX_JOINTS],
            kinds: [JointKind::Revolute; MAX_JOINTS],
            tcp_offset: Frame::identity(),
        };
        model.refresh();
        Ok(model)
    }

    /// Attaches the tool: the transform from the tip link to the TCP (the nozzle tip, z along the nozzle
    /// pointing at the substrate).
    pub fn with_tool(mut self, tool: Frame) -> Result<Self, ModelError> {
        let ok = tool.translation.vector.iter().all(|x| x.is_finite()) && tool.rotation.matrix().iter().all(|x| x.is_finite());
        if !ok {
            return Err(ModelError::BadTool("non-finite value".into()));
        }
        self.tool = tool;
        self.refresh();
        Ok(self)
    }

    /// Sets acceleration (rad/s², m/s²) and jerk (rad/s³, m/s³) limits, one per joint in chain order.
    /// `what` names the config keys in errors.
    pub fn with_dynamic_limits(mut self, acceleration: &[f64], jerk: &[f64], what: (&str, &str)) -> Result<Self, ModelError> {
        for (values, name) in [(acceleration, what.0), (jerk, what.1)] {
            if values.len() != self.joints.len() {
                return Err(ModelError::LimitCount { what: name.into(), expected: self.joints.len(), got: values.len() });
            }
            if let Some((i, v)) = values.iter().enumerate().find(|(_, v)| !(v.is_finite() && **v > 0.0)) {
                return Err(ModelError::LimitValue { what: name.into(), index: i, joint: self.joints[i].name.clone(), value: *v });
            }
        }
        for (j, (a, r)) in self.joints.iter_mut().zip(acceleration.iter().zip(jerk)) {
            j.limits.acceleration = *a;
            j.limits.jerk = *r;
        }
        Ok(self)
    }

    fn refresh(&mut self) {
        self.n = self.joints.len();
        for (i, j) in self.joints.iter().enumerate() {
            self.origins[i] = j.origin;
            self.axes[i] = j.axis.into_inner();
            self.kinds[i] = j.kind;
        }
        self.tcp_offset = self.tip_offset * self.tool;
    }

    /// Number of movable joints.
    #[inline]
    pub fn dof(&self) -> usize {
        self.n
    }
    /// The `<robot name>` of the URDF.
    pub fn name(&self) -> &str {
        &self.name
    }
    /// Where the model came from (a file path), for messages.
    pub fn source(&self) -> &str {
        &self.source
    }
    /// Root link: the base frame B in which FK and the Jacobian are expressed.
    pub fn root_link(&self) -> &str {
        &self.root_link
    }
    /// Tip link (the flange); the tool hangs off it.
    pub fn tip_link(&self) -> &str {
        &self.tip_link
    }
    /// The movable joints in chain order.
    pub fn joints(&self) -> &[Joint] {
        &self.joints
    }
    /// Links of the URDF that are not on the root → tip chain (informational: sensors, leaf frames).
    pub fn off_chain_links(&self) -> &[String] {
        &self.off_chain_links
    }
    /// Fixed transform from the last movable joint's frame to the tip link.
    pub fn tip_offset(&self) -> &Frame {
        &self.tip_offset
    }
    /// Tool transform, tip link → TCP.
    pub fn tool(&self) -> &Frame {
        &self.tool
    }
    /// Limits of joint `i`.
    #[inline]
    pub fn limits(&self, i: usize) -> &JointLimits {
        &self.joints[i].limits
    }

    #[inline]
    pub(crate) fn hot(&self) -> (&[Frame], &[Vector3<f64>], &[JointKind], &Frame) {
        (&self.origins[..self.n], &self.axes[..self.n], &self.kinds[..self.n], &self.tcp_offset)
    }

    /// True if every joint of `q` lies within its position limits (inclusive).
    pub fn within_limits(&self, q: &JointVector) -> bool {
        self.joints.iter().enumerate().all(|(i, j)| q[i] >= j.limits.lower && q[i] <= j.limits.upper)
    }

    /// The midpoint of every joint's range (0 for continuous joints).
    pub fn middle_configuration(&self) -> JointVector {
        let mut q = JointVector::zeros();
        for (i, j) in self.joints.iter().enumerate() {
            q[i] = j.limits.middle();
        }
        q
    }
}

/// The first movable joint whose `<limit>` element lacks the `velocity` attribute, with its type, found
/// by a plain scan of the text (used only to explain a parse error).
fn incomplete_limit(text: &str) -> Option<(String, String)> {
    let attr = |tag: &str, name: &str| -> Option<String> {
        let at = tag.find(&format!("{name}="))? + name.len() + 1;
        let quote = tag[at..].chars().next().filter(|c| *c == '"' || *c == '\'')?;
        let rest = &tag[at + 1..];
        Some(rest[..rest.find(quote)?].to_string())
    };
    let mut rest = text;
    while let Some(start) = rest.find("<joint") {
        let after = &rest[start..];
        let head_end = after.find('>')?;
        let head = &after[..head_end];
        let body_end = if head.ends_with('/') { head_end } else { after.find("</joint>").unwrap_or(after.len()) };
        let body = &after[..body_end];
        let kind = attr(head, "type").unwrap_or_default();
        if matches!(kind.as_str(), "revolute" | "prismatic" | "continuous")
            && let Some(l) = body.find("<limit")
        {
            let tag = &body[l..l + body[l..].find('>').unwrap_or(body.len() - l)];
            if !tag.contains("velocity=") {
                return Some((attr(head, "name").unwrap_or_else(|| "?".into()), kind));
            }
        }
        rest = &after[body_end.max(1)..];
    }
    None
}
