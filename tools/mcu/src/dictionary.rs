//! The MCU's data dictionary: what its commands and responses are called, their ids, the pins it
//! has, its constants.
//!
//! Klipper firmware assigns message ids at build time, so the host must never assume them. The
//! only fixed ids are the bootstrap pair `identify_response` (0) and `identify` (1): the host asks
//! for the dictionary in chunks with `identify offset count`, the chunks concatenate to a
//! zlib-compressed JSON object `{commands: {format: id}, responses: {format: id},
//! enumerations: {...}, config: {...}, version, build_versions, app}`. Everything else is looked up
//! here by *format string*, so a firmware whose command differs from what the host expects fails
//! with a message naming the command rather than sending wrong bytes.

use std::collections::HashMap;
use std::io::Read;

use crate::transport::{decode_vlq, encode_vlq};

/// The bootstrap response's format; its id is 0 on every Klipper MCU.
pub const IDENTIFY_RESPONSE: &str = "identify_response offset=%u data=%.*s";
/// The bootstrap command's format; its id is 1 on every Klipper MCU.
pub const IDENTIFY: &str = "identify offset=%u count=%c";

/// What went wrong with the dictionary or a message.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum DictError {
    /// The board's firmware has no such command or response.
    #[error("the MCU has no message '{0}'")]
    UnknownMessage(String),
    /// The board has the message under another format (a different Klipper version).
    #[error("the MCU's '{name}' is '{theirs}', the host expects '{ours}'")]
    FormatMismatch {
        /// Message name.
        name: String,
        /// The format the host uses.
        ours: String,
        /// The MCU's format.
        theirs: String,
    },
    /// A pin (or other enumerated value) the board lacks.
    #[error("the MCU has no {enumeration} '{value}'")]
    UnknownEnum {
        /// Enumeration name ("pin").
        enumeration: String,
        /// The value asked for.
        value: String,
    },
    /// A parameter the format needs was not given.
    #[error("'{message}' needs parameter '{param}'")]
    MissingParam {
        /// Message name.
        message: String,
        /// Parameter name.
        param: String,
    },
    /// A parameter of the wrong kind or out of its type's range.
    #[error("'{message}' parameter '{param}': {why}")]
    BadParam {
        /// Message name.
        message: String,
        /// Parameter name.
        param: String,
        /// What is wrong.
        why: String,
    },
    /// A format string with a type Klipper does not define.
    #[error("unsupported format '{0}'")]
    BadFormat(String),
    /// The identify data does not decompress or parse.
    #[error("data dictionary: {0}")]
    Corrupt(String),
    /// A received message is truncated, has an unknown id or trailing bytes.
    #[error("malformed message: {0}")]
    Malformed(String),
    /// A constant the host needs is missing.
    #[error("the MCU has no constant '{0}'")]
    MissingConstant(String),
}

/// A parameter's wire type (the printf-like specifier of the format string).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ParamType {
    /// `%u`: 32-bit unsigned.
    U32,
    /// `%i`: 32-bit signed.
    I32,
    /// `%hu`: 16-bit unsigned.
    U16,
    /// `%hi`: 16-bit signed.
    I16,
    /// `%c`: 8-bit.
    Byte,
    /// `%s`, `%.*s`, `%*s`: a length-prefixed byte string.
    Bytes,
}

impl ParamType {
    fn parse(spec: &str) -> Option<Self> {
        Some(match spec {
            "%u" => Self::U32,
            "%i" => Self::I32,
            "%hu" => Self::U16,
            "%hi" => Self::I16,
            "%c" => Self::Byte,
            "%s" | "%.*s" | "%*s" => Self::Bytes,
            _ => return None,
        })
    }
}

/// A parameter value, given to encode or returned by decode.
#[derive(Debug, Clone, PartialEq)]
pub enum Value {
    /// An integer (any of the integer types; checked against the type's range on encode).
    Int(i64),
    /// A byte string.
    Bytes(Vec<u8>),
    /// A name in an enumeration (a pin name such as "PA0"); encoded as its number.
    Enum(String),
}

impl Value {
    /// The integer, if this is one.
    pub fn as_int(&self) -> Option<i64> {
        match self {
            Self::Int(v) => Some(*v),
            _ => None,
        }
    }
}

/// A parameter: name, wire type, and the enumeration its values come from (if any).
pub type Param = (String, ParamType, Option<String>);

