//! KUKA RSI (Robot Sensor Interface, KR C4/C5) as a [`RobotProtocol`]: XML over UDP. Every cycle the
//! robot sends
//!
//! ```xml
//! <Rob TYPE="KUKA"><RIst X=".." Y=".." Z=".." A=".." B=".." C=".."/><RSol .../>
//!   <AIPos A1=".." A2=".." A3=".." A4=".." A5=".." A6=".."/><ASPos .../>
//!   <EIPos E1=".." E2=".." E3=".." E4=".." E5=".." E6=".."/><Delay D="0"/>
//!   <IPOC>4208146</IPOC></Rob>
//! ```
//!
//! (`AIPos`: the arm's actual axes in degrees; `EIPos`: the actual external axes, degrees for a
//! rotary axis and millimetres for a linear one, sent when the ETHERNET object's SEND list has
//! `DEF_EIPos`; `IPOC`: the controller's cycle stamp, in ms) and the sensor must answer within the
//! cycle, echoing the `IPOC`:
//!
//! ```xml
//! <Sen Type="ImFree"><AK A1=".." A2=".." A3=".." A4=".." A5=".." A6=".." /><EK E1=".." /><IPOC>4208146</IPOC></Sen>
//! ```
//!
//! `AK` is the total axis correction in degrees from the axes of the first packet (`RSI_ON(#ABSOLUTE)`
//! with an AXISCORR object, as ros-industrial's `kuka_rsi_hw_interface` and KUKA's external-control
//! SDK use it): the first packet sets the reference, and a reply of all zeros holds the robot where
//! it started. `EK` is the same for the external axes (an AXISCORREXT object fed by the ETHERNET
//! object's `EK.E1`.. outputs): the correction from the first packet's `EIPos`, degrees or mm. The
//! reply's `Type` must match `SENTYPE` of the RSI ETHERNET object
//! (`config/drivers/rsi/strand_rsi_ethernet.xml`). The robot's root element may spell its attribute
//! `TYPE` or `Type`, put attributes in any order and add elements (`Tech`, `GPIO`); only `AIPos`,
//! `EIPos` (for the cell's external axes) and `IPOC` are read.
//!
//! External axes: the cell's joints after the arm's six (a positioner's, in chain order) are E1,
//! E2, … ([`RobotProtocol::set_linear_axes`] says how many, and which are linear: a track, metres here and
//! millimetres on the wire). The element and attribute names, the units and the correction's
//! reference are those of KUKA's own public external-control SDK (github.com/kroshu/
//! kuka-external-control-sdk: `kss/src/message_builder.cc` reads `EIPos` `E1`.. for external joints
//! — degrees → rad, mm → m by the joint's type — and writes the command's external joints as `EK`
//! `E1`.. — (command − first packet's position), rad → degrees, m → mm; its
//! `krc_setup/.../rsi_ext_axis_ethernet.xml` sends `DEF_EIPos` and receives `EK.E1`, and its
//! `rsi_ext_axis_example.rsix` wires that input to an `AxisCorrExt` object, beside `AxisCorr` for
//! `AK`). A packet without `EIPos`, or without the attribute of a configured external axis, is
//! refused naming the axis. Unsure, not confirmed from a public source: whether an endless rotary
//! axis's `EIPos` wraps (read here as the controller sends it), and KR C2's linear axes, which a
//! ros-industrial user saw in mm·180/π (kuka_experimental issue #100; KR C4 and KSS 8 use mm).
//! The notes, with the robot's side: `docs/protocols/external-axes.md`.
//!
//! The extruder ([`RobotProtocol::set_extruder_output`], `[driver] extruder_tag`): the answer also
//! carries the extruder's command as RECEIVE tags of the ETHERNET object — an analog value in
//! volts from the volumetric flow and a 0/1 enable — in the same packet as `AK`, which the RSI
//! context maps to `$ANOUT[n]` and `$OUT[n]` (`config/drivers/rsi/`). A tag `Element.Attribute`
//! is written `<Element Attribute="…" />` (two tags of one element share it), a tag `Element`
//! `<Element>…</Element>`: the two forms of RSI's tags, as in `AK.A1` and `IPOC`.

