//! strand's wire contract: the messages that cross process boundaries, and the names of the services
//! that carry them — the types only, no transport. The controller's core and the offline crates
//! (jobs, planners) use them without linking shared memory; `strand-ipc` adds the iceoryx2 ports
//! and re-exports everything here, so a client names them `strand_ipc::Segment` as before.
//!
//! Every message is a fixed-size `#[repr(C)]` struct with no pointers and no implicit padding (every
//! gap is a named `_reserved` field, always zero), so a Python `ctypes.Structure` or a C++ struct with
//! the same fields in the same order has the same layout, and the bytes of a message are fully
//! defined (the logger can store them bit for bit). Each type carries an explicit iceoryx2 type name
//! that includes the contract version ("strand.v5.Segment"): a client built against another version
//! fails to open the service with `IncompatibleTypes` instead of misreading bytes. [`CONTRACT_VERSION`]
//! is also published in every [`Status`]. (The type names and the `ZeroCopySend` marker come from
//! iceoryx2's two building-block crates of derive macro and trait, not from iceoryx2 itself.)
//!
//! Conventions: SI units (m, rad, s; m/s for speeds), world frame W for segments and base poses,
//! quaternions (w, x, y, z), timestamps in nanoseconds of `CLOCK_MONOTONIC` on the robot PC, sequence
//! numbers counting up from any start per publisher. Joint arrays hold [`MAX_JOINTS`] entries of which
//! the first `dof` are used, in chain order (rad for revolute joints, m for prismatic ones).

use iceoryx2_bb_derive_macros::ZeroCopySend;
// The derive refers to the trait by its bare name.
#[allow(unused_imports)]
use iceoryx2_bb_elementary_traits::zero_copy_send::ZeroCopySend;

