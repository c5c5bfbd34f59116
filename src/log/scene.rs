//! The scene: what a 3D viewer needs beside the tick's own channels, encoded as the standard ROS 2
//! messages Foxglove draws — the URDF once (`/robot_description`), every link's transform as
//! `robot_state_publisher` would publish it (`/tf`), the joints against their limits
//! (`/joints/normalized`), and three marker channels: the queued path ahead of the tool
//! (`/path/ahead`), the path the tool has followed (`/path/executed`) and the bead it has laid
//! (`/bead`, coloured by the TCP error), and the bed's measured surface (`/bed/mesh`, `[bed.mesh]`
//! as a grid of lines coloured from its lowest to its highest point, once per file and latched).
//! The log writer thread runs it, decimated
//! (`[view] tf_rate_hz`, `marker_rate_hz`), and its messages go to the MCAP and to the live view
//! alike, so a log opened afterwards draws the same scene.
//!
//! The executed path and the bead are sent as chunks of a line strip: each chunk is one marker
//! (its `id` counts up) that grows until it holds [`CHUNK_POINTS`] points, and a viewer keeps every
//! chunk (no lifetime), so each message carries only the newest chunk and the scene costs the same
//! bytes at the end of a print as at its start.

use std::collections::VecDeque;

use nalgebra::{Isometry3, Translation3, UnitQuaternion, Vector3};
use strand_ipc as ipc;

use super::cdr::CdrWriter;
use super::messages::Tick;
use crate::config::view::ViewConfig;
use strand_core::kin::{JointVector, RobotModel, geom};

/// Points a trail chunk holds before the next one starts.
pub(crate) const CHUNK_POINTS: usize = 100;
/// Shortest spacing of trail points (m): the trail follows corners without a point per tick.
const TRAIL_SPACING: f64 = 0.0005;
/// Line widths (m).
const BEAD_WIDTH: f64 = 0.0008;
const PATH_WIDTH: f64 = 0.0003;

/// Where a scene message goes: the trails send the file each chunk once, when it is finished, and
/// the live view the growing chunk at every marker tick.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum SceneSink {
    /// The file and the live view.
    Both,
    /// The file only.
    File,
    /// The live view only.
    Live,
}

/// The scene's channels, in the order [`SceneTopic::ALL`] lists them.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum SceneTopic {
    /// `std_msgs/msg/String`: the URDF.
    RobotDescription,
    /// `tf2_msgs/msg/TFMessage`.
    Tf,
    /// `sensor_msgs/msg/JointState`: positions mapped to [−1, 1] across the limits.
    JointsNormalized,
    /// `visualization_msgs/msg/MarkerArray`: the queued path.
    PathAhead,
    /// `visualization_msgs/msg/MarkerArray`: the TCP's trail.
    PathExecuted,
    /// `visualization_msgs/msg/MarkerArray`: the bead.
    Bead,
    /// `visualization_msgs/msg/MarkerArray`: the bed mesh (only with `[bed.mesh]`).
    BedMesh,
}

impl SceneTopic {
    /// Every scene channel.
    pub(crate) const ALL: [SceneTopic; 7] = [
        SceneTopic::RobotDescription,
        SceneTopic::Tf,
        SceneTopic::JointsNormalized,
        SceneTopic::PathAhead,
        SceneTopic::PathExecuted,
        SceneTopic::Bead,
        SceneTopic::BedMesh,
    ];

    /// Its topic.
    pub(crate) fn topic(self) -> &'static str {
        match self {
            SceneTopic::RobotDescription => "/robot_description",
            SceneTopic::Tf => "/tf",
            SceneTopic::JointsNormalized => "/joints/normalized",
            SceneTopic::PathAhead => "/path/ahead",
            SceneTopic::PathExecuted => "/path/executed",
            SceneTopic::Bead => "/bead",
            SceneTopic::BedMesh => "/bed/mesh",
        }
    }

    /// Its schema name and text.
    pub(crate) fn schema(self) -> (&'static str, String) {
        match self {
            SceneTopic::RobotDescription => ("std_msgs/msg/String", "string data\n".to_string()),
            SceneTopic::Tf => ("tf2_msgs/msg/TFMessage", tf_schema()),
            SceneTopic::JointsNormalized => (super::messages::ros::JOINT_STATE, super::messages::ros::joint_state_schema()),
            _ => ("visualization_msgs/msg/MarkerArray", marker_array_schema()),
        }
    }

    /// Its index in [`SceneTopic::ALL`].
    pub(crate) fn index(self) -> usize {
        self as usize
    }
}

const SEPARATOR: &str = "================================================================================";

fn msg(name: &str, body: &str) -> String {
    format!("{SEPARATOR}\nMSG: {name}\n{body}")
}