use quick_xml::Reader;
use quick_xml::events::{BytesStart, Event};
use strand_ipc::MAX_JOINTS;

use crate::protocol::{Channel, Clock, ExtruderOutput, PacketError, RobotPacket, RobotProtocol};

/// Axes RSI streams for the robot arm (A1..A6).
pub const AXES: usize = 6;

/// External axes RSI can carry (E1..E6); the wire's joint arrays hold `MAX_JOINTS` − [`AXES`] of
/// them.
pub const EXTERNAL_AXES: usize = 6;

/// The RSI side of one connection: the reference axes the corrections are relative to.
#[derive(Clone, Debug, Default)]
pub struct Rsi {
    reference: Option<[f64; MAX_JOINTS]>,
    /// The newest packet's `IPOC`, which the answer echoes.
    ipoc: u64,
    /// The cell's external axes (E1.., after A1..A6).
    external: usize,
    /// Which of the cell's axes are linear (mm on the wire, m here); only external ones can be.
    linear: [bool; MAX_JOINTS],
    /// The extruder's outputs, and their values for the next answer (V, enable).
    extruder: Option<(ExtruderOutput, Tag, Option<Tag>)>,
    extruder_signal: (f64, bool),
}

/// An RSI RECEIVE tag: `Element.Attribute` or `Element`.
#[derive(Clone, Debug, PartialEq)]
struct Tag {
    element: String,
    attribute: Option<String>,
}

impl Tag {
    /// Parses `text`, refusing what RSI's XML cannot name and strand's own elements.
    fn parse(text: &str, key: &str) -> Result<Tag, String> {
        let name_ok =
            |n: &str| n.chars().next().is_some_and(|c| c.is_ascii_alphabetic()) && n.chars().all(|c| c.is_ascii_alphanumeric() || c == '_');
        let (element, attribute) = match text.split_once('.') {
            Some((e, a)) => (e, Some(a)),
            None => (text, None),
        };
        if !name_ok(element) || attribute.is_some_and(|a| !name_ok(a)) {
            return Err(format!(
                "[driver] {key} = {text:?}: an RSI tag is Element.Attribute or Element (letters, digits, _), e.g. \"Extruder.Volt\""
            ));
        }
        if ["AK", "EK", "IPOC", "Sen"].contains(&element) {
            return Err(format!("[driver] {key} = {text:?}: <{element}> is strand-rsi's own element; name another"));
        }
        Ok(Tag { element: element.to_string(), attribute: attribute.map(str::to_string) })
    }
}

impl Rsi {
    /// A connection that has not seen its first packet, for an arm without external axes (the
    /// driver sets the cell's with [`RobotProtocol::set_linear_axes`]).
    pub fn new() -> Rsi {
        Rsi::default()
    }

    /// The axes of the first packet (rad, or m for a linear external axis), which `AK` and `EK`
    /// are relative to.
    pub fn reference(&self) -> Option<&[f64; MAX_JOINTS]> {
        self.reference.as_ref()
    }

    /// The external axes the answers carry (E1..).
    pub fn external_axes(&self) -> usize {
        self.external
    }
}

