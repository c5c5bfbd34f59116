//! Reads a strand log back: its metadata, attachments, channels and ticks. Works on a finished file
//! and on one a crash cut short (everything in closed chunks is read; the open chunk is lost), by
//! scanning records in file order rather than trusting a summary that may not exist.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use mcap::read::{LinearReader, Options};
use mcap::records::Record;

use super::cdr::{CdrError, CdrWriter, decode};
use super::messages::Tick;
use super::record::{LoggedOutput, TickRecord, decode_block, output_digest};
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
    /// A compact log's outputs could not be recomputed: no controller from its config, a tick
    /// missing, or this build's controller not reproducing a logged digest.
    #[error("{path}: {message}")]
    Replay {
        /// The file.
        path: String,
        /// What went wrong, with the tick.
        message: String,
    },
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

    /// Every logged tick as the file holds it, from either replay record (`/strand/tick`, each
    /// output whole; `/strand/ticks`, blocks with digests), in file order.
    pub fn records(&self) -> impl Iterator<Item = Result<TickRecord, ReadError>> + '_ {
        let mut scratch = CdrWriter::new();
        let mut index = 0u64;
        self.messages().filter(|m| m.channel.topic == topics::TICK || m.channel.topic == topics::TICKS).flat_map(move |m| {
            let at = index;
            index += 1;
            let err = |e: CdrError| ReadError::Message {
                path: self.path.display().to_string(),
                topic: m.channel.topic.clone(),
                index: at,
                message: e.to_string(),
            };
            let records: Vec<Result<TickRecord, ReadError>> = if m.channel.topic == topics::TICK {
                vec![decode::<Tick>(&m.data).map_err(err).map(|t| TickRecord {
                    digest: output_digest(&mut scratch, &t.output),
                    input: Box::new(t.input),
                    timing: t.timing,
                    output: LoggedOutput::Whole(Box::new(t.output)),
                })]
            } else {
                match decode_block(&m.data) {
                    Ok(block) => block.into_iter().map(Ok).collect(),
                    Err(e) => vec![Err(err(e))],
                }
            };
            records
        })
    }

    /// Every logged tick with its output (see [`ticks_of`]; a rotated part of a compact log needs
    /// the parts before it).
    pub fn ticks(&self) -> Ticks<'_> {
        ticks_of(std::slice::from_ref(self))
    }
}

/// Every tick of `files` (one log, or a run's rotated parts in order) with its output: as logged
/// where the file holds it whole (`[log] record = "full"`), else recomputed by replaying the
/// inputs through a controller built from the log's own configuration, and checked against the
/// logged digest. The iteration ends after the first error (a tick missing, or a digest this
/// build does not reproduce: the outputs of a compact log are only as good as the replay).
pub fn ticks_of(files: &[LogFile]) -> Ticks<'_> {
    // Built before iterating (a controller is built on the stack): only for a compact log, which
    // the first replay record tells.
    let compact = files.first().is_some_and(|f| {
        f.messages()
            .find(|m| m.channel.topic == topics::TICK || m.channel.topic == topics::TICKS)
            .is_some_and(|m| m.channel.topic == topics::TICKS)
    });
    let controller = compact.then(|| {
        let cfg = files[0].config().map_err(|e| e.to_string())?;
        let controller = cfg.robot.build_controller(&cfg.controller_settings()).map_err(|e| e.to_string())?;
        Ok(Box::new(controller))
    });
    Ticks { files, file: 0, records: None, replayer: Replayer { controller, expected: 0, scratch: CdrWriter::new(), failed: false } }
}

/// The iterator of [`ticks_of`]. A struct rather than a chain of adaptors: a tick is large, and a
/// replay steps a controller inside `next`, which a deep chain of adaptor frames would leave
/// little stack for (a test thread has 2 MiB).
pub struct Ticks<'a> {
    files: &'a [LogFile],
    file: usize,
    records: Option<Box<dyn Iterator<Item = Result<TickRecord, ReadError>> + 'a>>,
    replayer: Replayer,
}

impl Iterator for Ticks<'_> {
    type Item = Result<Tick, ReadError>;

    fn next(&mut self) -> Option<Self::Item> {
        while !self.replayer.failed {
            let file = self.files.get(self.file)?;
            let records = self.records.get_or_insert_with(|| Box::new(file.records()));
            let Some(record) = records.next() else {
                self.records = None;
                self.file += 1;
                continue;
            };
            let tick = record.and_then(|r| self.replayer.tick(file, r));
            self.replayer.failed = tick.is_err();
            return Some(tick);
        }
        None
    }
}

struct Replayer {
    /// Boxed: a controller is large, and iterator adaptors move their state.
    controller: Option<Result<Box<strand_core::Controller>, String>>,
    expected: u64,
    scratch: CdrWriter,
    failed: bool,
}

impl Replayer {
    fn tick(&mut self, file: &LogFile, r: TickRecord) -> Result<Tick, ReadError> {
        let fail = |message: String| ReadError::Replay { path: file.path.display().to_string(), message };
        let digest = match r.output {
            LoggedOutput::Whole(output) => {
                // A full record: the outputs as logged, nothing to replay.
                return Ok(Tick { input: *r.input, output: *output, timing: r.timing });
            }
            LoggedOutput::Keyframe(_) => r.digest,
            LoggedOutput::Digest(d) => d,
        };
        if r.input.tick != self.expected {
            let hint = if self.expected == 0 {
                "a rotated part of a compact log: its outputs need the parts before it (read them together)"
            } else {
                "ticks were dropped (Status.log_drops): outputs cannot be recomputed past a hole"
            };
            return Err(fail(format!("expected tick {}, found {}: {hint}", self.expected, r.input.tick)));
        }
        let controller = match self.controller.as_mut() {
            Some(Ok(c)) => c,
            Some(Err(e)) => return Err(fail(format!("cannot build the controller to recompute the outputs: {e}"))),
            None => return Err(fail("a compact record after a full one".to_string())),
        };
        let output = controller.step(&r.input);
        let replayed = output_digest(&mut self.scratch, &output);
        if replayed != digest {
            return Err(fail(format!(
                "tick {}: this build does not reproduce the logged output (digest {digest:04x}, replayed {replayed:04x}); the log was \
                 written by strand {}",
                r.input.tick,
                file.meta("version").unwrap_or("(unknown)")
            )));
        }
        self.expected += 1;
        Ok(Tick { input: *r.input, output, timing: r.timing })
    }
}