fn header_and_geometry() -> String {
    [
        msg("std_msgs/Header", "builtin_interfaces/Time stamp\nstring frame_id\n"),
        msg("builtin_interfaces/Time", "int32 sec\nuint32 nanosec\n"),
        msg("geometry_msgs/Vector3", "float64 x\nfloat64 y\nfloat64 z\n"),
        msg("geometry_msgs/Quaternion", "float64 x\nfloat64 y\nfloat64 z\nfloat64 w\n"),
    ]
    .concat()
}

/// `tf2_msgs/msg/TFMessage`, as in ROS 2 Humble.
fn tf_schema() -> String {
    format!(
        "geometry_msgs/TransformStamped[] transforms\n{}{}{}",
        msg("geometry_msgs/TransformStamped", "std_msgs/Header header\nstring child_frame_id\ngeometry_msgs/Transform transform\n"),
        msg("geometry_msgs/Transform", "geometry_msgs/Vector3 translation\ngeometry_msgs/Quaternion rotation\n"),
        header_and_geometry()
    )
}

/// `visualization_msgs/msg/MarkerArray`, as in ROS 2 Humble (constants included: readers such as
/// rosbags compare the definition with their own).
fn marker_array_schema() -> String {
    format!(
        "visualization_msgs/Marker[] markers\n{}{}{}{}{}{}{}{}{}{}",
        msg(
            "visualization_msgs/Marker",
            "int32 ARROW=0\nint32 CUBE=1\nint32 SPHERE=2\nint32 CYLINDER=3\nint32 LINE_STRIP=4\nint32 LINE_LIST=5\n\
             int32 CUBE_LIST=6\nint32 SPHERE_LIST=7\nint32 POINTS=8\nint32 TEXT_VIEW_FACING=9\nint32 MESH_RESOURCE=10\n\
             int32 TRIANGLE_LIST=11\nint32 ADD=0\nint32 MODIFY=0\nint32 DELETE=2\nint32 DELETEALL=3\n\
             std_msgs/Header header\nstring ns\nint32 id\nint32 type\nint32 action\ngeometry_msgs/Pose pose\n\
             geometry_msgs/Vector3 scale\nstd_msgs/ColorRGBA color\nbuiltin_interfaces/Duration lifetime\nbool frame_locked\n\
             geometry_msgs/Point[] points\nstd_msgs/ColorRGBA[] colors\nstring texture_resource\n\
             sensor_msgs/CompressedImage texture\nvisualization_msgs/UVCoordinate[] uv_coordinates\nstring text\n\
             string mesh_resource\nvisualization_msgs/MeshFile mesh_file\nbool mesh_use_embedded_materials\n"
        ),
        msg("geometry_msgs/Pose", "geometry_msgs/Point position\ngeometry_msgs/Quaternion orientation\n"),
        msg("geometry_msgs/Point", "float64 x\nfloat64 y\nfloat64 z\n"),
        msg("std_msgs/ColorRGBA", "float32 r\nfloat32 g\nfloat32 b\nfloat32 a\n"),
        msg("builtin_interfaces/Duration", "int32 sec\nuint32 nanosec\n"),
        msg("sensor_msgs/CompressedImage", "std_msgs/Header header\nstring format\nuint8[] data\n"),
        msg("visualization_msgs/UVCoordinate", "float32 u\nfloat32 v\n"),
        msg("visualization_msgs/MeshFile", "string filename\nuint8[] data\n"),
        header_and_geometry(),
        ""
    )
}

/// One URDF joint, for `/tf`.
struct TfJoint {
    parent: String,
    child: String,
    origin: Isometry3<f64>,
    axis: Vector3<f64>,
    motion: JointMotion,
    /// Its index in the chain (`None`: off the chain, drawn at 0).
    chain: Option<usize>,
}

/// How a URDF joint moves its child.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum JointMotion {
    Rotates,
    Slides,
    Fixed,
}

/// A colour (r, g, b, a in 0..1).
type Rgba = [f32; 4];

const EXTRUDE_COLOUR: Rgba = [0.15, 0.45, 1.0, 0.9];
const TRAVEL_COLOUR: Rgba = [0.6, 0.6, 0.6, 0.5];
const TRAIL_COLOUR: Rgba = [1.0, 0.6, 0.1, 0.8];

/// One chunk of a trail: marker id, points (m, W), colours.
type Chunk = (i32, Vec<[f64; 3]>, Vec<Rgba>);

