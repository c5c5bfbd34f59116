//! Reads a strand log back: its metadata, attachments, channels and ticks. Works on a finished file
//! and on one a crash cut short (everything in closed chunks is read; the open chunk is lost), by
//! scanning records in file order rather than trusting a summary that may not exist.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use mcap::read::{LinearReader, Options};
use mcap::records::Record;

use super::cdr::decode;
use super::messages::Tick;
use super::{names, topics};
use crate::config::{Config, ConfigError};

/// Why a log could not be read.
#[derive(Debug, thiserror::Error)]
pub enum ReadError {
    /// The file could not be read.
    #[error("{path}: {message}")]
    File {
        /// The file.
        path: String,
        /// What went wrong.
        message: String,
    },
    /// A message on a channel could not be decoded.
    #[error("{path}: {topic} message {index}: {message}")]
    Message {
        /// The file.
        path: String,
        /// The channel.
        topic: String,
        /// Its index on the channel (from 0).
        index: u64,
        /// What went wrong.
        message: String,
    },
    /// The log's configuration could not be rebuilt.
    #[error(transparent)]
    Config(#[from] ConfigError),
}

/// One attachment.
#[derive(Clone, Debug)]
pub struct LogAttachment {
    /// Its name.
    pub name: String,
    /// Media type.
    pub media_type: String,
    /// Content.
    pub data: Vec<u8>,
}

/// A log file in memory.
pub struct LogFile {
    /// Where it was read from.
    pub path: PathBuf,
    bytes: Vec<u8>,
    /// The `strand` metadata record (empty if the file was cut before it).
    pub metadata: BTreeMap<String, String>,
    /// Attachments (config, URDF).
    pub attachments: Vec<LogAttachment>,
    /// The file ends with a footer and the closing magic (it was finished, not cut short).
    pub finished: bool,
}

const MAGIC: &[u8] = b"\x89MCAP0\r\n";

impl LogFile {
    /// Reads a file.
    pub fn open(path: &Path) -> Result<Self, ReadError> {
        let bytes = std::fs::read(path).map_err(|e| ReadError::File { path: path.display().to_string(), message: e.to_string() })?;
        Self::from_bytes(path, bytes)
    }

    /// From bytes already read.
    pub(crate) fn from_bytes(path: &Path, bytes: Vec<u8>) -> Result<Self, ReadError> {
        if !bytes.starts_with(MAGIC) {
            return Err(ReadError::File { path: path.display().to_string(), message: "not an MCAP file (no magic)".to_string() });
        }
        let finished = bytes.len() >= 2 * MAGIC.len() && bytes.ends_with(MAGIC);
        let mut metadata = BTreeMap::new();
        let mut attachments = Vec::new();
        if let Ok(reader) = LinearReader::new_with_options(&bytes, Options::IgnoreEndMagic.into()) {
            for rec in reader {
                match rec {
                    Ok(Record::Metadata(m)) if m.name == names::METADATA => metadata = m.metadata,
                    Ok(Record::Attachment { header, data, .. }) => {
                        attachments.push(LogAttachment { name: header.name, media_type: header.media_type, data: data.into_owned() })
                    }
                    Ok(_) => {}
                    Err(_) => break,
                }
            }
        }
        Ok(LogFile { path: path.to_path_buf(), bytes, metadata, attachments, finished })
    }

    /// The raw bytes.
    pub fn bytes(&self) -> &[u8] {
        &self.bytes
    }

    /// An attachment by name.
    pub fn attachment(&self, name: &str) -> Option<&LogAttachment> {
        self.attachments.iter().find(|a| a.name == name)
    }

    /// A metadata value.
    pub fn meta(&self, key: &str) -> Option<&str> {
        self.metadata.get(key).map(String::as_str)
    }

    /// The configuration the run used, rebuilt from the logged effective config and URDF.
    pub fn config(&self) -> Result<Config, ReadError> {
        let missing = |what: &str| ReadError::File {
            path: self.path.display().to_string(),
            message: format!("no {what} attachment (the file was cut before it was written?)"),
        };
        let text = self.attachment(names::EFFECTIVE_CONFIG).ok_or_else(|| missing(names::EFFECTIVE_CONFIG))?;
        let urdf = self.attachment(names::URDF).ok_or_else(|| missing(names::URDF))?;
        let text = String::from_utf8_lossy(&text.data);
        let urdf = String::from_utf8_lossy(&urdf.data);
        Ok(Config::from_effective(&self.path, &text, &urdf)?)
    }

    /// Every message in file order; stops quietly where a cut-short file ends.
    pub fn messages(&self) -> impl Iterator<Item = mcap::Message<'static>> + '_ {
        let stream = mcap::MessageStream::new_with_options(&self.bytes, Options::IgnoreEndMagic.into()).ok();
        stream.into_iter().flatten().map_while(Result::ok)
    }

    /// The messages of one channel.
    pub fn channel<'a>(&'a self, topic: &'a str) -> impl Iterator<Item = mcap::Message<'static>> + 'a {
        self.messages().filter(move |m| m.channel.topic == topic)
    }

    /// Every logged tick, decoded.
    pub fn ticks(&self) -> impl Iterator<Item = Result<Tick, ReadError>> + '_ {
        self.channel(topics::TICK).enumerate().map(|(i, m)| {
            decode::<Tick>(&m.data).map_err(|e| ReadError::Message {
                path: self.path.display().to_string(),
                topic: topics::TICK.to_string(),
                index: i as u64,
                message: e.to_string(),
            })
        })
    }
}