/// Reads the attributes `<letter>1`..`<letter><count>` of `e` (element `element`: `AIPos` or
/// `EIPos`) into `axes`, as sent (degrees or mm); other attributes (an external axis the cell does
/// not have) are ignored, whatever they hold.
fn attr_axes(e: &BytesStart, element: &str, letter: u8, count: usize, axes: &mut [Option<f64>; 6]) -> Result<(), PacketError> {
    for a in e.attributes() {
        let a = a.map_err(|err| PacketError::Malformed(format!("{element} attribute: {err}")))?;
        let key = a.key.as_ref();
        if key.len() == 2 && key[0] == letter && (b'1'..=b'6').contains(&key[1]) && usize::from(key[1] - b'1') < count {
            let k = usize::from(key[1] - b'1');
            let name = format!("{element} {}{}", letter as char, k + 1);
            let text = std::str::from_utf8(&a.value).map_err(|_| PacketError::Malformed(format!("{name}: not UTF-8")))?;
            let v: f64 = text.trim().parse().map_err(|_| PacketError::BadValue(format!("{name}: {text:?} is not a number")))?;
            if !v.is_finite() {
                return Err(PacketError::BadValue(format!("{name}: {v}")));
            }
            axes[k] = Some(v);
        }
    }
    Ok(())
}

/// The axes of one packet as sent, before they are checked and converted.
#[derive(Default)]
struct Read {
    axes: [Option<f64>; AXES],
    external: [Option<f64>; EXTERNAL_AXES],
    /// Whether the packet had an `EIPos` element at all.
    eipos: bool,
}

impl Read {
    /// Reads `e` if it is `AIPos`, or `EIPos` (its first `external` axes).
    fn element(&mut self, e: &BytesStart, external: usize) -> Result<(), PacketError> {
        match e.name().as_ref() {
            b"AIPos" => attr_axes(e, "AIPos", b'A', AXES, &mut self.axes),
            b"EIPos" => {
                self.eipos = true;
                attr_axes(e, "EIPos", b'E', external, &mut self.external)
            }
            _ => Ok(()),
        }
    }
}

/// Writes `value` under `tag`: `<Element Attribute="value" />` or `<Element>value</Element>`.
fn write_tag(out: &mut Vec<u8>, tag: &Tag, value: std::fmt::Arguments) {
    use std::io::Write;
    let _ = match &tag.attribute {
        Some(a) => write!(out, "<{} {a}=\"{value}\" />", tag.element),
        None => write!(out, "<{0}>{value}</{0}>", tag.element),
    };
}

/// An axis on the wire (degrees, or mm when linear) in the driver's units (rad, or m).
fn from_wire(v: f64, linear: bool) -> f64 {
    if linear { v * 1e-3 } else { v.to_radians() }
}

/// A correction in the driver's units (rad, or m) on the wire (degrees, or mm when linear).
fn to_wire(v: f64, linear: bool) -> f64 {
    if linear { v * 1e3 } else { v.to_degrees() }
}

impl RobotProtocol for Rsi {
    const NAME: &'static str = "rsi";
    const CLOCK: Clock = Clock::Robot;
    const CHANNEL: Channel = Channel::Datagram;
    /// A KR C4 packet with every element is about 700 bytes; 4 KiB leaves room for extra sensor
    /// elements the RSI XML may add.
    const MAX_PACKET: usize = 4096;

    /// `IPOC` is the controller's clock in ms: a cycle is `period` of it.
    fn cycles_between(earlier: u64, later: u64, period: f64) -> u64 {
        let ms = (period * 1e3).max(1e-3);
        (later.saturating_sub(earlier) as f64 / ms).round() as u64
    }

    /// A1..A6 are the arm's rotary axes (degrees); the cell's joints after them are its external
    /// axes E1.. (a positioner's or a track's, in chain order), rotary in degrees or linear in mm.
    /// A prismatic joint among the arm's six, or fewer than six joints, is refused.
    fn set_linear_axes(&mut self, linear: &[bool]) -> Result<(), String> {
        if linear.len() < AXES {
            return Err(format!("{} joints, but RSI streams a KUKA arm's six axes A1..A6", linear.len()));
        }
        if let Some(k) = linear.iter().take(AXES).position(|l| *l) {
            return Err(format!(
                "joint {} is prismatic, but RSI's A1..A6 are rotary (degrees); a linear axis (a track) comes after them, as an external axis (E1..E6, mm)",
                k + 1
            ));
        }
        let external = linear.len() - AXES;
        if linear.len() > MAX_JOINTS || external > EXTERNAL_AXES {
            return Err(format!(
                "the arm's six axes and {external} external axes: a joint command carries {MAX_JOINTS} joints, so at most {} external axes",
                MAX_JOINTS - AXES
            ));
        }
        self.external = external;
        self.linear = [false; MAX_JOINTS];
        self.linear[..linear.len()].copy_from_slice(linear);
        Ok(())
    }