/// A line strip that grows in chunks (see the module documentation).
#[derive(Default)]
struct Trail {
    id: i32,
    points: Vec<[f64; 3]>,
    colours: Vec<Rgba>,
    /// Points added since it was last sent.
    fresh: bool,
    /// The next point starts a new chunk (the bead stopped).
    broken: bool,
    /// Chunks that filled up or broke off since the last message while holding points not yet
    /// sent: sent once more, whole, with the next message (else their last points would never be
    /// drawn).
    finished: Vec<Chunk>,
    /// Chunks finished since the file last got this trail: the file takes each chunk once, whole,
    /// when it is finished (the live view gets the growing chunk at every marker tick).
    file_pending: Vec<Chunk>,
    /// Finished chunks (id, points, colours), oldest first, for viewers that connect later.
    history: VecDeque<Chunk>,
    /// Points in `history`, and the most it keeps (the oldest chunks go first).
    history_points: usize,
    history_cap: usize,
}

impl Trail {
    fn new(history_cap: usize) -> Trail {
        Trail { history_cap, ..Trail::default() }
    }

    fn add(&mut self, p: [f64; 3], colour: Rgba) {
        if self.broken || self.points.len() >= CHUNK_POINTS {
            // A full chunk starts the next at its last point, so the line stays continuous; a
            // broken one starts afresh.
            let last = if self.broken { None } else { self.points.last().copied().zip(self.colours.last().copied()) };
            if !self.points.is_empty() {
                if self.points.len() >= 2 && self.fresh {
                    self.finished.push((self.id, self.points.clone(), self.colours.clone()));
                    self.fresh = false;
                }
                if self.points.len() >= 2 {
                    self.file_pending.push((self.id, self.points.clone(), self.colours.clone()));
                }
                if self.points.len() >= 2 && self.history_cap > 0 {
                    self.history_points += self.points.len();
                    self.history.push_back((self.id, self.points.clone(), self.colours.clone()));
                    while self.history_points > self.history_cap {
                        let Some((_, dropped, _)) = self.history.pop_front() else { break };
                        self.history_points -= dropped.len();
                    }
                }
                self.id += 1;
            }
            self.points.clear();
            self.colours.clear();
            if let Some((q, c)) = last {
                self.points.push(q);
                self.colours.push(c);
            }
            self.broken = false;
        }
        let far = self.points.last().is_none_or(|q| dist(q, &p) >= TRAIL_SPACING);
        if far {
            self.points.push(p);
            self.colours.push(colour);
            self.fresh = true;
        }
    }
}

