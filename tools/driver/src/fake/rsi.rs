//! A KUKA KR C4 with an RSI ETHERNET object, as far as the wire shows it: every cycle a
//! `<Rob TYPE="KUKA">` packet with the Cartesian actual and setpoint (`RIst`, `RSol`; not computed
//! here, a fixed pose), the actual and setpoint axes (`AIPos`, `ASPos`, degrees, four decimals as
//! the ETHERNET object's `Precision=4` sends them), the actual external axes (`EIPos E1..`, degrees
//! for a rotary axis, mm for a linear one; only on a controller with external axes, whose SEND
//! list has `DEF_EIPos`), the late-packet count (`Delay`) and the cycle stamp `IPOC` (ms, stepping
//! by the cycle); the answer must be `<Sen Type="ImFree">` with `<AK A1..A6>` (degrees, the
//! correction from the axes at the start, `RSI_ON(#ABSOLUTE)`), with `<EK E1..>` for the external
//! axes (the same correction, through an AXISCORREXT object: degrees or mm from the start), and
//! the same `IPOC`. Written from KUKA's public external-control SDK's description of the external
//! axes (`rsi_ext_axis_ethernet.xml`: `DEF_EIPos` sent, `EK.E1` received), not from the driver.
//!
//! RECEIVE tags beyond `AK`/`EK` ([`FakeRsi::outputs`]: an analog and a digital output, as a cell
//! wires the extruder): as the ETHERNET object reads them, `Element.Attribute` is an attribute
//! and `Element` an element's text, each a number; the values of every answer taken in time are
//! recorded with the cycle, as the controller would set `$ANOUT`/`$OUT` from them.

use std::sync::{Arc, Mutex};

use quick_xml::Reader;
use quick_xml::events::Event;

use super::FakeProtocol;

/// Arm axes A1..A6.
const ARM: usize = 6;

/// External axes E1..E6 a KR C4 drives at most.
const MAX_EXTERNAL: usize = 6;

/// The fake KR C4's RSI side.
pub struct FakeRsi {
    /// `IPOC` of cycle 0 (ms).
    pub ipoc0: u64,
    /// The cycle (ms).
    pub period_ms: u64,
    /// Axes at `RSI_ON` (degrees, or mm for a linear external axis): A1..A6, then E1..; `AK` and
    /// `EK` are relative to them.
    pub start_deg: Vec<f64>,
    /// External axes the controller has (E1..): it sends them in `EIPos` and takes `EK` for them.
    pub external_axes: usize,
    /// Answers that came after their cycle so far (the controller's `Delay`).
    pub delay: u64,
    /// Extra RECEIVE tags (`Element.Attribute` or `Element`) whose values it records.
    pub outputs: Vec<String>,
    /// Per answer taken in time: its cycle and the values of `outputs` (None: absent or not a
    /// number).
    pub received: Arc<Mutex<Vec<OutputValues>>>,
}

/// One answer's output tags: its cycle, and each tag's value (None: absent or not a number).
pub type OutputValues = (u64, Vec<Option<f64>>);

impl FakeRsi {
    /// A controller whose RSI starts at `start_deg` (A1..A6, then one value per external axis,
    /// E1.., at most six), cycling every `period_ms`.
    pub fn new(start_deg: &[f64], period_ms: u64) -> FakeRsi {
        let external_axes = start_deg.len().saturating_sub(ARM).min(MAX_EXTERNAL);
        FakeRsi {
            ipoc0: 1_000_000,
            period_ms,
            start_deg: start_deg.to_vec(),
            external_axes,
            delay: 0,
            outputs: Vec::new(),
            received: Arc::default(),
        }
    }
}

/// Reads the attributes `<letter>1`..`<letter>6` of an element into `into` (None where absent or
/// not a number).
fn attributes(e: &quick_xml::events::BytesStart, letter: u8, into: &mut [Option<f64>; 6]) {
    for at in e.attributes().flatten() {
        let key = at.key.as_ref();
        if key.len() == 2 && key[0] == letter && (b'1'..=b'6').contains(&key[1]) {
            into[usize::from(key[1] - b'1')] = std::str::from_utf8(&at.value).ok().and_then(|s| s.trim().parse().ok());
        }
    }
}