/// One command or response format.
#[derive(Debug, Clone)]
pub struct MessageFormat {
    /// Message id on this MCU.
    pub id: u32,
    /// The full format string, e.g. `queue_step oid=%c interval=%u count=%hu add=%hi`.
    pub format: String,
    /// Name (first word).
    pub name: String,
    /// Parameters in wire order: name, type, and the enumeration it draws from, if any.
    pub params: Vec<Param>,
}

/// Decoded response: name and parameters by name.
#[derive(Debug, Clone, PartialEq)]
pub struct Message {
    /// Message name (first word of its format).
    pub name: String,
    /// Parameters by name; integers already sign- or zero-extended per their type.
    pub params: HashMap<String, Value>,
}

impl Message {
    /// An integer parameter.
    pub fn int(&self, name: &str) -> Result<i64, DictError> {
        self.params
            .get(name)
            .and_then(Value::as_int)
            .ok_or_else(|| DictError::Malformed(format!("'{}' has no integer '{name}'", self.name)))
    }

    /// A byte-string parameter.
    pub fn bytes(&self, name: &str) -> Result<&[u8], DictError> {
        match self.params.get(name) {
            Some(Value::Bytes(b)) => Ok(b),
            _ => Err(DictError::Malformed(format!("'{}' has no string '{name}'", self.name))),
        }
    }
}

/// The parsed data dictionary.
#[derive(Debug, Clone, Default)]
pub struct Dictionary {
    by_id: HashMap<u32, MessageFormat>,
    by_name: HashMap<String, MessageFormat>,
    /// Enumerations by name ("pin", "static_string_id", ...): value name → number.
    pub enumerations: HashMap<String, HashMap<String, i64>>,
    /// Firmware constants (CLOCK_FREQ, MCU, ADC_MAX, RECEIVE_WINDOW, ...), as JSON values.
    pub config: HashMap<String, serde_json::Value>,
    /// Firmware version string.
    pub version: String,
    /// Compiler versions the firmware was built with.
    pub build_versions: String,
    /// The `app` field ("Klipper" for Klipper firmware; other firmware may differ or omit it).
    pub app: String,
}

/// Parses a format string into its name and parameters.
pub fn parse_format(format: &str, enumerations: &HashMap<String, HashMap<String, i64>>) -> Result<(String, Vec<Param>), DictError> {
    let mut words = format.split_whitespace();
    let name = words.next().ok_or_else(|| DictError::BadFormat(format.into()))?.to_string();
    let mut params = Vec::new();
    for w in words {
        let (pname, spec) = w.split_once('=').ok_or_else(|| DictError::BadFormat(format.into()))?;
        let ty = ParamType::parse(spec).ok_or_else(|| DictError::BadFormat(format.into()))?;
        // msgproto.py: a parameter named like an enumeration, or ending in "_<enumeration>",
        // takes its values from it (pin, step_pin, dir_pin, static_string_id...).
        let mut en = None;
        if ty != ParamType::Bytes {
            let mut names: Vec<&String> = enumerations.keys().collect();
            names.sort();
            for e in names {
                if pname == e || pname.ends_with(&format!("_{e}")) {
                    en = Some(e.clone());
                    break;
                }
            }
        }
        params.push((pname.to_string(), ty, en));
    }
    Ok((name, params))
}

impl Dictionary {
    /// The bootstrap dictionary: only `identify` and `identify_response`.
    pub fn bootstrap() -> Self {
        let mut d = Self::default();
        d.add(IDENTIFY_RESPONSE, 0).expect("valid format");
        d.add(IDENTIFY, 1).expect("valid format");
        d
    }

    fn add(&mut self, format: &str, id: u32) -> Result<(), DictError> {
        let (name, params) = parse_format(format, &self.enumerations)?;
        let m = MessageFormat { id, format: format.to_string(), name: name.clone(), params };
        self.by_id.insert(id, m.clone());
        self.by_name.insert(name, m);
        Ok(())
    }

    /// Parses the identify data (zlib-compressed JSON as the MCU sends it).
    pub fn from_identify_data(compressed: &[u8]) -> Result<Self, DictError> {
        let mut json = Vec::new();
        flate2::read::ZlibDecoder::new(compressed).read_to_end(&mut json).map_err(|e| DictError::Corrupt(format!("zlib: {e}")))?;
        Self::from_json(&json)
    }