fn dist(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

/// The URDF a viewer draws: `urdf` with a stick figure added to every link that has no visual of
/// its own — a cylinder from the link's origin to each child joint and a sphere at the joint —
/// so a kinematics-only URDF (strand's robots carry no meshes) still shows the arm, not just its
/// frames. Kinematics are untouched (joints, origins, limits); an URDF that does not parse is
/// returned as it is.
pub(crate) fn with_stick_visuals(urdf: &str) -> String {
    let Ok(mut robot) = urdf_rs::read_from_string(urdf) else { return urdf.to_string() };
    let offsets: Vec<(String, Vector3<f64>)> =
        robot.joints.iter().map(|j| (j.parent.link.clone(), Vector3::from(j.origin.xyz.0))).collect();
    let longest = offsets.iter().map(|(_, t)| t.norm()).fold(0.0, f64::max);
    let radius = (0.12 * longest).clamp(0.008, 0.04);
    let material = || urdf_rs::Material {
        name: "strand_stick".to_string(),
        color: Some(urdf_rs::Color { rgba: urdf_rs::Vec4([0.85, 0.55, 0.1, 1.0]) }),
        texture: None,
    };
    for link in robot.links.iter_mut().filter(|l| l.visual.is_empty()) {
        for (_, t) in offsets.iter().filter(|(parent, _)| *parent == link.name) {
            let length = t.norm();
            if length < 1e-4 {
                continue;
            }
            let rot = UnitQuaternion::rotation_between(&Vector3::z(), t)
                .unwrap_or_else(|| UnitQuaternion::from_scaled_axis(Vector3::x() * std::f64::consts::PI));
            let (roll, pitch, yaw) = rot.euler_angles();
            let mid = t * 0.5;
            link.visual.push(urdf_rs::Visual {
                name: None,
                origin: urdf_rs::Pose { xyz: urdf_rs::Vec3([mid.x, mid.y, mid.z]), rpy: urdf_rs::Vec3([roll, pitch, yaw]) },
                geometry: urdf_rs::Geometry::Cylinder { radius, length },
                material: Some(material()),
            });
            link.visual.push(urdf_rs::Visual {
                name: None,
                origin: urdf_rs::Pose { xyz: urdf_rs::Vec3([t.x, t.y, t.z]), rpy: urdf_rs::Vec3([0.0; 3]) },
                geometry: urdf_rs::Geometry::Sphere { radius: 1.3 * radius },
                material: Some(material()),
            });
        }
    }
    urdf_rs::write_to_string(&robot).unwrap_or_else(|_| urdf.to_string())
}

/// Builds the scene's messages from the ticks (see the module documentation).
pub(crate) struct Scene {
    joints: Vec<TfJoint>,
    model: RobotModel,
    names: Vec<String>,
    urdf: String,
    cfg: ViewConfig,
    next_tf_ns: u64,
    next_marker_ns: u64,
    /// Segments received and not yet passed: (seq, kind, flags, end, centre, normal, sweep).
    ahead: VecDeque<ipc::Segment>,
    /// The end of the last segment already executed (the start of the first one ahead).
    ahead_start: Option<[f64; 3]>,
    executed: Trail,
    bead: Trail,
    /// The bed mesh's grid lines (W) and their colours, if the config has a mesh.
    bed_mesh: Vec<(Vec<[f64; 3]>, Vec<Rgba>)>,
    /// The file takes the trails a finished chunk at a time ([`SceneSink::File`]); else it gets
    /// what the live view gets.
    file_chunks: bool,
    cdr: CdrWriter,
}

impl Scene {
    /// From the robot's URDF text and chain. An URDF that does not parse leaves `/tf` empty (the
    /// model was built from the same text, so it does).
    pub(crate) fn new(urdf: &str, model: &RobotModel, cfg: &ViewConfig, bed_mesh: Option<&strand_core::BedMesh>) -> Scene {
        let chain: Vec<&str> = model.joints().iter().map(|j| j.name.as_str()).collect();
        let joints = urdf_rs::read_from_string(urdf)
            .map(|robot| {
                robot
                    .joints
                    .iter()
                    .map(|j| {
                        let (xyz, rpy) = (j.origin.xyz.0, j.origin.rpy.0);
                        let rot = UnitQuaternion::from_rotation_matrix(&geom::rpy(rpy[0], rpy[1], rpy[2]));
                        let axis = Vector3::from(j.axis.xyz.0);
                        let motion = match j.joint_type {
                            urdf_rs::JointType::Revolute | urdf_rs::JointType::Continuous => JointMotion::Rotates,
                            urdf_rs::JointType::Prismatic => JointMotion::Slides,
                            _ => JointMotion::Fixed,
                        };
                        TfJoint {
                            parent: j.parent.link.clone(),
                            child: j.child.link.clone(),
                            origin: Isometry3::from_parts(Translation3::new(xyz[0], xyz[1], xyz[2]), rot),
                            axis: if axis.norm() > 0.0 { axis.normalize() } else { Vector3::z() },
                            motion,
                            chain: chain.iter().position(|n| *n == j.name),
                        }
                    })
                    .collect()
            })
            .unwrap_or_default();
        Scene {
            joints,
            model: model.clone(),
            names: chain.iter().map(|s| s.to_string()).collect(),
            urdf: with_stick_visuals(urdf),
            cfg: cfg.clone(),
            next_tf_ns: 0,
            next_marker_ns: 0,
            ahead: VecDeque::new(),
            ahead_start: None,
            executed: Trail::new(cfg.history_points),
            bead: Trail::new(cfg.history_points),
            bed_mesh: bed_mesh.map(mesh_lines).unwrap_or_default(),
            file_chunks: false,
            cdr: CdrWriter::new(),
        }
    }

    /// Whether the file takes the trails a finished chunk at a time (the service's thinned log)
    /// or as the live view gets them (a log with every channel at every tick).
    pub(crate) fn set_file_chunks(&mut self, on: bool) {
        self.file_chunks = on;
    }

    /// `/bed/mesh`: the bed's measured surface as grid lines (sent once per file, and to each live
    /// client that subscribes), or `None` without a mesh.
    pub(crate) fn bed_mesh(&mut self, stamp_ns: u64) -> Option<&[u8]> {
        if self.bed_mesh.is_empty() {
            return None;
        }
        let lines = self.bed_mesh.iter().enumerate().map(|(k, (p, c))| (k as i32, p, c));
        encode_strips(&mut self.cdr, stamp_ns, "bed_mesh", PATH_WIDTH, lines);
        Some(self.cdr.bytes())
    }

    /// `/robot_description`: the URDF (sent once per file, and to each live client that subscribes).
    pub(crate) fn robot_description(&mut self) -> &[u8] {
        self.cdr.begin();
        self.cdr.string(&self.urdf);
        self.cdr.bytes()
    }

    /// Takes one tick (log time `stamp_ns`, Unix ns; `measured`: the last measured joints, when
    /// known) and emits the messages that are due.
    pub(crate) fn tick<E>(
        &mut self,
        t: &Tick,
        stamp_ns: u64,
        measured: Option<&JointVector>,
        emit: &mut impl FnMut(SceneTopic, SceneSink, &[u8]) -> Result<(), E>,
    ) -> Result<(), E> {
        for s in t.input.segments() {
            if self.ahead.len() >= self.cfg.path_ahead_segments.max(1) * 4 {
                self.ahead.pop_front();
            }
            self.ahead.push_back(*s);
        }
        let status = &t.output.status;
        while self.ahead.front().is_some_and(|s| s.seq < status.executing_seq) {
            self.ahead_start = self.ahead.pop_front().map(|s| s.end);
        }
        let dof = self.model.dof();
        let q = measured.copied().or_else(|| {
            let c = &t.output.joint_command;
            (c.valid == 1).then(|| {
                let mut q = JointVector::zeros();
                q.as_mut_slice()[..dof].copy_from_slice(&c.position[..dof]);
                q
            })
        });
        let base = &t.output.diagnostics.base;
        // The trail and the bead take a point every tick the tool has moved far enough.
        if let Some(q) = &q {
            let tcp = self.model.forward_kinematics(q);
            let (p, _) = base.base_to_world(&tcp.translation.vector, &UnitQuaternion::identity());
            let p = [p.x, p.y, p.z];
            if p.iter().all(|v| v.is_finite()) {
                self.executed.add(p, TRAIL_COLOUR);
                if t.output.extruder.flags & ipc::extruder_flags::EXTRUDING != 0 && status.run_state == ipc::RunState::Running as u32 {
                    self.bead.add(p, error_colour(status.tcp_error / self.cfg.bead_error_scale));
                } else {
                    self.bead.broken = true;
                }
            }
        }
        if stamp_ns >= self.next_tf_ns {
            self.next_tf_ns = stamp_ns + (1e9 / self.cfg.tf_rate_hz) as u64;
            if let Some(q) = &q {
                self.encode_tf(stamp_ns, q, base);
                emit(SceneTopic::Tf, SceneSink::Both, self.cdr.bytes())?;
                self.encode_normalized(stamp_ns, q);
                emit(SceneTopic::JointsNormalized, SceneSink::Both, self.cdr.bytes())?;
            }
        }
        if stamp_ns >= self.next_marker_ns {
            self.next_marker_ns = stamp_ns + (1e9 / self.cfg.marker_rate_hz) as u64;
            let target = t.output.diagnostics.tcp_target_world;
            self.encode_ahead(stamp_ns, [target.x, target.y, target.z]);
            emit(SceneTopic::PathAhead, SceneSink::Both, self.cdr.bytes())?;
            for topic in [SceneTopic::PathExecuted, SceneTopic::Bead] {
                let (trail, ns, width) = match topic {
                    SceneTopic::Bead => (&mut self.bead, "bead", BEAD_WIDTH),
                    _ => (&mut self.executed, "executed", PATH_WIDTH),
                };
                let live_sink = if self.file_chunks { SceneSink::Live } else { SceneSink::Both };
                if !self.file_chunks {
                    trail.file_pending.clear();
                } else if !trail.file_pending.is_empty() {
                    encode_strips(&mut self.cdr, stamp_ns, ns, width, trail.file_pending.iter().map(|(i, p, c)| (*i, p, c)));
                    trail.file_pending.clear();
                    emit(topic, SceneSink::File, self.cdr.bytes())?;
                }
                let finished = std::mem::take(&mut trail.finished);
                let current = (trail.fresh && trail.points.len() >= 2).then_some((trail.id, &trail.points, &trail.colours));
                if finished.is_empty() && current.is_none() {
                    continue;
                }
                let chunks = finished.iter().map(|(i, p, c)| (*i, p, c)).chain(current);
                encode_strips(&mut self.cdr, stamp_ns, ns, width, chunks);
                trail.fresh = false;
                emit(topic, live_sink, self.cdr.bytes())?;
            }
        }
        Ok(())
    }

    /// The trails' chunks the file has not had (finished ones, and the current one however short)
    /// as one message per trail, for the end of a file: `emit` gets them for the file only.
    pub(crate) fn flush_trails<E>(&mut self, stamp_ns: u64, emit: &mut impl FnMut(SceneTopic, &[u8]) -> Result<(), E>) -> Result<(), E> {
        if !self.file_chunks {
            return Ok(());
        }
        for topic in [SceneTopic::PathExecuted, SceneTopic::Bead] {
            let (trail, ns, width) = match topic {
                SceneTopic::Bead => (&mut self.bead, "bead", BEAD_WIDTH),
                _ => (&mut self.executed, "executed", PATH_WIDTH),
            };
            let current = (trail.points.len() >= 2).then_some((trail.id, &trail.points, &trail.colours));
            if trail.file_pending.is_empty() && current.is_none() {
                continue;
            }
            let chunks = trail.file_pending.iter().map(|(i, p, c)| (*i, p, c)).chain(current);
            encode_strips(&mut self.cdr, stamp_ns, ns, width, chunks);
            trail.file_pending.clear();
            emit(topic, self.cdr.bytes())?;
        }
        Ok(())
    }

    /// The whole trail of `topic` (`/path/executed` or `/bead`) as one MarkerArray — every kept
    /// chunk with its own id, then the current one — for a viewer that subscribed late; `None`
    /// while there is none.
    pub(crate) fn history(&self, topic: SceneTopic, stamp_ns: u64) -> Option<Vec<u8>> {
        let (trail, ns, width) = match topic {
            SceneTopic::Bead => (&self.bead, "bead", BEAD_WIDTH),
            _ => (&self.executed, "executed", PATH_WIDTH),
        };
        let current = (trail.points.len() >= 2).then_some((trail.id, &trail.points, &trail.colours));
        if trail.history.is_empty() && current.is_none() {
            return None;
        }
        let chunks = trail.history.iter().map(|(i, p, c)| (*i, p, c)).chain(current);
        // Its own buffer (up to tens of MB), freed when sent, not kept by the per-tick encoder.
        let mut w = CdrWriter::new();
        encode_strips(&mut w, stamp_ns, ns, width, chunks);
        Some(w.into_bytes())
    }

    fn encode_tf(&mut self, stamp_ns: u64, q: &JointVector, base: &strand_core::BaseState) {
        let w = &mut self.cdr;
        w.begin();
        let root = self.model.root_link().to_string();
        let base = Isometry3::from_parts(Translation3::from(base.position), base.orientation);
        // A URDF whose root link is called `world` (the iiwa's) is the base frame under W's name:
        // the base pose then goes onto the root's own joints instead of a world → world loop.
        let root_is_world = root == "world";
        w.len(self.joints.len() + 1 + usize::from(!root_is_world));
        if !root_is_world {
            transform(w, stamp_ns, "world", &root, &base);
        }
        for j in &self.joints {
            let v = j.chain.map_or(0.0, |i| q[i]);
            let motion = match j.motion {
                JointMotion::Rotates => Isometry3::from_parts(Translation3::identity(), UnitQuaternion::from_scaled_axis(j.axis * v)),
                JointMotion::Slides => Isometry3::from_parts(Translation3::from(j.axis * v), UnitQuaternion::identity()),
                JointMotion::Fixed => Isometry3::identity(),
            };
            let x = j.origin * motion;
            transform(w, stamp_ns, &j.parent, &j.child, &if root_is_world && j.parent == root { base * x } else { x });
        }
        let tcp = self.model.forward_kinematics(q);
        let tcp = Isometry3::from_parts(Translation3::from(tcp.translation.vector), UnitQuaternion::from_rotation_matrix(&tcp.rotation));
        transform(w, stamp_ns, &root, "tcp", &if root_is_world { base * tcp } else { tcp });
    }

    fn encode_normalized(&mut self, stamp_ns: u64, q: &JointVector) {
        let n = self.model.dof();
        let mut x = [0.0; strand_core::kin::MAX_JOINTS];
        for (i, x) in x.iter_mut().enumerate().take(n) {
            let l = self.model.limits(i);
            let half = 0.5 * (l.upper - l.lower);
            *x = if half > 0.0 { (q[i] - l.middle()) / half } else { 0.0 };
        }
        super::messages::ros::joint_state(&mut self.cdr, stamp_ns, &self.names, &x[..n], &[], &[]);
    }

    fn encode_ahead(&mut self, stamp_ns: u64, from: [f64; 3]) {
        let mut points = Vec::with_capacity(2 * self.cfg.path_ahead_segments);
        let mut colours = Vec::with_capacity(points.capacity());
        let mut start = from;
        for s in self.ahead.iter().filter(|s| s.seq >= 1).take(self.cfg.path_ahead_segments) {
            let colour = if s.flags & ipc::segment_flags::EXTRUDE != 0 && s.filament > 0.0 { EXTRUDE_COLOUR } else { TRAVEL_COLOUR };
            let mut line = |a: [f64; 3], b: [f64; 3]| {
                points.extend([a, b]);
                colours.extend([colour, colour]);
            };
            if s.kind == ipc::SegmentKind::Arc as u32 && s.sweep.is_finite() {
                // Eight chords per arc: the start turned about the normal through the centre.
                let (c, n) = (Vector3::from(s.centre), Vector3::from(s.normal));
                let r0 = Vector3::from(start) - c;
                let mut a = start;
                for k in 1..=8 {
                    let rot = UnitQuaternion::from_scaled_axis(n.normalize() * (s.sweep * k as f64 / 8.0));
                    let p = c + rot * r0;
                    let b = if k == 8 { s.end } else { [p.x, p.y, p.z] };
                    line(a, b);
                    a = b;
                }
            } else if s.kind != ipc::SegmentKind::Dwell as u32 {
                line(start, s.end);
            }
            if s.kind != ipc::SegmentKind::Dwell as u32 {
                start = s.end;
            }
        }
        let w = &mut self.cdr;
        w.begin();
        w.len(1);
        // LINE_LIST (5): a pair of points per chord, each segment in its own colour.
        marker(w, stamp_ns, "ahead", 0, 5, PATH_WIDTH, &points, &colours);
    }
}

/// The mesh's grid lines in W: one along x per probed row, one along y per probed column, four
/// points a cell, coloured from blue (the lowest height) to red (the highest).
fn mesh_lines(mesh: &strand_core::BedMesh) -> Vec<(Vec<[f64; 3]>, Vec<Rgba>)> {
    let c = mesh.config();
    let (nx, ny) = c.counts();
    let (lo, hi) = c.range();
    let colour = |z: f64| -> Rgba {
        let t = if hi > lo { ((z - lo) / (hi - lo)) as f32 } else { 0.5 };
        [t, 0.2, 1.0 - t, 1.0]
    };
    let at = |a: f64, b: f64| [c.min[0] + a * (c.max[0] - c.min[0]), c.min[1] + b * (c.max[1] - c.min[1])];
    let line = |along_x: bool, k: usize| {
        let (n, across) = if along_x { (nx, k as f64 / (ny - 1) as f64) } else { (ny, k as f64 / (nx - 1) as f64) };
        let samples = 4 * (n - 1);
        let mut points = Vec::with_capacity(samples + 1);
        let mut colours = Vec::with_capacity(samples + 1);
        for i in 0..=samples {
            let u = i as f64 / samples as f64;
            let [x, y] = if along_x { at(u, across) } else { at(across, u) };
            let p = mesh.surface_point(x, y);
            points.push([p.x, p.y, p.z]);
            colours.push(colour(mesh.height(x, y)));
        }
        (points, colours)
    };
    (0..ny).map(|j| line(true, j)).chain((0..nx).map(|i| line(false, i))).collect()
}

/// Green (0) through yellow to red (1 and above).
fn error_colour(x: f64) -> Rgba {
    let x = if x.is_finite() { x.clamp(0.0, 1.0) as f32 } else { 1.0 };
    [(2.0 * x).min(1.0), (2.0 * (1.0 - x)).min(1.0), 0.1, 1.0]
}

fn header(w: &mut CdrWriter, stamp_ns: u64, frame: &str) {
    w.i32((stamp_ns / 1_000_000_000) as i32);
    w.u32((stamp_ns % 1_000_000_000) as u32);
    w.string(frame);
}

fn transform(w: &mut CdrWriter, stamp_ns: u64, parent: &str, child: &str, x: &Isometry3<f64>) {
    header(w, stamp_ns, parent);
    w.string(child);
    for v in x.translation.vector.iter() {
        w.f64(*v);
    }
    let r = x.rotation;
    for v in [r.i, r.j, r.k, r.w] {
        w.f64(v);
    }
}

/// A MarkerArray of line strips (LINE_STRIP, 4), one per chunk.
fn encode_strips<'a>(
    w: &mut CdrWriter,
    stamp_ns: u64,
    ns: &str,
    width: f64,
    chunks: impl Iterator<Item = (i32, &'a Vec<[f64; 3]>, &'a Vec<Rgba>)> + Clone,
) {
    w.begin();
    w.len(chunks.clone().count());
    for (id, points, colours) in chunks {
        marker(w, stamp_ns, ns, id, 4, width, points, colours);
    }
}