    fn read(&mut self, packet: &[u8]) -> Result<RobotPacket, PacketError> {
        if packet.len() > Self::MAX_PACKET {
            return Err(PacketError::Oversized(packet.len()));
        }
        let mut reader = Reader::from_reader(packet);
        let mut r = Read::default();
        let (mut root, mut ipoc, mut in_ipoc, mut depth) = (false, None, false, 0usize);
        loop {
            match reader.read_event() {
                Ok(Event::Start(e)) => {
                    if depth == 0 {
                        if e.name().as_ref() != b"Rob" {
                            return Err(PacketError::Malformed(format!(
                                "root <{}>, not <Rob>",
                                String::from_utf8_lossy(e.name().as_ref())
                            )));
                        }
                        root = true;
                    } else if depth == 1 && e.name().as_ref() == b"IPOC" {
                        in_ipoc = true;
                    } else if depth == 1 {
                        r.element(&e, self.external)?;
                    }
                    depth += 1;
                }
                Ok(Event::Empty(e)) => {
                    if depth == 1 {
                        r.element(&e, self.external)?;
                    } else if depth == 0 {
                        return Err(PacketError::Malformed("an empty root element".into()));
                    }
                }
                Ok(Event::Text(t)) if in_ipoc => {
                    let text = std::str::from_utf8(&t).map_err(|_| PacketError::Malformed("IPOC: not UTF-8".into()))?;
                    ipoc = Some(
                        text.trim().parse::<u64>().map_err(|_| PacketError::BadValue(format!("IPOC {text:?} is not a whole number")))?,
                    );
                }
                Ok(Event::End(_)) => {
                    in_ipoc = false;
                    depth = depth.saturating_sub(1);
                    if depth == 0 && root {
                        break;
                    }
                }
                Ok(Event::Eof) => {
                    return Err(if root {
                        PacketError::Truncated("the packet ends inside <Rob>".into())
                    } else {
                        PacketError::Malformed("no <Rob> element".into())
                    });
                }
                Ok(_) => {}
                Err(e) => return Err(PacketError::Malformed(format!("XML: {e}"))),
            }
        }
        let ipoc = ipoc.ok_or_else(|| PacketError::Truncated("no <IPOC>".into()))?;
        let mut out = [0.0; MAX_JOINTS];
        for (k, a) in r.axes.iter().enumerate() {
            out[k] = a.ok_or_else(|| PacketError::Truncated(format!("no AIPos A{}", k + 1)))?.to_radians();
        }
        for (i, e) in r.external.iter().take(self.external).enumerate() {
            let k = AXES + i;
            let Some(v) = e else {
                return Err(PacketError::Truncated(if r.eipos {
                    format!("no EIPos E{}: the cell's external axis {} (joint {})", i + 1, i + 1, k + 1)
                } else {
                    format!(
                        "no EIPos: the cell has {} external axes (E1..E{}, joints 7..); the ETHERNET object must send DEF_EIPos",
                        self.external, self.external
                    )
                }));
            };
            out[k] = from_wire(*v, self.linear[k]);
        }
        if self.reference.is_none() {
            self.reference = Some(out);
        }
        self.ipoc = ipoc;
        Ok(RobotPacket { seq: ipoc, axes: out, dof: AXES + self.external, following: true })
    }

    fn reset(&mut self) {
        self.reference = None;
        self.extruder_signal = (0.0, false);
    }

