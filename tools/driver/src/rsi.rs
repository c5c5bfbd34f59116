//! KUKA RSI (Robot Sensor Interface, KR C4/C5) as a [`RobotProtocol`]: XML over UDP. Every cycle the
//! robot sends
//!
//! ```xml
//! <Rob TYPE="KUKA"><RIst X=".." Y=".." Z=".." A=".." B=".." C=".."/><RSol .../>
//!   <AIPos A1=".." A2=".." A3=".." A4=".." A5=".." A6=".."/><ASPos .../><Delay D="0"/>
//!   <IPOC>4208146</IPOC></Rob>
//! ```
//!
//! (`AIPos`: the actual axes in degrees; `IPOC`: the controller's cycle stamp, in ms) and the
//! sensor must answer within the cycle, echoing the `IPOC`:
//!
//! ```xml
//! <Sen Type="ImFree"><AK A1=".." A2=".." A3=".." A4=".." A5=".." A6=".." /><IPOC>4208146</IPOC></Sen>
//! ```
//!
//! `AK` is the total axis correction in degrees from the axes of the first packet (`RSI_ON(#ABSOLUTE)`
//! with an AXISCORR object, as ros-industrial's `kuka_rsi_hw_interface` and KUKA's external-control
//! SDK use it): the first packet sets the reference, and a reply of all zeros holds the robot where
//! it started. The reply's `Type` must match `SENTYPE` of the RSI ETHERNET object
//! (`config/drivers/rsi/strand_rsi.xml`). The robot's root element may spell its attribute `TYPE` or
//! `Type`, put attributes in any order and add elements (`EIPos`, `Tech`); only `AIPos` and `IPOC`
//! are read.

use quick_xml::Reader;
use quick_xml::events::{BytesStart, Event};
use strand_ipc::MAX_JOINTS;

use crate::protocol::{Channel, Clock, PacketError, RobotPacket, RobotProtocol};

/// Axes RSI streams for the robot arm (A1..A6).
pub const AXES: usize = 6;

/// The RSI side of one connection: the reference axes the corrections are relative to.
#[derive(Clone, Debug, Default)]
pub struct Rsi {
    reference: Option<[f64; MAX_JOINTS]>,
    /// The newest packet's `IPOC`, which the answer echoes.
    ipoc: u64,
}

impl Rsi {
    /// A connection that has not seen its first packet.
    pub fn new() -> Rsi {
        Rsi::default()
    }

    /// The axes of the first packet (rad), which `AK` is relative to.
    pub fn reference(&self) -> Option<&[f64; MAX_JOINTS]> {
        self.reference.as_ref()
    }
}

fn attr_axes(e: &BytesStart, axes: &mut [Option<f64>; AXES]) -> Result<(), PacketError> {
    for a in e.attributes() {
        let a = a.map_err(|err| PacketError::Malformed(format!("AIPos attribute: {err}")))?;
        let key = a.key.as_ref();
        if key.len() == 2 && key[0] == b'A' && (b'1'..=b'6').contains(&key[1]) {
            let k = (key[1] - b'1') as usize;
            let text = std::str::from_utf8(&a.value).map_err(|_| PacketError::Malformed("AIPos: not UTF-8".into()))?;
            let v: f64 = text.trim().parse().map_err(|_| PacketError::BadValue(format!("AIPos A{}: {text:?} is not a number", k + 1)))?;
            if !v.is_finite() {
                return Err(PacketError::BadValue(format!("AIPos A{}: {v}", k + 1)));
            }
            axes[k] = Some(v);
        }
    }
    Ok(())
}

impl RobotProtocol for Rsi {
    const NAME: &'static str = "rsi";
    const CLOCK: Clock = Clock::Robot;
    const CHANNEL: Channel = Channel::Datagram;
    /// A KR C4 packet with every element is about 600 bytes; 4 KiB leaves room for extra sensor
    /// elements the RSI XML may add.
    const MAX_PACKET: usize = 4096;