/// One `visualization_msgs/Marker` (action ADD, identity pose, no lifetime) in the world frame.
#[allow(clippy::too_many_arguments)]
fn marker(w: &mut CdrWriter, stamp_ns: u64, ns: &str, id: i32, kind: i32, width: f64, points: &[[f64; 3]], colours: &[Rgba]) {
    header(w, stamp_ns, "world");
    w.string(ns);
    w.i32(id);
    w.i32(kind);
    w.i32(0);
    for v in [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0] {
        w.f64(v);
    }
    for v in [width, width, width] {
        w.f64(v);
    }
    for v in [1.0f32, 1.0, 1.0, 1.0] {
        w.f32(v);
    }
    w.i32(0);
    w.u32(0);
    w.u8(0);
    w.len(points.len());
    for p in points {
        for v in p {
            w.f64(*v);
        }
    }
    w.len(colours.len());
    for c in colours {
        for v in c {
            w.f32(*v);
        }
    }
    // Texture (none): resource, image (header, format, data), UV coordinates.
    w.string("");
    header(w, stamp_ns, "");
    w.string("");
    w.len(0);
    w.len(0);
    // Text, mesh resource, mesh file (name, data), embedded materials: none.
    w.string("");
    w.string("");
    w.string("");
    w.len(0);
    w.u8(0);
}