    fn set_extruder_output(&mut self, output: ExtruderOutput) -> Result<(), String> {
        let tag = Tag::parse(&output.tag, "extruder_tag")?;
        let enable = if output.enable_tag.is_empty() { None } else { Some(Tag::parse(&output.enable_tag, "extruder_enable_tag")?) };
        if enable.as_ref() == Some(&tag) {
            return Err(format!("[driver] extruder_enable_tag = {:?} is extruder_tag too: each needs its own", output.enable_tag));
        }
        if enable.as_ref().is_some_and(|e| e.element == tag.element && (e.attribute.is_none() || tag.attribute.is_none())) {
            return Err(format!(
                "[driver] extruder_tag = {:?} and extruder_enable_tag = {:?}: one element holds both only as attributes (Element.A and Element.B)",
                output.tag, output.enable_tag
            ));
        }
        self.extruder_signal = output.signal(None);
        self.extruder = Some((output, tag, enable));
        Ok(())
    }

    fn wants_extruder(&self) -> bool {
        self.extruder.is_some()
    }

    fn set_extruder(&mut self, command: Option<&strand_ipc::ExtruderCommand>) {
        if let Some((output, _, _)) = &self.extruder {
            self.extruder_signal = output.signal(command);
        }
    }

    /// The corrections `AK` (the arm's, degrees) and `EK` (the external axes', degrees or mm),
    /// relative to the first packet's axes, echoing the newest packet's `IPOC`; before any
    /// packet, nothing. `EK` carries the cell's external axes only, and only those `axes` gives.
    fn write(&mut self, axes: &[f64], out: &mut Vec<u8>) {
        use std::io::Write;
        out.clear();
        let Some(reference) = self.reference else { return };
        let mut ak = [0.0; AXES];
        for k in 0..AXES.min(axes.len()) {
            ak[k] = (axes[k] - reference[k]).to_degrees();
        }
        // Six decimals of a degree (17 nrad) or of a mm, as kuka_rsi_hw_interface writes them (`%f`).
        let _ = write!(
            out,
            "<Sen Type=\"ImFree\"><AK A1=\"{:.6}\" A2=\"{:.6}\" A3=\"{:.6}\" A4=\"{:.6}\" A5=\"{:.6}\" A6=\"{:.6}\" />",
            ak[0], ak[1], ak[2], ak[3], ak[4], ak[5]
        );
        let external = self.external.min(axes.len().saturating_sub(AXES));
        if external > 0 {
            out.extend_from_slice(b"<EK");
            for i in 0..external {
                let k = AXES + i;
                let _ = write!(out, " E{}=\"{:.6}\"", i + 1, to_wire(axes[k] - reference[k], self.linear[k]));
            }
            out.extend_from_slice(b" />");
        }
        if let Some((_, tag, enable)) = &self.extruder {
            // Volts to 6 decimals (µV), the enable as 0 or 1.
            let (volts, on) = self.extruder_signal;
            match (enable, &tag.attribute) {
                // Two attributes of one element: one element.
                (Some(e), Some(a)) if e.element == tag.element => {
                    let _ = write!(
                        out,
                        "<{} {a}=\"{volts:.6}\" {}=\"{}\" />",
                        tag.element,
                        e.attribute.as_deref().unwrap_or_default(),
                        u8::from(on)
                    );
                }
                _ => {
                    write_tag(out, tag, format_args!("{volts:.6}"));
                    if let Some(e) = enable {
                        write_tag(out, e, format_args!("{}", u8::from(on)));
                    }
                }
            }
        }
        let _ = write!(out, "<IPOC>{}</IPOC></Sen>", self.ipoc);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const SAMPLE: &str = "<Rob TYPE=\"KUKA\"><RIst X=\"445.0\" Y=\"0.0\" Z=\"890.0\" A=\"180.0\" B=\"0.0\" C=\"180.0\"/>\
        <RSol X=\"445.0\" Y=\"0.0\" Z=\"890.0\" A=\"180.0\" B=\"0.0\" C=\"180.0\"/>\
        <AIPos A1=\"0.0\" A2=\"-90.0\" A3=\"90.0\" A4=\"0.0\" A5=\"90.0\" A6=\"0.0\"/>\
        <ASPos A1=\"0.0\" A2=\"-90.0\" A3=\"90.0\" A4=\"0.0\" A5=\"90.0\" A6=\"0.0\"/>\
        <EIPos E1=\"30.0\" E2=\"1250.5\" E3=\"0.0\" E4=\"0.0\" E5=\"0.0\" E6=\"0.0\"/>\
        <Delay D=\"0\"/><IPOC>4208146</IPOC></Rob>";

    /// The sample with `E1` and `IPOC` set.
    fn packet(e1: &str, ipoc: u64) -> String {
        SAMPLE.replace("E1=\"30.0\"", &format!("E1=\"{e1}\"")).replace("4208146", &ipoc.to_string())
    }

    #[test]
    fn a_robot_packet_decodes_and_the_reply_echoes_its_ipoc() {
        let mut rsi = Rsi::new();
        let p = rsi.read(SAMPLE.as_bytes()).unwrap();
        assert_eq!(p.seq, 4208146);
        assert_eq!(p.dof, 6, "no external axis configured: EIPos is not read");
        assert!((p.axes[1] + std::f64::consts::FRAC_PI_2).abs() < 1e-15);
        let mut target = p.axes;
        target[0] += 1f64.to_radians();
        let mut out = Vec::new();
        rsi.write(&target[..6], &mut out);
        let text = String::from_utf8(out).unwrap();
        assert_eq!(
            text,
            "<Sen Type=\"ImFree\"><AK A1=\"1.000000\" A2=\"0.000000\" A3=\"0.000000\" A4=\"0.000000\" A5=\"0.000000\" A6=\"0.000000\" /><IPOC>4208146</IPOC></Sen>"
        );
    }

    /// A rotary table as E1: `EIPos` degrees in, rad inside; `EK` the correction from the first
    /// packet's E1, in degrees, beside `AK`.
    #[test]
    fn a_rotary_external_axis_is_read_from_eipos_and_corrected_by_ek() {
        let mut rsi = Rsi::new();
        rsi.set_linear_axes(&[false; 7]).unwrap();
        assert_eq!(rsi.external_axes(), 1);
        let p = rsi.read(SAMPLE.as_bytes()).unwrap();
        assert_eq!(p.dof, 7);
        assert_eq!(p.axes[6], 30f64.to_radians());
        assert_eq!(p.axes[7], 0.0, "E2 is not the cell's");
        let mut target = p.axes;
        target[0] = 2f64.to_radians();
        target[6] = 40f64.to_radians();
        let mut out = Vec::new();
        rsi.write(&target[..7], &mut out);
        assert_eq!(
            String::from_utf8(out.clone()).unwrap(),
            "<Sen Type=\"ImFree\"><AK A1=\"2.000000\" A2=\"0.000000\" A3=\"0.000000\" A4=\"0.000000\" A5=\"0.000000\" A6=\"0.000000\" />\
             <EK E1=\"10.000000\" /><IPOC>4208146</IPOC></Sen>"
        );
        // A later packet: E1 read as it is; the correction stays relative to the first packet.
        let p = rsi.read(packet("35.25", 4208150).as_bytes()).unwrap();
        assert_eq!(p.axes[6], 35.25f64.to_radians());
        assert_eq!(rsi.reference().unwrap()[6], 30f64.to_radians());
        target[6] = -15.5f64.to_radians();
        rsi.write(&target[..7], &mut out);
        let text = String::from_utf8(out).unwrap();
        assert!(text.contains("<EK E1=\"-45.500000\" /><IPOC>4208150</IPOC>"), "{text}");
    }

    /// A track as E2 after a table as E1: mm on the wire, m inside; EK in mm.
    #[test]
    fn a_linear_external_axis_is_millimetres_on_the_wire() {
        let mut rsi = Rsi::new();
        let e = rsi.set_linear_axes(&[false, true, false, false, false, false, false]).unwrap_err();
        assert!(e.contains("joint 2 is prismatic"), "{e}");
        assert!(rsi.set_linear_axes(&[false; 5]).unwrap_err().contains("six axes"));
        assert!(rsi.set_linear_axes(&[false; 9]).unwrap_err().contains("at most 2 external axes"));
        rsi.set_linear_axes(&[false, false, false, false, false, false, false, true]).unwrap();
        let p = rsi.read(SAMPLE.as_bytes()).unwrap();
        assert_eq!(p.dof, 8);
        assert_eq!(p.axes[6], 30f64.to_radians());
        assert_eq!(p.axes[7], 1250.5 * 1e-3);
        let mut target = p.axes;
        target[7] = 1.5;
        let mut out = Vec::new();
        rsi.write(&target[..8], &mut out);
        let text = String::from_utf8(out).unwrap();
        assert!(text.contains("<EK E1=\"0.000000\" E2=\"249.500000\" />"), "{text}");
    }

    #[test]
    fn a_missing_external_axis_is_named() {
        let mut rsi = Rsi::new();
        rsi.set_linear_axes(&[false; 8]).unwrap();
        let no_eipos = SAMPLE.replace("<EIPos E1=\"30.0\" E2=\"1250.5\" E3=\"0.0\" E4=\"0.0\" E5=\"0.0\" E6=\"0.0\"/>", "");
        match rsi.read(no_eipos.as_bytes()) {
            Err(PacketError::Truncated(why)) => assert!(why.contains("no EIPos") && why.contains("DEF_EIPos"), "{why}"),
            other => panic!("{other:?}"),
        }
        match rsi.read(SAMPLE.replace(" E2=\"1250.5\"", "").as_bytes()) {
            Err(PacketError::Truncated(why)) => assert!(why.contains("no EIPos E2") && why.contains("joint 8"), "{why}"),
            other => panic!("{other:?}"),
        }
        match rsi.read(packet("nan", 1).as_bytes()) {
            Err(PacketError::BadValue(why)) => assert!(why.contains("EIPos E1"), "{why}"),
            other => panic!("{other:?}"),
        }
        match rsi.read(packet("x", 1).as_bytes()) {
            Err(PacketError::BadValue(why)) => assert!(why.contains("EIPos E1"), "{why}"),
            other => panic!("{other:?}"),
        }
        assert!(rsi.reference().is_none(), "no bad packet sets the reference");
        // E3 is not the cell's: whatever it holds is not read.
        assert_eq!(rsi.read(SAMPLE.replace("E3=\"0.0\"", "E3=\"x\"").as_bytes()).unwrap().dof, 8);
        rsi.reset();
        // An answer before any packet is nothing.
        let mut out = vec![1];
        rsi.write(&[0.0; 8], &mut out);
        assert!(out.is_empty());
    }

    #[test]
    fn bad_packets_are_named() {
        let mut rsi = Rsi::new();
        let cut = &SAMPLE[..SAMPLE.len() - 20];
        assert!(matches!(rsi.read(cut.as_bytes()), Err(PacketError::Truncated(_) | PacketError::Malformed(_))));
        assert!(matches!(rsi.read(b"hello"), Err(PacketError::Malformed(_))));
        assert!(matches!(rsi.read(SAMPLE.replace("A3=\"90.0\" ", "").as_bytes()), Err(PacketError::Truncated(_))));
        assert!(matches!(rsi.read(SAMPLE.replace("<IPOC>4208146</IPOC>", "").as_bytes()), Err(PacketError::Truncated(_))));
        assert!(matches!(rsi.read(SAMPLE.replace("A2=\"-90.0\"", "A2=\"nan\"").as_bytes()), Err(PacketError::BadValue(_))));
        assert!(matches!(rsi.read(SAMPLE.replace("4208146", "x").as_bytes()), Err(PacketError::BadValue(_))));
        assert!(matches!(rsi.read(&vec![b' '; 5000]), Err(PacketError::Oversized(5000))));
        assert!(matches!(rsi.read(SAMPLE.replace("Rob", "Sen").as_bytes()), Err(PacketError::Malformed(_))));
        assert!(rsi.reference().is_none(), "no bad packet sets the reference");
    }

    fn output(tag: &str, enable: &str) -> ExtruderOutput {
        ExtruderOutput {
            tag: tag.into(),
            enable_tag: enable.into(),
            volts_per_flow: 0.5,
            volts_offset: 0.25,
            volts_min: 0.0,
            volts_max: 10.0,
        }
    }

    fn extruding(mm3_s: f64) -> strand_ipc::ExtruderCommand {
        strand_ipc::ExtruderCommand { volumetric_rate: mm3_s * 1e-9, flags: strand_ipc::extruder_flags::EXTRUDING, ..Default::default() }
    }

    /// The extruder's command rides in the answer after `AK`: volts = offset + gain × mm³/s,
    /// clamped, and the enable while extruding; two attributes of one element share it, other
    /// tags are elements of their own; a hold (None) sends the offset, disabled.
    #[test]
    fn the_extruders_command_rides_in_the_answer_as_rsi_tags() {
        let mut rsi = Rsi::new();
        rsi.set_extruder_output(output("Extruder.Volt", "Extruder.On")).unwrap();
        assert!(rsi.wants_extruder());
        rsi.read(SAMPLE.as_bytes()).unwrap();
        let mut out = Vec::new();
        rsi.set_extruder(Some(&extruding(7.5)));
        rsi.write(&[0.0; 6], &mut out);
        let text = String::from_utf8(out.clone()).unwrap();
        assert!(text.contains("/><Extruder Volt=\"4.000000\" On=\"1\" /><IPOC>4208146</IPOC></Sen>"), "{text}");
        rsi.set_extruder(Some(&extruding(1000.0)));
        rsi.write(&[0.0; 6], &mut out);
        assert!(String::from_utf8_lossy(&out).contains("Volt=\"10.000000\" On=\"1\""), "clamped to 10 V");
        let mut retract = extruding(-3.0);
        retract.flags = strand_ipc::extruder_flags::RETRACTED;
        rsi.set_extruder(Some(&retract));
        rsi.write(&[0.0; 6], &mut out);
        assert!(String::from_utf8_lossy(&out).contains("Volt=\"0.000000\" On=\"0\""), "a retraction clamps to the minimum, disabled");
        rsi.set_extruder(None);
        rsi.write(&[0.0; 6], &mut out);
        assert!(String::from_utf8_lossy(&out).contains("Volt=\"0.250000\" On=\"0\""), "a hold: the offset, disabled");
        // Other spellings: an element's text, two elements.
        let mut rsi = Rsi::new();
        rsi.set_extruder_output(output("AnOut", "DigOut.O1")).unwrap();
        rsi.read(SAMPLE.as_bytes()).unwrap();
        rsi.set_extruder(Some(&extruding(2.0)));
        rsi.write(&[0.0; 6], &mut out);
        let text = String::from_utf8(out).unwrap();
        assert!(text.contains("<AnOut>1.250000</AnOut><DigOut O1=\"1\" /><IPOC>"), "{text}");
    }

    #[test]
    fn extruder_tags_rsi_cannot_name_are_refused_naming_the_key() {
        for (tag, enable, said) in [
            ("", "", "extruder_tag = \"\""),
            ("1Volt", "", "extruder_tag"),
            ("Ex.Volt.x", "", "extruder_tag"),
            ("AK.A7", "", "strand-rsi's own element"),
            ("Extruder.Volt", "IPOC", "strand-rsi's own element"),
            ("Extruder.Volt", "Extruder.Volt", "each needs its own"),
            ("Extruder", "Extruder.On", "only as attributes"),
        ] {
            let e = Rsi::new().set_extruder_output(output(tag, enable)).unwrap_err();
            assert!(e.contains(said), "{tag:?} {enable:?}: {e}");
        }
    }
}