    /// Parses the uncompressed JSON dictionary.
    pub fn from_json(json: &[u8]) -> Result<Self, DictError> {
        let v: serde_json::Value = serde_json::from_slice(json).map_err(|e| DictError::Corrupt(format!("json: {e}")))?;
        let obj = v.as_object().ok_or_else(|| DictError::Corrupt("not a JSON object".into()))?;
        let mut d = Self::default();
        if let Some(en) = obj.get("enumerations").and_then(|e| e.as_object()) {
            for (ename, values) in en {
                let map = d.enumerations.entry(ename.clone()).or_default();
                let Some(values) = values.as_object() else { continue };
                for (k, val) in values {
                    if let Some(n) = val.as_i64() {
                        map.insert(k.clone(), n);
                    } else if let Some(arr) = val.as_array()
                        && arr.len() == 2
                        && let (Some(start), Some(count)) = (arr[0].as_i64(), arr[1].as_i64())
                    {
                        // A range "PA0": [0, 16] names PA0..PA15 from value 0.
                        let root = k.trim_end_matches(|c: char| c.is_ascii_digit());
                        let first: i64 = k[root.len()..].parse().unwrap_or(0);
                        for i in 0..count.clamp(0, 4096) {
                            map.insert(format!("{root}{}", first + i), start + i);
                        }
                    }
                }
            }
        }
        for section in ["commands", "responses", "output"] {
            if let Some(m) = obj.get(section).and_then(|e| e.as_object()) {
                for (fmt, id) in m {
                    let id = id.as_u64().ok_or_else(|| DictError::Corrupt(format!("id of '{fmt}'")))?;
                    if section == "output" {
                        // Debug printf-style messages: names are not unique; keep by id only.
                        continue;
                    }
                    d.add(fmt, id as u32)?;
                }
            }
        }
        if !d.by_name.contains_key("identify") {
            d.add(IDENTIFY, 1)?;
            d.add(IDENTIFY_RESPONSE, 0)?;
        }
        if let Some(c) = obj.get("config").and_then(|e| e.as_object()) {
            d.config = c.iter().map(|(k, v)| (k.clone(), v.clone())).collect();
        }
        let s = |k: &str| obj.get(k).and_then(|v| v.as_str()).unwrap_or("").to_string();
        d.version = s("version");
        d.build_versions = s("build_versions");
        d.app = s("app");
        Ok(d)
    }

    /// A numeric constant (CLOCK_FREQ, ADC_MAX, ...). Klipper sends them as numbers or strings.
    pub fn constant_f64(&self, name: &str) -> Result<f64, DictError> {
        let v = self.config.get(name).ok_or_else(|| DictError::MissingConstant(name.into()))?;
        v.as_f64()
            .or_else(|| v.as_str().and_then(|s| s.trim().parse().ok()))
            .ok_or_else(|| DictError::MissingConstant(format!("{name} (not a number: {v})")))
    }

    /// A string constant (MCU, ...).
    pub fn constant_str(&self, name: &str) -> Result<String, DictError> {
        let v = self.config.get(name).ok_or_else(|| DictError::MissingConstant(name.into()))?;
        Ok(v.as_str().map(str::to_string).unwrap_or_else(|| v.to_string()))
    }

    /// The number of a value in an enumeration (a pin's number); an error names the missing one.
    pub fn enum_value(&self, enumeration: &str, name: &str) -> Result<i64, DictError> {
        self.enumerations
            .get(enumeration)
            .and_then(|m| m.get(name))
            .copied()
            .ok_or_else(|| DictError::UnknownEnum { enumeration: enumeration.into(), value: name.into() })
    }

    /// The reverse: the name of an enumeration number (a shutdown reason's text).
    pub fn enum_name(&self, enumeration: &str, value: i64) -> Option<&str> {
        self.enumerations.get(enumeration)?.iter().find(|(_, v)| **v == value).map(|(k, _)| k.as_str())
    }

    /// The message with this name, checked to have exactly this format.
    pub fn lookup(&self, format: &str) -> Result<&MessageFormat, DictError> {
        let name = format.split_whitespace().next().unwrap_or("");
        let m = self.by_name.get(name).ok_or_else(|| DictError::UnknownMessage(name.into()))?;
        if m.format != format.trim() {
            return Err(DictError::FormatMismatch { name: name.into(), ours: format.into(), theirs: m.format.clone() });
        }
        Ok(m)
    }

