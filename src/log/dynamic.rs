//! Schema-driven CDR decoding: parses a ros2msg schema text (the one stored with each MCAP
//! channel) and decodes any message of it into a flat list of named values. `strand-replay export`
//! and `info` use it for every channel, so they read logs of older builds too, and the tests use it to
//! prove that each schema we write describes exactly the bytes we encode.

use std::collections::HashMap;
use std::fmt;

use super::cdr::{CdrError, CdrReader};

/// A decoded primitive.
#[derive(Clone, Debug, PartialEq)]
pub enum Value {
    /// bool, byte, char, uint*.
    U(u64),
    /// int*.
    I(i64),
    /// float32, float64.
    F(f64),
    /// string.
    S(String),
}

impl Value {
    /// As f64 (strings: NaN).
    pub fn as_f64(&self) -> f64 {
        match self {
            Value::U(v) => *v as f64,
            Value::I(v) => *v as f64,
            Value::F(v) => *v,
            Value::S(_) => f64::NAN,
        }
    }
}

impl fmt::Display for Value {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Value::U(v) => write!(f, "{v}"),
            Value::I(v) => write!(f, "{v}"),
            // Shortest text that reads back to the same f64.
            Value::F(v) => write!(f, "{v:?}"),
            Value::S(v) => write!(f, "{v}"),
        }
    }
}

#[derive(Clone, Debug, PartialEq)]
enum Arity {
    One,
    Fixed(usize),
    Unbounded,
    Bounded(usize),
}

#[derive(Clone, Debug)]
struct Field {
    name: String,
    ty: String,
    arity: Arity,
}

/// Why a schema could not be used.
#[derive(Debug, thiserror::Error)]
pub enum SchemaError {
    /// A line that is not `type name`.
    #[error("schema {schema}: line {line}: cannot parse {text:?}")]
    Line {
        /// Schema name.
        schema: String,
        /// Line number in the schema text (from 1).
        line: usize,
        /// The line.
        text: String,
    },
    /// A field type that no section defines.
    #[error("schema {schema}: unknown type {ty}")]
    UnknownType {
        /// Schema name.
        schema: String,
        /// The type.
        ty: String,
    },
    /// The message does not match the schema.
    #[error("schema {schema}: {source}")]
    Decode {
        /// Schema name.
        schema: String,
        /// What went wrong.
        source: CdrError,
    },
}

/// A parsed ros2msg schema with its dependencies.
#[derive(Clone, Debug)]
pub struct Schema {
    name: String,
    types: HashMap<String, Vec<Field>>,
}

fn short_name(name: &str) -> String {
    name.trim().replace("/msg/", "/")
}

const PRIMITIVES: &[&str] =
    &["bool", "byte", "char", "int8", "uint8", "int16", "uint16", "int32", "uint32", "int64", "uint64", "float32", "float64", "string"];