    /// `IPOC` is the controller's clock in ms: a cycle is `period` of it.
    fn cycles_between(earlier: u64, later: u64, period: f64) -> u64 {
        let ms = (period * 1e3).max(1e-3);
        (later.saturating_sub(earlier) as f64 / ms).round() as u64
    }

    /// A1..A6 are the arm's rotary axes (degrees); the external axes (`EIPos`, E1..E6, where a
    /// linear track would be) are not streamed by this driver, so no axis can be linear.
    fn set_linear_axes(&mut self, linear: &[bool]) -> Result<(), String> {
        match linear.iter().position(|l| *l) {
            Some(k) => Err(format!(
                "joint {} is prismatic, but RSI's A1..A6 are rotary (degrees) and external axes (E1..E6) are not streamed",
                k + 1
            )),
            None => Ok(()),
        }
    }

    fn read(&mut self, packet: &[u8]) -> Result<RobotPacket, PacketError> {
        if packet.len() > Self::MAX_PACKET {
            return Err(PacketError::Oversized(packet.len()));
        }
        let mut reader = Reader::from_reader(packet);
        let (mut root, mut axes, mut ipoc, mut in_ipoc, mut depth) = (false, [None; AXES], None, false, 0usize);
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
                    } else if depth == 1 && e.name().as_ref() == b"AIPos" {
                        attr_axes(&e, &mut axes)?;
                    }
                    depth += 1;
                }
                Ok(Event::Empty(e)) => {
                    if depth == 1 && e.name().as_ref() == b"AIPos" {
                        attr_axes(&e, &mut axes)?;
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
        for (k, a) in axes.iter().enumerate() {
            out[k] = a.ok_or_else(|| PacketError::Truncated(format!("no AIPos A{}", k + 1)))?.to_radians();
        }
        if self.reference.is_none() {
            self.reference = Some(out);
        }
        self.ipoc = ipoc;
        Ok(RobotPacket { seq: ipoc, axes: out, dof: AXES, following: true })
    }

    fn reset(&mut self) {
        self.reference = None;
    }

    /// The correction `AK` (relative to the first packet's axes, degrees), echoing the newest
    /// packet's `IPOC`; before any packet, nothing.
    fn write(&mut self, axes: &[f64], out: &mut Vec<u8>) {
        use std::io::Write;
        out.clear();
        let Some(reference) = self.reference else { return };
        let mut ak = [0.0; AXES];
        for k in 0..AXES.min(axes.len()) {
            ak[k] = (axes[k] - reference[k]).to_degrees();
        }
        // Six decimals of a degree (17 nrad), as kuka_rsi_hw_interface writes them (`%f`).
        let _ = write!(
            out,
            "<Sen Type=\"ImFree\"><AK A1=\"{:.6}\" A2=\"{:.6}\" A3=\"{:.6}\" A4=\"{:.6}\" A5=\"{:.6}\" A6=\"{:.6}\" /><IPOC>{}</IPOC></Sen>",
            ak[0], ak[1], ak[2], ak[3], ak[4], ak[5], self.ipoc
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const SAMPLE: &str = "<Rob TYPE=\"KUKA\"><RIst X=\"445.0\" Y=\"0.0\" Z=\"890.0\" A=\"180.0\" B=\"0.0\" C=\"180.0\"/>\
        <RSol X=\"445.0\" Y=\"0.0\" Z=\"890.0\" A=\"180.0\" B=\"0.0\" C=\"180.0\"/>\
        <AIPos A1=\"0.0\" A2=\"-90.0\" A3=\"90.0\" A4=\"0.0\" A5=\"90.0\" A6=\"0.0\"/>\
        <ASPos A1=\"0.0\" A2=\"-90.0\" A3=\"90.0\" A4=\"0.0\" A5=\"90.0\" A6=\"0.0\"/>\
        <Delay D=\"0\"/><IPOC>4208146</IPOC></Rob>";

    #[test]
    fn a_robot_packet_decodes_and_the_reply_echoes_its_ipoc() {
        let mut rsi = Rsi::new();
        let p = rsi.read(SAMPLE.as_bytes()).unwrap();
        assert_eq!(p.seq, 4208146);
        assert_eq!(p.dof, 6);
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
}