    /// Whether the MCU has a message of this name.
    pub fn has(&self, name: &str) -> bool {
        self.by_name.contains_key(name)
    }

    /// Encodes a command by its format and named parameters.
    pub fn encode(&self, format: &str, args: &[(&str, Value)]) -> Result<Vec<u8>, DictError> {
        let m = self.lookup(format)?;
        let mut out = Vec::new();
        encode_vlq(&mut out, m.id);
        for (pname, ty, en) in &m.params {
            let v = args
                .iter()
                .find(|(n, _)| n == pname)
                .map(|(_, v)| v)
                .ok_or_else(|| DictError::MissingParam { message: m.name.clone(), param: pname.clone() })?;
            let bad = |why: String| DictError::BadParam { message: m.name.clone(), param: pname.clone(), why };
            let int = match (v, ty) {
                (Value::Bytes(b), ParamType::Bytes) => {
                    if b.len() > 255 {
                        return Err(bad(format!("{} bytes is too long", b.len())));
                    }
                    out.push(b.len() as u8);
                    out.extend_from_slice(b);
                    continue;
                }
                (_, ParamType::Bytes) => return Err(bad("expects a byte string".into())),
                (Value::Int(i), _) => *i,
                (Value::Enum(s), _) => {
                    let e = en.as_deref().ok_or_else(|| bad("is not an enumeration".into()))?;
                    self.enum_value(e, s)?
                }
                (Value::Bytes(_), _) => return Err(bad("expects an integer".into())),
            };
            let (lo, hi) = match ty {
                ParamType::U32 => (i64::from(i32::MIN), i64::from(u32::MAX)),
                ParamType::I32 => (i64::from(i32::MIN), i64::from(u32::MAX)),
                ParamType::U16 | ParamType::I16 => (i64::from(i16::MIN), i64::from(u16::MAX)),
                ParamType::Byte => (-128, 255),
                ParamType::Bytes => unreachable!("handled above"),
            };
            if !(lo..=hi).contains(&int) {
                return Err(bad(format!("{int} out of range {lo}..={hi}")));
            }
            encode_vlq(&mut out, int as u32);
        }
        if out.len() > crate::transport::MESSAGE_PAYLOAD_MAX {
            return Err(DictError::BadParam { message: m.name.clone(), param: String::new(), why: "message longer than one block".into() });
        }
        Ok(out)
    }

    /// Decodes every message in a block's content.
    pub fn decode_all(&self, content: &[u8]) -> Result<Vec<Message>, DictError> {
        let mut pos = 0;
        let mut out = Vec::new();
        while pos < content.len() {
            out.push(self.decode_one(content, &mut pos)?);
        }
        Ok(out)
    }

    fn decode_one(&self, buf: &[u8], pos: &mut usize) -> Result<Message, DictError> {
        let trunc = || DictError::Malformed("truncated".into());
        let id = decode_vlq(buf, pos).ok_or_else(trunc)?;
        let m = self.by_id.get(&id).ok_or_else(|| DictError::Malformed(format!("unknown id {id}")))?;
        let mut params = HashMap::new();
        for (pname, ty, en) in &m.params {
            let v = if *ty == ParamType::Bytes {
                let len = *buf.get(*pos).ok_or_else(trunc)? as usize;
                let data = buf.get(*pos + 1..*pos + 1 + len).ok_or_else(trunc)?.to_vec();
                *pos += 1 + len;
                Value::Bytes(data)
            } else {
                let raw = decode_vlq(buf, pos).ok_or_else(trunc)?;
                let i = match ty {
                    ParamType::U32 => i64::from(raw),
                    ParamType::I32 => i64::from(raw as i32),
                    ParamType::U16 => i64::from(raw as u16),
                    ParamType::I16 => i64::from(raw as i16),
                    ParamType::Byte => i64::from(raw as u8),
                    ParamType::Bytes => unreachable!("handled above"),
                };
                match en.as_deref().and_then(|e| self.enum_name(e, i)) {
                    Some(name) if pname != "oid" => Value::Enum(name.to_string()),
                    _ => Value::Int(i),
                }
            };
            params.insert(pname.clone(), v);
        }
        Ok(Message { name: m.name.clone(), params })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::io::Write;

    fn dict() -> Dictionary {
        let json = serde_json::json!({
            "commands": {
                "identify offset=%u count=%c": 1,
                "queue_step oid=%c interval=%u count=%hu add=%hi": 20,
                "config_stepper oid=%c step_pin=%c dir_pin=%c invert_step=%c step_pulse_ticks=%u": 200,
            },
            "responses": {
                "identify_response offset=%u data=%.*s": 0,
                "clock clock=%u": 81,
                "shutdown clock=%u static_string_id=%hu": 82,
            },
            "enumerations": {
                "pin": {"PA0": [0, 16], "PB0": [16, 16], "gpio2": [2, 3]},
                "static_string_id": {"Timer too close": 2},
            },
            "config": {"CLOCK_FREQ": 12000000, "MCU": "rp2040", "ADC_MAX": "4095"},
            "version": "v0.12.0-fake",
            "app": "Klipper",
        });
        let mut z = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::default());
        z.write_all(json.to_string().as_bytes()).unwrap();
        Dictionary::from_identify_data(&z.finish().unwrap()).unwrap()
    }