impl FakeProtocol for FakeRsi {
    fn packet(&mut self, k: u64, axes: &[f64], out: &mut Vec<u8>) {
        let a = |i: usize| axes.get(i).copied().unwrap_or(0.0);
        let axes_xml =
            format!("A1=\"{:.4}\" A2=\"{:.4}\" A3=\"{:.4}\" A4=\"{:.4}\" A5=\"{:.4}\" A6=\"{:.4}\"", a(0), a(1), a(2), a(3), a(4), a(5));
        let external_xml = if self.external_axes > 0 {
            let e: Vec<String> = (0..self.external_axes).map(|i| format!("E{}=\"{:.4}\"", i + 1, a(ARM + i))).collect();
            format!("<EIPos {}/>\r\n", e.join(" "))
        } else {
            String::new()
        };
        let text = format!(
            "<Rob TYPE=\"KUKA\">\r\n<RIst X=\"445.0000\" Y=\"0.0000\" Z=\"810.0000\" A=\"180.0000\" B=\"0.0000\" C=\"180.0000\"/>\r\n\
             <RSol X=\"445.0000\" Y=\"0.0000\" Z=\"810.0000\" A=\"180.0000\" B=\"0.0000\" C=\"180.0000\"/>\r\n\
             <AIPos {axes_xml}/>\r\n<ASPos {axes_xml}/>\r\n{external_xml}<Delay D=\"{}\"/>\r\n<IPOC>{}</IPOC>\r\n</Rob>\r\n",
            self.delay,
            self.ipoc0 + k * self.period_ms
        );
        out.clear();
        out.extend_from_slice(text.as_bytes());
    }

