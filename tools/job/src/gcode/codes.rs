//! Code tables: what each G- and M-code means in each [`Dialect`], and the one-line description
//! given when one is not acted on. Acting on them is the interpreter's (RS274/NGC core) and the
//! dialect module's (firmware commands) business; this module only sorts.

use super::block::Block;
use super::dialect::Dialect;
use super::limits::LimitM;
use super::{INCH, MM};

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Motion {
    Rapid,
    Linear,
    Clockwise,
    CounterClockwise,
}

impl Motion {
    pub(super) fn name(self) -> &'static str {
        match self {
            Motion::Rapid => "G0",
            Motion::Linear => "G1",
            Motion::Clockwise => "G2",
            Motion::CounterClockwise => "G3",
        }
    }

    pub(super) fn is_arc(self) -> bool {
        matches!(self, Motion::Clockwise | Motion::CounterClockwise)
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Plane {
    Xy,
    Zx,
    Yz,
}

/// An arc plane as LinuxCNC orders it: (first, second, normal) form a right-handed frame, and G3
/// turns from first towards second.
pub(super) struct PlaneAxes {
    pub(super) first: usize,
    pub(super) second: usize,
    pub(super) normal: usize,
    /// Centre-offset letters along first, second and normal.
    pub(super) offsets: [u8; 3],
    pub(super) name: &'static str,
}

impl Plane {
    pub(super) fn axes(self) -> PlaneAxes {
        match self {
            Plane::Xy => PlaneAxes { first: 0, second: 1, normal: 2, offsets: [b'I', b'J', b'K'], name: "XY plane (G17)" },
            Plane::Zx => PlaneAxes { first: 2, second: 0, normal: 1, offsets: [b'K', b'I', b'J'], name: "ZX plane (G18)" },
            Plane::Yz => PlaneAxes { first: 1, second: 2, normal: 0, offsets: [b'J', b'K', b'I'], name: "YZ plane (G19)" },
        }
    }
}

/// What a G-code does here.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) enum GAction {
    Motion(Motion),
    CancelMotion,
    Dwell,
    Plane(Plane),
    Units(f64),
    Absolute(bool),
    AbsoluteArcCentres(bool),
    SetPosition,
    ResetOffsets,
    /// Firmware retraction: `G10` (true) or its recovery `G11` (false).
    Retract(bool),
    /// Not acted on; true if its words are its own parameters (`G28 X0`, `G29 P1`), false if axis
    /// words beside it still move with the modal motion (`G43 H1 Z5`, as in RS274/NGC).
    Ignored {
        takes_axes: bool,
    },
    /// Acting on it would change the path, ignoring it too: an error.
    Unsupported(&'static str),
}

/// The meaning of `G<tenths/10>` on `block` in `dialect`.
pub(super) fn classify_g(tenths: u32, dialect: Dialect, block: &Block) -> GAction {
    use GAction::*;
    match (tenths, dialect) {
        // Marlin, RepRapFirmware and Klipper: G10 retracts, G11 recovers. A G10 with L is
        // LinuxCNC's/RRF's "set offsets", with P RepRapFirmware's tool offsets and temperatures.
        (100, Dialect::Firmware) if !block.has_any(b"LP") => Retract(true),
        (110, Dialect::Firmware) => Retract(false),
        // Prusa's firmware reads G80 as mesh bed levelling and may give it a region (`G80 X.. Y..
        // W.. H..`); RS274/NGC's "cancel motion" is harmless to a printer, so both hold, with the
        // words as parameters.
        (800, Dialect::Firmware) if block.params.iter().any(Option::is_some) => Ignored { takes_axes: true },
        _ => classify_rs274(tenths),
    }
}

/// RS274/NGC (LinuxCNC) meanings, plus the printer homing and levelling codes.
fn classify_rs274(tenths: u32) -> GAction {
    use GAction::*;
    match tenths {
        0 => Motion(self::Motion::Rapid),
        10 => Motion(self::Motion::Linear),
        20 => Motion(self::Motion::Clockwise),
        30 => Motion(self::Motion::CounterClockwise),
        1..=39 => Unsupported("unknown motion variant"),
        40 => Dwell,
        170 => Plane(self::Plane::Xy),
        180 => Plane(self::Plane::Zx),
        190 => Plane(self::Plane::Yz),
        200 => Units(INCH),
        210 => Units(MM),
        800 => CancelMotion,
        900 => Absolute(true),
        910 => Absolute(false),
        901 => AbsoluteArcCentres(true),
        911 => AbsoluteArcCentres(false),
        920 => SetPosition,
        921 | 922 => ResetOffsets,
        50..=53 => Unsupported("spline motion"),
        60 => Unsupported("direct stepper motion"),
        70 => Unsupported("lathe diameter mode"),
        330 | 331 => Unsupported("spindle-synchronised motion"),
        382..=385 => Unsupported("probing motion"),
        410 | 411 | 420 | 421 => Unsupported("cutter radius compensation"),
        510 => Unsupported("scaling"),
        520 => Unsupported("local coordinate offset"),
        530 => Unsupported("motion in machine coordinates"),
        680 => Unsupported("coordinate rotation"),
        700..=722 | 730 | 740 | 760 | 810..=890 => Unsupported("canned cycle"),
        930 => Unsupported("inverse-time feed"),
        950 => Unsupported("feed per revolution"),
        // RS274/NGC modal codes whose axis words (if any) still move.
        80 | 400 | 430..=432 | 490 | 540..=593 | 610 | 611 | 640 | 940 | 960 | 970 | 980 | 990 => Ignored { takes_axes: false },
        // Everything else (homing G28, levelling G29, firmware extras such as G12, G26, G27,
        // G34, G60, Bambu's G29.1, G380): its words are its parameters, never a move.
        _ => Ignored { takes_axes: true },
    }
}

/// A short description of a G-code not acted on, for the first warning of its kind.
pub(super) fn ignored_g_message(tenths: u32) -> &'static str {
    match tenths {
        280 | 281 | 300 | 301 => "homing / predefined position not acted on: position unchanged",
        290..=299 | 800 => "bed levelling not acted on",
        100 => "G10 with L or P (set offsets, tool settings) not acted on",
        110 => "G11 not acted on (RS274/NGC: no meaning)",
        400 => "cutter compensation off: nothing to do",
        430..=432 | 490 => "tool length offset not acted on",
        540..=593 => "work coordinate system not acted on",
        610 | 611 | 640 => "path control mode not acted on (blending is the path engine's)",
        80 => "lathe radius mode: X is read as a radius, as always here",
        940 => "units-per-minute feed mode: the only one supported",
        _ => "G-code not acted on",
    }
}