impl Schema {
    /// Parses the schema text of message type `name` (e.g. `sensor_msgs/msg/JointState`).
    pub fn parse(name: &str, text: &str) -> Result<Self, SchemaError> {
        let top = short_name(name);
        let package = top.split('/').next().unwrap_or("").to_string();
        let mut types: HashMap<String, Vec<Field>> = HashMap::new();
        let mut current = top.clone();
        let mut current_package = package;
        types.insert(current.clone(), Vec::new());
        for (i, raw) in text.lines().enumerate() {
            let line = raw.split('#').next().unwrap_or("").trim();
            if line.is_empty() {
                continue;
            }
            if line.starts_with("==") {
                continue;
            }
            if let Some(msg) = line.strip_prefix("MSG:") {
                current = short_name(msg);
                current_package = current.split('/').next().unwrap_or("").to_string();
                types.entry(current.clone()).or_default();
                continue;
            }
            let bad = || SchemaError::Line { schema: top.clone(), line: i + 1, text: raw.to_string() };
            let mut parts = line.split_whitespace();
            let (Some(ty), Some(field_name)) = (parts.next(), parts.next()) else { return Err(bad()) };
            if field_name.contains('=') || parts.clone().next().is_some_and(|p| p.starts_with('=')) {
                continue; // a constant: no data
            }
            let (base, arity) = match ty.find('[') {
                None => (ty, Arity::One),
                Some(k) => {
                    let inner = ty[k + 1..].strip_suffix(']').ok_or_else(bad)?;
                    let arity = if inner.is_empty() {
                        Arity::Unbounded
                    } else if let Some(n) = inner.strip_prefix("<=") {
                        Arity::Bounded(n.parse().map_err(|_| bad())?)
                    } else {
                        Arity::Fixed(inner.parse().map_err(|_| bad())?)
                    };
                    (&ty[..k], arity)
                }
            };
            // Bounded strings (`string<=10`) decode like strings.
            let base = if base.starts_with("string") { "string" } else { base };
            let ty = if PRIMITIVES.contains(&base) {
                base.to_string()
            } else if base.contains('/') {
                short_name(base)
            } else if base == "Header" {
                "std_msgs/Header".to_string()
            } else {
                format!("{current_package}/{base}")
            };
            types.get_mut(&current).expect("section").push(Field { name: field_name.to_string(), ty, arity });
        }
        let schema = Schema { name: top, types };
        for fields in schema.types.values() {
            for f in fields {
                if !PRIMITIVES.contains(&f.ty.as_str()) && !schema.types.contains_key(&f.ty) {
                    return Err(SchemaError::UnknownType { schema: schema.name.clone(), ty: f.ty.clone() });
                }
            }
        }
        Ok(schema)
    }

    /// The message type name (`pkg/Type`).
    pub fn name(&self) -> &str {
        &self.name
    }

    /// Decodes a whole CDR message into (path, value) pairs in declaration order; paths look like
    /// `header.stamp.sec`, `position[2]`.
    pub fn decode(&self, bytes: &[u8]) -> Result<Vec<(String, Value)>, SchemaError> {
        let err = |source| SchemaError::Decode { schema: self.name.clone(), source };
        let mut r = CdrReader::new(bytes).map_err(err)?;
        let mut out = Vec::new();
        self.decode_type(&self.name, "", &mut r, &mut out).map_err(err)?;
        if r.remaining() > 3 {
            return Err(err(CdrError::TooLong { at: bytes.len() - r.remaining(), len: r.remaining(), max: 0 }));
        }
        Ok(out)
    }

    fn decode_type(&self, ty: &str, path: &str, r: &mut CdrReader, out: &mut Vec<(String, Value)>) -> Result<(), CdrError> {
        for f in &self.types[ty] {
            let p = if path.is_empty() { f.name.clone() } else { format!("{path}.{}", f.name) };
            let n = match f.arity {
                Arity::One => {
                    self.decode_one(&f.ty, &p, r, out)?;
                    continue;
                }
                Arity::Fixed(n) => n,
                Arity::Unbounded => r.len(u32::MAX as usize)?,
                Arity::Bounded(max) => r.len(max)?,
            };
            for i in 0..n {
                self.decode_one(&f.ty, &format!("{p}[{i}]"), r, out)?;
            }
        }
        Ok(())
    }

    fn decode_one(&self, ty: &str, path: &str, r: &mut CdrReader, out: &mut Vec<(String, Value)>) -> Result<(), CdrError> {
        let v = match ty {
            "bool" | "byte" | "char" | "uint8" => Value::U(r.u8()? as u64),
            "int8" => Value::I(r.u8()? as i8 as i64),
            "uint16" => Value::U(r.u16()? as u64),
            "int16" => Value::I(r.u16()? as i16 as i64),
            "uint32" => Value::U(r.u32()? as u64),
            "int32" => Value::I(r.i32()? as i64),
            "uint64" => Value::U(r.u64()?),
            "int64" => Value::I(r.u64()? as i64),
            "float32" => Value::F(f32::from_bits(r.u32()?) as f64),
            "float64" => Value::F(r.f64()?),
            "string" => Value::S(r.string()?.to_string()),
            nested => return self.decode_type(nested, path, r, out),
        };
        out.push((path.to_string(), v));
        Ok(())
    }
}