#[cfg(test)]
mod tests {
    use super::*;

    /// What a viewer ends up with — the last version of each chunk it was sent — is the whole
    /// trail, whenever the sends fall, and the history a late viewer gets is the same.
    #[test]
    fn every_point_of_the_trail_reaches_the_viewer() {
        let mut trail = Trail::new(1_000_000);
        let mut drawn: std::collections::BTreeMap<i32, Vec<[f64; 3]>> = Default::default();
        let mut all = Vec::new();
        for k in 0..1000 {
            let p = [k as f64 * 0.001, 0.0, 0.0];
            trail.add(p, TRAIL_COLOUR);
            all.push(p);
            if k == 600 {
                trail.broken = true; // the bead stops; the next point starts afresh
            }
            if k % 37 == 0 || k == 999 {
                for (id, points, _) in std::mem::take(&mut trail.finished) {
                    drawn.insert(id, points);
                }
                if trail.fresh && trail.points.len() >= 2 {
                    drawn.insert(trail.id, trail.points.clone());
                    trail.fresh = false;
                }
            }
        }
        let mut seen: Vec<[f64; 3]> = drawn.values().flatten().copied().collect();
        seen.dedup();
        assert!(seen == all, "{} points drawn of {}: chunks share their joining point, and nothing may be missing", seen.len(), all.len());
        let mut history: Vec<(i32, Vec<[f64; 3]>)> = trail.history.iter().map(|(i, p, _)| (*i, p.clone())).collect();
        history.push((trail.id, trail.points.clone()));
        assert_eq!(history, drawn.into_iter().collect::<Vec<_>>());
    }