/// A firmware M-code that the parser acts on (firmware dialect only).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum FirmwareM {
    /// M220: feed percentage.
    FeedOverride,
    /// M221: flow percentage.
    FlowOverride,
    /// M207: firmware retraction settings.
    RetractSettings,
    /// A motion limit (see the `limits` module).
    Limit(LimitM),
    /// M104/M109 (hot end), M140/M190 (bed): a heater's target, and with `wait` a hold.
    Heat { bed: bool, wait: bool },
}

/// What an M-code does here.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum MAction {
    ExtruderMode { absolute: bool },
    ProgramEnd,
    Firmware(FirmwareM),
    Ignored,
}

pub(super) fn classify_m(tenths: u32, dialect: Dialect) -> MAction {
    use FirmwareM::*;
    use LimitM::*;
    let firmware = match tenths {
        820 | 830 => return MAction::ExtruderMode { absolute: tenths == 820 },
        20 | 300 => return MAction::ProgramEnd,
        _ if dialect == Dialect::Rs274ngc => return MAction::Ignored,
        1040 => Heat { bed: false, wait: false },
        1090 => Heat { bed: false, wait: true },
        1400 => Heat { bed: true, wait: false },
        1900 => Heat { bed: true, wait: true },
        2200 => FeedOverride,
        2210 => FlowOverride,
        2070 => RetractSettings,
        2030 => Limit(AxisFeeds),
        2010 => Limit(AxisAccelerations),
        2040 => Limit(Accelerations),
        2050 => Limit(Jerk),
        5660 => Limit(JerkPerMinute),
        9000 => Limit(LinearAdvance),
        5720 => Limit(PressureAdvance),
        _ => return MAction::Ignored,
    };
    MAction::Firmware(firmware)
}

pub(super) fn ignored_m_message(tenths: u32) -> &'static str {
    match tenths {
        0 | 10 | 250 | 6000 | 6010 | 6020 => "program pause / filament change not acted on",
        30 | 40 | 50 => "spindle / torch / laser not acted on",
        60 => "tool change code not acted on (the T word selects the tool)",
        70..=90 => "coolant not acted on",
        170 | 180 | 840 => "motors on / off not acted on",
        730 => "progress display not acted on",
        1040 | 1090 => "hot end temperature not acted on in RS274/NGC",
        1400 | 1900 => "bed temperature not acted on in RS274/NGC",
        1050 => "temperature report: nothing to do",
        1080 | 1160 => "M108 / M116 (cancel heating, wait for all heaters) not acted on: M109/M190 wait in the job",
        1410 | 1910 => "chamber temperature not acted on",
        1060 | 1070 => "fan not acted on",
        1170 | 1180 => "message (free text) not acted on",
        4000 => "wait for moves to finish: nothing to do (segments run in order)",
        4860 => "object label (cancel objects) not acted on",
        _ => "M-code not acted on",
    }
}
