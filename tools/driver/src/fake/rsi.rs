//! A KUKA KR C4 with an RSI ETHERNET object, as far as the wire shows it: every cycle a
//! `<Rob TYPE="KUKA">` packet with the Cartesian actual and setpoint (`RIst`, `RSol`; not computed
//! here, a fixed pose), the actual and setpoint axes (`AIPos`, `ASPos`, degrees, four decimals as
//! the ETHERNET object's `Precision=4` sends them), the late-packet count (`Delay`) and the cycle
//! stamp `IPOC` (ms, stepping by the cycle); the answer must be `<Sen Type="ImFree">` with
//! `<AK A1..A6>` (degrees, the correction from the axes at the start, `RSI_ON(#ABSOLUTE)`) and the
//! same `IPOC`.

use quick_xml::Reader;
use quick_xml::events::Event;

use super::FakeProtocol;

/// The fake KR C4's RSI side.
pub struct FakeRsi {
    /// `IPOC` of cycle 0 (ms).
    pub ipoc0: u64,
    /// The cycle (ms).
    pub period_ms: u64,
    /// Axes at `RSI_ON` (degrees): `AK` is relative to them.
    pub start_deg: Vec<f64>,
    /// Answers that came after their cycle so far (the controller's `Delay`).
    pub delay: u64,
}

impl FakeRsi {
    /// A controller whose RSI starts at `start_deg`, cycling every `period_ms`.
    pub fn new(start_deg: &[f64], period_ms: u64) -> FakeRsi {
        FakeRsi { ipoc0: 1_000_000, period_ms, start_deg: start_deg.to_vec(), delay: 0 }
    }
}

impl FakeProtocol for FakeRsi {
    fn packet(&mut self, k: u64, axes: &[f64], out: &mut Vec<u8>) {
        let a = |i: usize| axes.get(i).copied().unwrap_or(0.0);
        let axes_xml =
            format!("A1=\"{:.4}\" A2=\"{:.4}\" A3=\"{:.4}\" A4=\"{:.4}\" A5=\"{:.4}\" A6=\"{:.4}\"", a(0), a(1), a(2), a(3), a(4), a(5));
        let text = format!(
            "<Rob TYPE=\"KUKA\">\r\n<RIst X=\"445.0000\" Y=\"0.0000\" Z=\"810.0000\" A=\"180.0000\" B=\"0.0000\" C=\"180.0000\"/>\r\n\
             <RSol X=\"445.0000\" Y=\"0.0000\" Z=\"810.0000\" A=\"180.0000\" B=\"0.0000\" C=\"180.0000\"/>\r\n\
             <AIPos {axes_xml}/>\r\n<ASPos {axes_xml}/>\r\n<Delay D=\"{}\"/>\r\n<IPOC>{}</IPOC>\r\n</Rob>\r\n",
            self.delay,
            self.ipoc0 + k * self.period_ms
        );
        out.clear();
        out.extend_from_slice(text.as_bytes());
    }

    fn answer(&mut self, k: u64, bytes: &[u8], axes: &mut [f64]) -> Result<(), Option<u64>> {
        let mut reader = Reader::from_reader(bytes);
        let (mut sen, mut ak, mut ipoc, mut in_ipoc) = (false, [None::<f64>; 6], None::<u64>, false);
        loop {
            match reader.read_event() {
                Ok(Event::Start(e)) if e.name().as_ref() == b"Sen" => {
                    sen = e.attributes().flatten().any(|a| a.key.as_ref() == b"Type" && a.value.as_ref() == b"ImFree");
                }
                Ok(Event::Start(e)) if e.name().as_ref() == b"IPOC" => in_ipoc = true,
                Ok(Event::Start(e) | Event::Empty(e)) if e.name().as_ref() == b"AK" => {
                    for at in e.attributes().flatten() {
                        let key = at.key.as_ref();
                        if key.len() == 2 && key[0] == b'A' && (b'1'..=b'6').contains(&key[1]) {
                            ak[(key[1] - b'1') as usize] = std::str::from_utf8(&at.value).ok().and_then(|s| s.parse().ok());
                        }
                    }
                }
                Ok(Event::Text(t)) if in_ipoc => {
                    ipoc = std::str::from_utf8(&t).ok().and_then(|s| s.trim().parse().ok());
                    in_ipoc = false;
                }
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
        if ak.iter().any(|v| v.is_none_or(|x| !x.is_finite())) {
            return Err(None);
        }
        for (i, a) in axes.iter_mut().enumerate().take(6) {
            *a = self.start_deg[i] + ak[i].unwrap_or(0.0);
        }
        Ok(())
    }
}