    #[test]
    fn encodes_by_format_and_pins() {
        let d = dict();
        let b = d
            .encode(
                "queue_step oid=%c interval=%u count=%hu add=%hi",
                &[("oid", Value::Int(3)), ("interval", Value::Int(1000)), ("count", Value::Int(5)), ("add", Value::Int(-2))],
            )
            .unwrap();
        assert_eq!(b, vec![20, 3, 0x87, 0x68, 5, 0x7e]);
        assert_eq!(d.enum_value("pin", "PB15").unwrap(), 31);
        assert_eq!(d.enum_value("pin", "gpio4").unwrap(), 4);
        let e = d.enum_value("pin", "PC3").unwrap_err();
        assert_eq!(e.to_string(), "the MCU has no pin 'PC3'");
        let c = d
            .encode(
                "config_stepper oid=%c step_pin=%c dir_pin=%c invert_step=%c step_pulse_ticks=%u",
                &[
                    ("oid", Value::Int(0)),
                    ("step_pin", Value::Enum("PA3".into())),
                    ("dir_pin", Value::Enum("PZ9".into())),
                    ("invert_step", Value::Int(-1)),
                    ("step_pulse_ticks", Value::Int(24)),
                ],
            )
            .unwrap_err();
        assert!(c.to_string().contains("PZ9"));
        assert_eq!(d.encode("endstop_home oid=%c", &[]).unwrap_err().to_string(), "the MCU has no message 'endstop_home'");
        assert!(matches!(d.encode("queue_step oid=%c interval=%u count=%c add=%hi", &[]), Err(DictError::FormatMismatch { .. })));
        assert_eq!(d.constant_f64("CLOCK_FREQ").unwrap(), 12e6);
        assert_eq!(d.constant_f64("ADC_MAX").unwrap(), 4095.0);
        assert_eq!(d.constant_str("MCU").unwrap(), "rp2040");
    }

    #[test]
    fn decodes_responses_with_enums() {
        let d = dict();
        let mut b = Vec::new();
        encode_vlq(&mut b, 82);
        encode_vlq(&mut b, 0xdead_beef);
        encode_vlq(&mut b, 2);
        encode_vlq(&mut b, 81);
        encode_vlq(&mut b, 7);
        let m = d.decode_all(&b).unwrap();
        assert_eq!(m[0].name, "shutdown");
        assert_eq!(m[0].int("clock").unwrap(), 0xdead_beef);
        assert_eq!(m[0].params["static_string_id"], Value::Enum("Timer too close".into()));
        assert_eq!(m[1].int("clock").unwrap(), 7);
        // Truncated or unknown ids are errors, never panics.
        assert!(d.decode_all(&b[..3]).is_err());
        assert!(d.decode_all(&[0x7f, 0x7f]).is_err());
    }

    #[test]
    fn corrupt_data_is_an_error_and_random_bytes_never_panic() {
        assert!(Dictionary::from_identify_data(b"not zlib").is_err());
        let d = dict();
        let mut s = 99u64;
        for _ in 0..20_000 {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            let n = (s >> 60) as usize;
            let bytes: Vec<u8> = (0..n).map(|i| (s >> (i * 4 % 56)) as u8).collect();
            let _ = d.decode_all(&bytes);
            let _ = Dictionary::from_identify_data(&bytes);
        }
    }
}