    /// `/bed/mesh`: a line per probed row and column, every point on the surface in W, the lowest
    /// blue and the highest red.
    #[test]
    fn the_bed_mesh_is_drawn_on_its_surface() {
        let cfg = strand_core::BedMeshConfig {
            min: [0.0, 0.0],
            max: [0.1, 0.05],
            points: vec![vec![0.0, 1e-4, 3e-4], vec![-2e-4, 0.0, 1e-4]],
            algorithm: strand_core::MeshAlgorithm::Bicubic,
            fade_start: 1e-3,
            fade_end: 10e-3,
            fade_target: None,
        };
        let rotation = geom::rpy(0.0, 0.1, 0.5);
        let origin = Vector3::new(0.45, 0.0, 0.2);
        let mesh = strand_core::BedMesh::new(&cfg, origin, rotation).unwrap();
        let lines = mesh_lines(&mesh);
        assert_eq!(lines.len(), 2 + 3);
        assert_eq!(lines[0].0.len(), 4 * 2 + 1);
        assert_eq!(lines[2].0.len(), 4 + 1);
        for (points, colours) in &lines {
            assert_eq!(points.len(), colours.len());
            for p in points {
                let (surface, above) = mesh.height_at(&Vector3::from(*p));
                assert!((above - surface).abs() < 1e-12, "{p:?}");
            }
        }
        // Row 1 (y = 0.05) starts at the lowest node, row 0 ends at the highest.
        assert_eq!(lines[1].1[0], [0.0, 0.2, 1.0, 1.0]);
        assert_eq!(*lines[0].1.last().unwrap(), [1.0, 0.2, 0.0, 1.0]);
    }