    fn answer(&mut self, k: u64, bytes: &[u8], axes: &mut [f64]) -> Result<(), Option<u64>> {
        let mut reader = Reader::from_reader(bytes);
        let (mut sen, mut ak, mut ek, mut ipoc, mut in_ipoc) = (false, [None::<f64>; 6], [None::<f64>; 6], None::<u64>, false);
        let mut values = vec![None::<f64>; self.outputs.len()];
        // The element whose text is an `outputs` tag's value, while inside it.
        let mut in_output: Option<usize> = None;
        let number = |v: &[u8]| std::str::from_utf8(v).ok().and_then(|s| s.trim().parse::<f64>().ok());
        loop {
            match reader.read_event() {
                Ok(Event::Start(e)) if e.name().as_ref() == b"Sen" => {
                    sen = e.attributes().flatten().any(|a| a.key.as_ref() == b"Type" && a.value.as_ref() == b"ImFree");
                }
                Ok(Event::Start(e)) if e.name().as_ref() == b"IPOC" => in_ipoc = true,
                Ok(Event::Start(e) | Event::Empty(e)) if e.name().as_ref() == b"AK" => attributes(&e, b'A', &mut ak),
                Ok(Event::Start(e) | Event::Empty(e)) if e.name().as_ref() == b"EK" => attributes(&e, b'E', &mut ek),
                Ok(ref event @ (Event::Start(ref e) | Event::Empty(ref e))) => {
                    for (i, tag) in self.outputs.iter().enumerate() {
                        match tag.split_once('.') {
                            Some((element, attribute)) if e.name().as_ref() == element.as_bytes() => {
                                if let Some(a) = e.attributes().flatten().find(|a| a.key.as_ref() == attribute.as_bytes()) {
                                    values[i] = number(&a.value);
                                }
                            }
                            None if e.name().as_ref() == tag.as_bytes() && matches!(event, Event::Start(_)) => in_output = Some(i),
                            _ => {}
                        }
                    }
                }
                Ok(Event::Text(t)) if in_ipoc => {
                    ipoc = std::str::from_utf8(&t).ok().and_then(|s| s.trim().parse().ok());
                    in_ipoc = false;
                }
                Ok(Event::Text(t)) if in_output.is_some() => {
                    if let Some(i) = in_output.take() {
                        values[i] = number(&t);
                    }
                }
                Ok(Event::End(_)) => in_output = None,
                Ok(Event::Eof) => break,
                Err(_) => return Err(None),
                Ok(_) => {}
            }
        }
        let (true, Some(ipoc)) = (sen, ipoc) else { return Err(None) };
        let expected = self.ipoc0 + k * self.period_ms;
        if ipoc != expected {
            self.delay += 1;
            return Err(Some(ipoc.saturating_sub(self.ipoc0) / self.period_ms.max(1)));
        }
        // Every axis the controller has needs its correction: A1..A6, and E1.. for its external
        // axes (a correction the sensor leaves out is no answer here).
        let needed = ak.iter().chain(ek.iter().take(self.external_axes));
        if needed.clone().any(|v| v.is_none_or(|x| !x.is_finite())) {
            return Err(None);
        }
        for (i, c) in needed.enumerate() {
            if let (Some(a), Some(start)) = (axes.get_mut(i), self.start_deg.get(i)) {
                *a = start + c.unwrap_or(0.0);
            }
        }
        if !self.outputs.is_empty() {
            self.received.lock().unwrap_or_else(|e| e.into_inner()).push((k, values));
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The fake's own wire, checked by hand: `EIPos` with as many axes as it has, `EK` applied to
    /// them like `AK` to A1..A6.
    #[test]
    fn the_external_axes_are_sent_and_corrected() {
        let mut fake = FakeRsi::new(&[0.0, -90.0, 90.0, 0.0, 90.0, 0.0, 15.0], 4);
        assert_eq!(fake.external_axes, 1);
        let mut out = Vec::new();
        fake.packet(0, &[0.0, -90.0, 90.0, 0.0, 90.0, 0.0, 15.0], &mut out);
        let text = String::from_utf8(out.clone()).unwrap();
        assert!(text.contains("<EIPos E1=\"15.0000\"/>"), "{text}");
        let mut axes = vec![0.0; 7];
        let answer = "<Sen Type=\"ImFree\"><AK A1=\"1.5\" A2=\"0\" A3=\"0\" A4=\"0\" A5=\"0\" A6=\"0\" /><EK E1=\"-20.25\" /><IPOC>1000000</IPOC></Sen>";
        fake.answer(0, answer.as_bytes(), &mut axes).unwrap();
        assert_eq!(axes, [1.5, -90.0, 90.0, 0.0, 90.0, 0.0, -5.25]);
        // Without EK for E1: no answer.
        let without = answer.replace("<EK E1=\"-20.25\" />", "");
        assert_eq!(fake.answer(0, without.as_bytes(), &mut axes), Err(None));
        // An arm alone sends no EIPos and needs no EK.
        let mut arm = FakeRsi::new(&[0.0; 6], 4);
        arm.packet(0, &[0.0; 6], &mut out);
        assert!(!String::from_utf8_lossy(&out).contains("EIPos"));
        let mut axes = vec![0.0; 6];
        arm.answer(0, without.as_bytes(), &mut axes).unwrap();
        assert_eq!(axes[0], 1.5);
    }

    /// Output tags as the ETHERNET object reads them: an attribute, or an element's text.
    #[test]
    fn output_tags_are_recorded_per_answer() {
        let mut fake = FakeRsi::new(&[0.0; 6], 4);
        fake.outputs = vec!["Extruder.Volt".into(), "Extruder.On".into(), "Flow".into()];
        let mut axes = vec![0.0; 6];
        let ak = "<AK A1=\"0\" A2=\"0\" A3=\"0\" A4=\"0\" A5=\"0\" A6=\"0\" />";
        let answer = format!("<Sen Type=\"ImFree\">{ak}<Extruder Volt=\"2.5\" On=\"1\" /><Flow>7.25</Flow><IPOC>1000000</IPOC></Sen>");
        fake.answer(0, answer.as_bytes(), &mut axes).unwrap();
        let without = format!("<Sen Type=\"ImFree\">{ak}<IPOC>1000004</IPOC></Sen>");
        fake.answer(1, without.as_bytes(), &mut axes).unwrap();
        let received = fake.received.lock().unwrap().clone();
        assert_eq!(received, vec![(0, vec![Some(2.5), Some(1.0), Some(7.25)]), (1, vec![None, None, None])]);
    }
}