/// Declares a wire enum: `#[repr(u32)]`, its variants with explicit wire values, and the decoders
/// `from_u32` and `TryFrom<u32>` (the error is the unknown value), derived from the one list so a
/// new variant cannot be forgotten in its decoder.
macro_rules! wire_enum {
    ($(#[$meta:meta])* $vis:vis enum $name:ident { $($(#[$vmeta:meta])* $variant:ident = $value:literal,)+ }) => {
        $(#[$meta])*
        #[repr(u32)]
        $vis enum $name {
            $($(#[$vmeta])* $variant = $value,)+
        }

        impl $name {
            /// The variant for a wire value, if it names one.
            pub fn from_u32(v: u32) -> Option<Self> {
                $(if v == $value {
                    return Some(Self::$variant);
                })+
                None
            }
        }

        impl TryFrom<u32> for $name {
            type Error = u32;
            fn try_from(v: u32) -> Result<Self, u32> {
                Self::from_u32(v).ok_or(v)
            }
        }
    };
}

/// Version of this contract. Bumped on any change of layout or meaning; part of every type name.
pub const CONTRACT_VERSION: u32 = 5;
/// Joints per message (the longest chain strand drives).
pub const MAX_JOINTS: usize = 8;
/// Segments per [`SegmentBatch`].
pub const SEGMENT_BATCH_CAPACITY: usize = 32;
/// Default service-name prefix; the cell name is the second part.
pub const DEFAULT_PREFIX: &str = "strand/cell";

wire_enum! {
    /// What a [`Segment`] describes (`Segment::kind`).
    #[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
    pub enum SegmentKind {
        #[default]
        /// Straight line from the previous end point to `end`.
        Line = 0,
        /// Circular arc or helix about `centre`, in the plane with normal `normal`, sweeping `sweep`.
        Arc = 1,
        /// Stand still for `duration`, optionally moving filament.
        Dwell = 2,
        /// A heater's target and, with a `heat_wait`, a hold: the job stands (no later segment
        /// executes) until the heater's measured temperature has settled (`heater`, `heat_wait`,
        /// `temperature`, `temperature_range`; `end` is not used: the tool stands where the path
        /// is).
        /// Contract v5.
        Heat = 3,
    }
}

wire_enum! {
    /// Which heater a [`SegmentKind::Heat`] segment is about (`Segment::heater`).
    #[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
    pub enum Heater {
        /// The hot end (Klipper's `extruder`; `M104`/`M109`).
        #[default]
        HotEnd = 0,
        /// The bed (Klipper's `heater_bed`; `M140`/`M190`).
        Bed = 1,
    }
}

wire_enum! {
    /// How a [`SegmentKind::Heat`] segment holds the job (`Segment::heat_wait`). Every hold ends
    /// when the measured temperature has stayed inside its band for the service's
    /// `[extruder] temperature_settle_time`, the arm standing still meanwhile.
    #[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
    pub enum HeatWait {
        /// No hold: the target is set where the segment stands in the job, and the job goes on.
        #[default]
        None = 0,
        /// Marlin's `M109 S` / `M190 S`: hold while heating, until |T − target| ≤ the tolerance
        /// (`[extruder] temperature_tolerance`, `bed_temperature_tolerance`); a heater already
        /// above target + tolerance when the hold begins does not hold (no wait for cooling).
        Heating = 1,
        /// Marlin's `M109 R` / `M190 R`: hold until |T − target| ≤ the tolerance, cooling too.
        Both = 2,
        /// Klipper's `TEMPERATURE_WAIT`: hold until `temperature_range[0] ≤ T ≤
        /// temperature_range[1]`; the target is not changed.
        Range = 3,
    }
}

/// Bits of `Segment::flags`.
pub mod segment_flags {
    /// The segment deposits material.
    pub const EXTRUDE: u32 = 1;
    /// A travel move (no material).
    pub const TRAVEL: u32 = 2;
    /// The first segment of a new layer.
    pub const LAYER_START: u32 = 4;
    /// The last segment of the job: the controller stops at its end and reports the job finished.
    pub const LAST: u32 = 8;
    /// `Segment::pressure_advance` holds the program's pressure advance for this segment.
    pub const PRESSURE_ADVANCE: u32 = 16;
    /// `Segment::axes` holds where the cell's external axes (a positioner under the part) are at
    /// the segment's end; without it they keep their position over the segment.
    pub const AXES: u32 = 32;
}

/// External axes a [`Segment`] can carry (a two-axis positioner: tilt and turn).
pub const MAX_EXTERNAL_AXES: usize = 2;

/// One planned motion segment, world frame W. 224 bytes.
///
/// In a cell with a positioner (external axes that carry the part), `end`, `centre`, `normal` and
/// `orientation` are in the *work frame at home*: where they lie in W while every external axis is
/// at 0. The part rides on the positioner; the controller moves the points with it (the path's
/// speed is then the speed on the part: tool-tip following).
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[type_name("strand.v5.Segment")]
#[repr(C)]
pub struct Segment {
    /// Sequence number; consecutive within a job (a gap is rejected).
    pub seq: u64,
    /// When the feeder sent it (ns, monotonic).
    pub stamp_ns: u64,
    /// [`SegmentKind`] as u32.
    pub kind: u32,
    /// [`segment_flags`] bits.
    pub flags: u32,
    /// End point (m, W).
    pub end: [f64; 3],
    /// Arc centre (m, W); arcs only.
    pub centre: [f64; 3],
    /// Arc plane normal (unit, W); the arc turns counter-clockwise about it; arcs only.
    pub normal: [f64; 3],
    /// Arc sweep angle (rad, > 0); arcs only.
    pub sweep: f64,
    /// Tool orientation at the end (unit quaternion w, x, y, z, W); the nozzle is its z axis.
    pub orientation: [f64; 4],
    /// Programmed feed speed along the path (m/s, > 0 for lines and arcs).
    pub feed: f64,
    /// Filament length to push over the segment (m; < 0 retracts).
    pub filament: f64,
    /// Dwell time (s); dwells only.
    pub duration: f64,
    /// Line in the source program (0 if none), for reports.
    pub source_line: u32,
    /// Always 0.
    pub _reserved: u32,
    /// Pressure advance the program set (s; `SET_PRESSURE_ADVANCE`, `M900 K`, `M572 S`), valid when
    /// the [`segment_flags::PRESSURE_ADVANCE`] bit is set; the controller clamps it to its config's
    /// `[extruder] max_pressure_advance`. Without the bit the config's `pressure_advance` holds.
    pub pressure_advance: f64,
    /// Where the cell's external axes are at the segment's end (rad or m, in the order of the
    /// cell's `[positioner]` chain; unused entries 0), valid with [`segment_flags::AXES`]. Over
    /// the segment they move in proportion to the path travelled.
    pub axes: [f64; MAX_EXTERNAL_AXES],
    /// [`Heater`] as u32; [`SegmentKind::Heat`] only (0 otherwise).
    pub heater: u32,
    /// [`HeatWait`] as u32; [`SegmentKind::Heat`] only (0 otherwise).
    pub heat_wait: u32,
    /// The heater's new target (°C — temperatures are in degrees Celsius on the wire, the one
    /// exception to SI, as every firmware and slicer writes them; 0 = heater off; < 0 = keep the
    /// current target, as `TEMPERATURE_WAIT` does); [`SegmentKind::Heat`] only.
    pub temperature: f64,
    /// The band of a [`HeatWait::Range`] hold (°C, low then high; an open end is −273.15 or
    /// 10,000); [`SegmentKind::Heat`] only.
    pub temperature_range: [f64; 2],
}

/// Up to [`SEGMENT_BATCH_CAPACITY`] segments in one message, in order.
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("strand.v5.SegmentBatch")]
#[repr(C)]
pub struct SegmentBatch {
    /// Batch sequence number.
    pub seq: u64,
    /// When the feeder sent it (ns, monotonic).
    pub stamp_ns: u64,
    /// Segments used, from the front.
    pub len: u32,
    /// Always 0.
    pub _reserved: u32,
    /// The segments; entries at `len` and beyond are ignored.
    pub segments: [Segment; SEGMENT_BATCH_CAPACITY],
}

impl Default for SegmentBatch {
    fn default() -> Self {
        SegmentBatch { seq: 0, stamp_ns: 0, len: 0, _reserved: 0, segments: [Segment::default(); SEGMENT_BATCH_CAPACITY] }
    }
}

impl SegmentBatch {
    /// The segments in use.
    pub fn as_slice(&self) -> &[Segment] {
        &self.segments[..(self.len as usize).min(SEGMENT_BATCH_CAPACITY)]
    }
}

wire_enum! {
    /// An operator or client command (`Control::command`).
    #[derive(Clone, Copy, Debug, PartialEq, Eq)]
    pub enum Command {
        /// Start the queued job (moving to its first point first if needed).
        Start = 1,
        /// Slow to a stop on the path and wait.
        Pause = 2,
        /// Continue after a pause.
        Resume = 3,
        /// Controlled stop on the path; the rest of the job is discarded.
        Stop = 4,
        /// Stop as fast as the joint limits allow, extrusion off, then fault.
        EmergencyStop = 5,
        /// Clear a latched fault.
        ClearFault = 6,
        /// Set the feed override to `value` (fraction, 0.01 to 2).
        FeedOverride = 7,
        /// Set the flow override to `value` (fraction, 0 to 2).
        FlowOverride = 8,
        /// The robot's own speed scaling is `value` (fraction, 0.01 to 1): UR's speed slider times
        /// its trajectory limiter, sent by the robot's driver when it changes. The path's speed is
        /// the feed override times it, so that the path slows with the robot instead of the robot
        /// falling behind its commands; the operator's feed override (`Status::feed_override`)
        /// stays the operator's.
        RobotSpeedScaling = 9,
        /// The next job starts `value` metres along a moving base's plan (`[base] plan`, by the
        /// print's progress) instead of at its start: a job resumed at segment n (strand-feed
        /// `--resume-from`, `--resume-layer`) sends the program's path length before n, so the base
        /// goes where the plan has it there, not back to the plan's start. Idle only; 0 to 10⁶ m;
        /// it holds until that job ends.
        ProgressOffset = 10,
    }
}

/// A command to the controller. 32 bytes.
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[type_name("strand.v5.Control")]
#[repr(C)]
pub struct Control {
    /// Sequence number.
    pub seq: u64,
    /// When it was sent (ns, monotonic).
    pub stamp_ns: u64,
    /// [`Command`] as u32.
    pub command: u32,
    /// Always 0.
    pub _reserved: u32,
    /// Argument of the override commands (fraction); 0 otherwise.
    pub value: f64,
}

/// Bits of `JointState::flags`.
pub mod joint_state_flags {
    /// `robot_target` holds the joint target the robot was last given (a driver fills it; a
    /// simulator or a client that does not know leaves it 0).
    pub const TARGET_KNOWN: u32 = 1;
    /// Since the previous JointState the robot kept its last target through one cycle or more: an
    /// answer never reached it in its cycle (the service was late, the answer left too late, or a
    /// packet was lost). It stood at `robot_target`; the driver's guard catches up from there.
    pub const HELD: u32 = 2;
    /// The robot's last target was not the service's command: the driver's guard is catching up
    /// with it after a hold.
    pub const CATCHING_UP: u32 = 4;
}

/// Measured joint state from the robot driver, and what the driver last told the robot. 344 bytes.
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[type_name("strand.v5.JointState")]
#[repr(C)]
pub struct JointState {
    /// Sequence number.
    pub seq: u64,
    /// When the joints were measured (ns, monotonic).
    pub stamp_ns: u64,
    /// Joints used.
    pub dof: u32,
    /// [`joint_state_flags`] bits.
    pub flags: u32,
    /// Joint positions (rad or m).
    pub position: [f64; MAX_JOINTS],
    /// Joint velocities (rad/s or m/s).
    pub velocity: [f64; MAX_JOINTS],
    /// Joint torques or forces (N·m or N); 0 if not measured.
    pub effort: [f64; MAX_JOINTS],
    /// The joint target the robot holds, as the driver last gave it (rad or m): the service's
    /// command when in step, the guard's answer while it catches up. Valid with
    /// [`joint_state_flags::TARGET_KNOWN`].
    pub robot_target: [f64; MAX_JOINTS],
    /// The velocity of that target (rad/s or m/s): its step over the robot's last cycle, divided
    /// by the cycle. Valid with [`joint_state_flags::TARGET_KNOWN`].
    pub robot_target_velocity: [f64; MAX_JOINTS],
}

/// A feeder's view of the job it streams, for consoles (`strand ctl status`) and HMIs: what the
/// controller cannot know — the job's name, its layers, how far it is and when it will end.
/// Published by the feeder about once a second on its own service (the controller does not read
/// it); history 1, so a console that opens late gets the latest at the next publish. 112 bytes.
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("strand.v5.JobProgress")]
#[repr(C)]
pub struct JobProgress {
    /// Sequence number.
    pub seq: u64,
    /// When it was published (ns, monotonic).
    pub stamp_ns: u64,
    /// The job's first and last segment numbers.
    pub first_seq: u64,
    /// The job's last segment number.
    pub last_seq: u64,
    /// Segments sent so far (count).
    pub segments_sent: u64,
    /// The program's layer of the segment executing (the slicer's number; −1: none yet or unknown).
    pub layer: i32,
    /// The program's last layer (−1: unknown).
    pub last_layer: i32,
    /// Fraction of the job's path length done (0 to 1).
    pub fraction: f64,
    /// Time since streaming started (s).
    pub elapsed_s: f64,
    /// Estimated time left (s; < 0: not known yet).
    pub eta_s: f64,
    /// The job's file name (UTF-8, zero-padded, cut to 40 bytes).
    pub name: [u8; 40],
}

impl Default for JobProgress {
    fn default() -> Self {
        JobProgress {
            seq: 0,
            stamp_ns: 0,
            first_seq: 0,
            last_seq: 0,
            segments_sent: 0,
            layer: -1,
            last_layer: -1,
            fraction: 0.0,
            elapsed_s: 0.0,
            eta_s: -1.0,
            name: [0; 40],
        }
    }
}

impl JobProgress {
    /// `name` cut to the field (on a character boundary).
    pub fn set_name(&mut self, name: &str) {
        let mut end = name.len().min(self.name.len());
        while !name.is_char_boundary(end) {
            end -= 1;
        }
        self.name = [0; 40];
        self.name[..end].copy_from_slice(&name.as_bytes()[..end]);
    }

    /// The name as text.
    pub fn name(&self) -> String {
        let end = self.name.iter().position(|b| *b == 0).unwrap_or(self.name.len());
        String::from_utf8_lossy(&self.name[..end]).into_owned()
    }
}

/// A measured pose of the robot base B in W, from tracking. 72 bytes.
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[type_name("strand.v5.BasePose")]
#[repr(C)]
pub struct BasePose {
    /// Sequence number.
    pub seq: u64,
    /// When the pose was *measured* (ns, monotonic; the capture time, not the arrival time).
    pub stamp_ns: u64,
    /// Base origin (m, W).
    pub position: [f64; 3],
    /// Base orientation R_WB (unit quaternion w, x, y, z).
    pub orientation: [f64; 4],
}

/// Bits of `HeaterState::flags` and `Status::heater_flags`.
pub mod heater_flags {
    /// `hot_end` holds a measurement.
    pub const HOT_END: u32 = 1;
    /// `bed` holds a measurement.
    pub const BED: u32 = 2;
    /// (`Status` only) the service acts on temperatures (`[extruder] heater = "wire"`): it holds
    /// at waits and refuses cold extrusion. Without it, targets are passed on and waits skipped.
    pub const ACTING: u32 = 4;
    /// (`HeaterState` only) the owner has switched a heater off for a fault (it does not heat as
    /// commanded, or its thermistor is out of range): the service faults `HeaterFault`.
    pub const FAULT: u32 = 8;
}

/// Measured heater temperatures, from whoever owns the heaters: strand-sim's thermal model today,
/// a Klipper extruder board's process (`strand-mcu`) later. Publish at 5 Hz or faster (the
/// service faults `TemperatureLost` after `[extruder] temperature_timeout` without one while a
/// hold or an extruding move needs it). Temperatures in °C (the wire's one exception to SI). 56 bytes.
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[type_name("strand.v5.HeaterState")]
#[repr(C)]
pub struct HeaterState {
    /// Sequence number.
    pub seq: u64,
    /// When the temperatures were measured (ns, monotonic).
    pub stamp_ns: u64,
    /// Hot end (°C), valid with [`heater_flags::HOT_END`].
    pub hot_end: f64,
    /// Bed (°C), valid with [`heater_flags::BED`].
    pub bed: f64,
    /// The hot end heater's duty (fraction, 0 to 1; for display).
    pub hot_end_power: f64,
    /// The bed heater's duty (fraction, 0 to 1; for display).
    pub bed_power: f64,
    /// [`heater_flags`] bits (`HOT_END`, `BED`).
    pub flags: u32,
    /// Always 0.
    pub _reserved: u32,
}

/// The heater targets for whoever owns the heaters (strand-sim, a board's process), published
/// every tick: targets change where the job says (in order with the motion: a
/// [`SegmentKind::Heat`] segment takes effect when the path reaches it), and fall to 0 (off) on
/// every fault and emergency stop. °C (the wire's one exception to SI). 48 bytes.
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[type_name("strand.v5.HeaterCommand")]
#[repr(C)]
pub struct HeaterCommand {
    /// Sequence number (one per tick).
    pub seq: u64,
    /// Nominal time of the tick (ns, monotonic).
    pub stamp_ns: u64,
    /// Tick index.
    pub tick: u64,
    /// Hot end target (°C; 0 = off).
    pub hot_end_target: f64,
    /// Bed target (°C; 0 = off).
    pub bed_target: f64,
    /// Always 0.
    pub _reserved: u64,
}

/// The joint command for the robot driver. 240 bytes.
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[type_name("strand.v5.JointCommand")]
#[repr(C)]
pub struct JointCommand {
    /// Sequence number (one per tick).
    pub seq: u64,
    /// Nominal time of the tick that computed it (ns, monotonic).
    pub stamp_ns: u64,
    /// Tick index.
    pub tick: u64,
    /// Sequence number of the latest [`JointState`] the tick used (0 if none): a driver measures
    /// state-in → command-out latency with it.
    pub state_seq: u64,
    /// That state's timestamp (ns, monotonic).
    pub state_stamp_ns: u64,
    /// Joints used.
    pub dof: u32,
    /// 1 when the command is valid; 0 before the controller knows where the robot is (drivers hold).
    pub valid: u32,
    /// Joint positions for the next tick (rad or m).
    pub position: [f64; MAX_JOINTS],
    /// Joint velocities (rad/s or m/s).
    pub velocity: [f64; MAX_JOINTS],
    /// Joint accelerations (rad/s² or m/s²).
    pub acceleration: [f64; MAX_JOINTS],
}

/// Bits of `ExtruderCommand::flags`.
pub mod extruder_flags {
    /// Material is being deposited along the path.
    pub const EXTRUDING: u32 = 1;
    /// The filament is pulled back (after an unplanned stop or pause).
    pub const RETRACTED: u32 = 2;
}

/// The extruder command for the extruder driver. 64 bytes.
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[type_name("strand.v5.ExtruderCommand")]
#[repr(C)]
pub struct ExtruderCommand {
    /// Sequence number (one per tick).
    pub seq: u64,
    /// Nominal time of the tick (ns, monotonic).
    pub stamp_ns: u64,
    /// Tick index.
    pub tick: u64,
    /// Drive wheel speed (rad/s; < 0 retracts).
    pub motor_speed: f64,
    /// Filament speed into the hot end (m/s).
    pub filament_rate: f64,
    /// Filament pushed since the service started (m).
    pub filament_position: f64,
    /// Volumetric flow (m³/s).
    pub volumetric_rate: f64,
    /// [`extruder_flags`] bits.
    pub flags: u32,
    /// Always 0.
    pub _reserved: u32,
}

/// The moving base's setpoint for its own controller (000's free flyer, a mobile platform): the
/// base's planned pose taken at the print's progress, not at a time, so that a pause stops the base
/// with the nozzle and a feed override slows both (the `[base] plan` of the service config), and
/// moved there within the base's velocity and acceleration limits. Published every tick while the
/// service has a plan; `valid` is 0 without one. 152 bytes.
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[type_name("strand.v5.BaseCommand")]
#[repr(C)]
pub struct BaseCommand {
    /// Sequence number (one per tick).
    pub seq: u64,
    /// Nominal time of the tick (ns, monotonic).
    pub stamp_ns: u64,
    /// Tick index.
    pub tick: u64,
    /// Where the base origin should be (m, W).
    pub position: [f64; 3],
    /// Its orientation R_WB (unit quaternion w, x, y, z): the mount's roll and pitch, the plan's yaw.
    pub orientation: [f64; 4],
    /// The setpoint's velocity (m/s, W).
    pub velocity: [f64; 3],
    /// The setpoint's angular velocity (rad/s, W; about z).
    pub angular_velocity: [f64; 3],
    /// The print's progress the plan was read at: path length since the job's first point (m).
    pub progress: f64,
    /// How far the setpoint is behind the plan's pose at that progress (m, horizontal): the
    /// base's limits at work (a fast stretch, a stop, the move to the plan's start).
    pub lag: f64,
    /// 1 when the service has a plan and the setpoint is meant; 0 otherwise (hold where you are).
    pub valid: u32,
    /// Always 0.
    pub _reserved: u32,
}

wire_enum! {
    /// The controller's run state (`Status::run_state`, `JointCommand` has it too).
    #[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
    pub enum RunState {
        /// No job running; segments may be queued.
        #[default]
        Idle = 0,
        /// Moving in joint space to the job's first point, not extruding.
        Approaching = 1,
        /// Executing the path.
        Running = 2,
        /// Slowing to a stop on the path.
        Pausing = 3,
        /// Stopped on the path; resume continues.
        Paused = 4,
        /// Controlled stop on the path; the rest of the job is then discarded.
        Stopping = 5,
        /// Braking as hard as the joint limits allow, then fault.
        EmergencyStopping = 6,
        /// Latched fault: holding still until ClearFault.
        Fault = 7,
    }
}

wire_enum! {
    /// Why the controller faulted (`Status::fault`).
    #[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
    pub enum FaultCode {
        /// No fault.
        #[default]
        None = 0,
        /// An emergency stop was commanded.
        EmergencyStop = 1,
        /// Base tracking went silent past its timeout.
        TrackingLost = 2,
        /// The robot's joint state went silent past its timeout.
        JointStateLost = 3,
        /// A non-finite number appeared in the controller (never published).
        NonFinite = 4,
        /// The job's first point could not be reached (no inverse kinematics solution).
        ApproachFailed = 5,
        /// The measured joints left their limits or the commanded path by more than allowed.
        RobotDeviation = 6,
        /// The path had segments to execute but made no progress (neither the path position nor a
        /// dwell advanced) for `[path] stall_timeout`: a planner fault, never a silent hang.
        PathStalled = 7,
        /// The TCP stayed further than `[controller] tcp_error_limit` from the path target for
        /// `tcp_error_time`: the commanded (or measured) tool left its path — out of reach, at a joint
        /// limit, a singularity, or a base that drifted away.
        TcpErrorLimit = 8,
        /// An extruding segment was about to start (or the extruder to push) with the hot end's
        /// measured temperature below `[extruder] min_extrude_temp`, as Marlin and Klipper refuse
        /// a cold extrusion: the job stops, nothing is pushed.
        ColdExtrusion = 9,
        /// No [`HeaterState`] within `[extruder] temperature_timeout` while a hold or an extruding
        /// move needed the temperature (the heater's owner went silent or stopped measuring).
        TemperatureLost = 10,
        /// The heaters' owner switched a heater off and said so ([`heater_flags::FAULT`] in a
        /// [`HeaterState`]): it could not reach or hold its target within bounds (Klipper's
        /// verify_heater), or its thermistor left its range. The job stops; the heaters stay off.
        HeaterFault = 11,
    }
}

wire_enum! {
    /// Why a segment or control was rejected (`Status::last_reject_reason`).
    #[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
    pub enum RejectReason {
        /// Nothing rejected.
        #[default]
        None = 0,
        /// A field is NaN or infinite.
        NonFinite = 1,
        /// Feed ≤ 0 (or a dwell's duration < 0).
        BadFeed = 2,
        /// A point outside the configured workspace bounds.
        OutOfBounds = 3,
        /// The sequence number is not the next one expected.
        SequenceGap = 4,
        /// The intake queue is full; resend after Status shows space.
        QueueFull = 5,
        /// Inconsistent geometry (arc centre, normal, sweep, orientation).
        BadGeometry = 6,
        /// Unknown segment kind or control command.
        UnknownKind = 7,
        /// The controller cannot take it yet (no joint state, or faulted).
        NotReady = 8,
        /// The command is not allowed in the current run state.
        NotAllowed = 9,
        /// An override value outside its range.
        BadValue = 10,
        /// A joint state with the wrong number of joints.
        WrongDof = 11,
        /// A segment sent before a Stop or an emergency stop the controller took (its `stamp_ns`
        /// is not after the stop's): the rest of the job that stop ended, still in flight. Refused
        /// so that it cannot open a job nobody started. A `stamp_ns` of 0 is never stale.
        Stale = 12,
    }
}

wire_enum! {
    /// How the last job ended (`Status::job_outcome`).
    #[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
    pub enum JobOutcome {
        /// No job has run yet.
        #[default]
        None = 0,
        /// A job is in progress.
        InProgress = 1,
        /// The segment flagged LAST ran to its end.
        Finished = 2,
        /// Stopped on command (or because the feeder went away); the rest was discarded.
        Stopped = 3,
        /// Ended by a fault or an emergency stop.
        Faulted = 4,
    }
}

/// The controller's state, published every tick. Feeders use `last_received_seq + queue_free` as the
/// last segment sequence number they may send (credit-based back-pressure: nothing is ever dropped).
/// 256 bytes.
#[derive(Debug, Clone, Copy, Default, PartialEq, ZeroCopySend)]
#[type_name("strand.v5.Status")]
#[repr(C)]
pub struct Status {
    /// Sequence number (one per tick).
    pub seq: u64,
    /// Nominal time of the tick (ns, monotonic).
    pub stamp_ns: u64,
    /// Tick index.
    pub tick: u64,
    /// [`CONTRACT_VERSION`] of the service.
    pub contract_version: u32,
    /// [`RunState`] as u32.
    pub run_state: u32,
    /// [`FaultCode`] as u32 (latched until ClearFault).
    pub fault: u32,
    /// [`JobOutcome`] as u32.
    pub job_outcome: u32,
    /// [`RejectReason`] of the last rejected segment or control.
    pub last_reject_reason: u32,
    /// Segments the intake queue holds at most.
    pub queue_capacity: u32,
    /// Segments the intake queue can take now.
    pub queue_free: u32,
    /// Source line of the segment being executed.
    pub executing_line: u32,
    /// Sequence number of the last segment received and accepted (0 before any).
    pub last_received_seq: u64,
    /// Sequence number of the last rejected segment (0 if none).
    pub last_rejected_seq: u64,
    /// Sequence number of the segment being executed.
    pub executing_seq: u64,
    /// Segments accepted since start.
    pub segments_accepted: u64,
    /// Segments and controls rejected since start.
    pub rejected: u64,
    /// Times the path ran dry before the job's last segment.
    pub underruns: u64,
    /// Ticks whose work did not finish before the next tick was due.
    pub overruns: u64,
    /// Wake-ups later than the configured lateness threshold.
    pub late_wakeups: u64,
    /// Worst wake-up lateness so far (ns).
    pub worst_lateness_ns: u64,
    /// Ticks in which the final command stage had to clamp a joint (position, speed or acceleration).
    pub clamps: u64,
    /// Records the logger could not take (queue full or write error).
    pub log_drops: u64,
    /// Feed override (fraction).
    pub feed_override: f64,
    /// Flow override (fraction).
    pub flow_override: f64,
    /// Path position since the job's start (m).
    pub path_position: f64,
    /// Path speed (m/s).
    pub path_speed: f64,
    /// TCP position error the CLIK corrected this tick (m).
    pub tcp_error: f64,
    /// [`LogState`] as u32: whether the MCAP log is being written.
    pub log_state: u32,
    /// Layer of the segment being executed: the segments flagged `LAYER_START` that have begun
    /// executing since the job started (0 before the first). A feeder that resumes a job from
    /// layer N adds N − 1 to show the program's layer number.
    pub executing_layer: u32,
    /// Hot end: measured (°C; valid with [`heater_flags::HOT_END`] in `heater_flags`).
    pub hot_end_temperature: f64,
    /// Hot end: the target in force (°C; 0 = off).
    pub hot_end_target: f64,
    /// Bed: measured (°C; valid with [`heater_flags::BED`]).
    pub bed_temperature: f64,
    /// Bed: the target in force (°C; 0 = off).
    pub bed_target: f64,
    /// [`heater_flags`] bits: which measurements are fresh, and whether the service acts on them.
    pub heater_flags: u32,
    /// [`HeatHold`] as u32: the job holds at a heat wait (the path stands still).
    pub heat_hold: u32,
    /// During a hold: the settle time still to run (s); the whole settle time while the
    /// temperature is outside the band.
    pub heat_hold_left: f64,
    /// During a hold: the band the temperature must stay in (°C, low then high).
    pub heat_hold_band: [f64; 2],
}

wire_enum! {
    /// What the job holds for (`Status::heat_hold`).
    #[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
    pub enum HeatHold {
        /// No hold.
        #[default]
        None = 0,
        /// Waiting for the hot end (`M109`, `TEMPERATURE_WAIT SENSOR=extruder`).
        HotEnd = 1,
        /// Waiting for the bed (`M190`, `TEMPERATURE_WAIT SENSOR=heater_bed`).
        Bed = 2,
    }
}

wire_enum! {
    /// Whether the service is logging (`Status::log_state`).
    #[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
    pub enum LogState {
        /// No log configured.
        #[default]
        Off = 0,
        /// Every tick is written.
        Recording = 1,
        /// A write failed (disk full, I/O error): logging stopped, control goes on, and every tick
        /// since is counted in `Status::log_drops`.
        Failed = 2,
        /// The log's disk has less free space than `[log] min_free_bytes`: only the replay record
        /// and the segments are written (every tick still is, and still replays); the derived and
        /// viewing channels resume when the space is back.
        RecordOnly = 3,
    }
}

/// The service names of one cell, all under one prefix (default [`DEFAULT_PREFIX`]). Each
/// publish-subscribe service has an event service of the same name for wake-ups: publishers notify
/// after sending.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ServiceNames {
    /// The prefix, e.g. `strand/cell`.
    pub prefix: String,
}

impl ServiceNames {
    /// Names under `prefix` (no trailing slash).
    pub fn new(prefix: &str) -> Self {
        ServiceNames { prefix: prefix.trim_end_matches('/').to_string() }
    }
    /// [`SegmentBatch`]es from feeders.
    pub fn segments(&self) -> String {
        format!("{}/segments", self.prefix)
    }
    /// [`Control`] commands.
    pub fn control(&self) -> String {
        format!("{}/control", self.prefix)
    }
    /// [`JointState`] from the robot driver.
    pub fn joint_state(&self) -> String {
        format!("{}/joint_state", self.prefix)
    }
    /// [`BasePose`] from tracking.
    pub fn base_pose(&self) -> String {
        format!("{}/base_pose", self.prefix)
    }
    /// [`JointCommand`] to the robot driver.
    pub fn joint_command(&self) -> String {
        format!("{}/joint_command", self.prefix)
    }
    /// [`ExtruderCommand`] to the extruder driver.
    pub fn extruder_command(&self) -> String {
        format!("{}/extruder_command", self.prefix)
    }
    /// [`BaseCommand`] to a moving base's controller.
    pub fn base_command(&self) -> String {
        format!("{}/base_command", self.prefix)
    }
    /// [`Status`] of the controller.
    pub fn status(&self) -> String {
        format!("{}/status", self.prefix)
    }
    /// [`JobProgress`] from the feeder.
    pub fn job_progress(&self) -> String {
        format!("{}/job_progress", self.prefix)
    }
    /// [`HeaterState`] from the heaters' owner (strand-sim, a board's process).
    pub fn heater_state(&self) -> String {
        format!("{}/heater_state", self.prefix)
    }
    /// [`HeaterCommand`] to the heaters' owner.
    pub fn heater_command(&self) -> String {
        format!("{}/heater_command", self.prefix)
    }
}

impl Default for ServiceNames {
    fn default() -> Self {
        ServiceNames::new(DEFAULT_PREFIX)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use core::mem::{align_of, size_of};

    /// The sizes are part of the contract (Python and C++ mirrors check them).
    #[test]
    fn sizes_are_stable() {
        assert_eq!(size_of::<Segment>(), 224);
        assert_eq!(size_of::<SegmentBatch>(), 24 + 32 * 224);
        assert_eq!(size_of::<Control>(), 32);
        assert_eq!(size_of::<JointState>(), 24 + 5 * 64);
        assert_eq!(size_of::<BasePose>(), 72);
        assert_eq!(size_of::<JointCommand>(), 48 + 3 * 64);
        assert_eq!(size_of::<ExtruderCommand>(), 64);
        assert_eq!(size_of::<BaseCommand>(), 152);
        assert_eq!(size_of::<Status>(), 256);
        assert_eq!(size_of::<HeaterState>(), 56);
        assert_eq!(size_of::<HeaterCommand>(), 48);
        assert_eq!(size_of::<JobProgress>(), 112);
        for a in [align_of::<Segment>(), align_of::<Status>(), align_of::<JointCommand>()] {
            assert_eq!(a, 8);
        }
    }

    #[test]
    fn enums_round_trip() {
        for v in 0..12 {
            if let Some(r) = RejectReason::from_u32(v) {
                assert_eq!(r as u32, v);
            }
            if let Some(s) = RunState::from_u32(v) {
                assert_eq!(s as u32, v);
            }
            if let Some(c) = Command::from_u32(v) {
                assert_eq!(c as u32, v);
            }
        }
        assert_eq!(RunState::from_u32(8), None);
        assert_eq!(Command::from_u32(0), None);
    }

    #[test]
    fn names_share_the_prefix() {
        let n = ServiceNames::new("strand/test/");
        assert_eq!(n.segments(), "strand/test/segments");
        assert_eq!(n.status(), "strand/test/status");
    }
}