    #[test]
    fn the_stick_figure_keeps_the_kinematics() {
        let dir = concat!(env!("CARGO_MANIFEST_DIR"), "/config/robots/");
        for (robot, root, tip) in [("iiwa7", "world", "iiwa_link_ee"), ("kr6r900", "base_link", "tool0")] {
            let urdf = std::fs::read_to_string(format!("{dir}{robot}.urdf")).unwrap();
            let drawn = with_stick_visuals(&urdf);
            let parsed = urdf_rs::read_from_string(&drawn).unwrap();
            let sticks = parsed.links.iter().map(|l| l.visual.len()).sum::<usize>();
            assert!(sticks >= 10, "{robot}: {sticks} visuals");
            let a = RobotModel::from_urdf_str(&urdf, robot, root, tip).unwrap();
            let b = RobotModel::from_urdf_str(&drawn, robot, root, tip).unwrap();
            let mut q = JointVector::zeros();
            for k in 0..20 {
                for i in 0..a.dof() {
                    q[i] = ((k * 7 + i * 3) % 11) as f64 * 0.1 - 0.5;
                }
                let (fa, fb) = (a.forward_kinematics(&q), b.forward_kinematics(&q));
                assert!((fa.translation.vector - fb.translation.vector).norm() < 1e-12, "{robot}");
                assert!((fa.rotation.matrix() - fb.rotation.matrix()).norm() < 1e-12, "{robot}");
            }
        }
    }
}
