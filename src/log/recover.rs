//! Salvages a log that a crash (kill -9, power loss) left without its summary: copies the metadata,
//! the attachments and every message of every closed chunk into a new, finished and indexed file.
//! What the open chunk held is lost; the writer closes a chunk at least every `chunk_interval`, so
//! that is at most 100 ms of ticks.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::BufWriter;
use std::path::Path;

use mcap::records::Metadata;
use mcap::{Attachment, WriteOptions};

use super::reader::{LogFile, ReadError};

/// What a recovery found.
#[derive(Clone, Debug, Default)]
pub struct Recovered {
    /// Messages copied.
    pub messages: u64,
    /// Messages per topic.
    pub per_topic: BTreeMap<String, u64>,
    /// Log time of the last message (ns).
    pub last_log_time: u64,
    /// The input was already finished (nothing to recover, copied anyway).
    pub was_finished: bool,
    /// Attachments copied.
    pub attachments: usize,
}

/// Rewrites `input` into `output`.
pub fn recover(input: &Path, output: &Path) -> Result<Recovered, ReadError> {
    let log = LogFile::open(input)?;
    let io = |e: &dyn std::fmt::Display| ReadError::File { path: output.display().to_string(), message: e.to_string() };
    let file = File::create(output).map_err(|e| io(&e))?;
    let mut w = WriteOptions::new().compression_threads(0).profile("ros2").create(BufWriter::new(file)).map_err(|e| io(&e))?;
    let mut report = Recovered { was_finished: log.finished, ..Default::default() };
    if !log.metadata.is_empty() {
        let mut meta = log.metadata.clone();
        meta.insert("recovered_from".to_string(), input.display().to_string());
        w.write_metadata(&Metadata { name: super::names::METADATA.to_string(), metadata: meta }).map_err(|e| io(&e))?;
    }
    for a in &log.attachments {
        w.attach(&Attachment {
            log_time: 0,
            create_time: 0,
            name: a.name.clone(),
            media_type: a.media_type.clone(),
            data: std::borrow::Cow::Borrowed(&a.data),
        })
        .map_err(|e| io(&e))?;
        report.attachments += 1;
    }
    for m in log.messages() {
        w.write(&m).map_err(|e| io(&e))?;
        report.messages += 1;
        *report.per_topic.entry(m.channel.topic.clone()).or_default() += 1;
        report.last_log_time = report.last_log_time.max(m.log_time);
    }
    w.finish().map_err(|e| io(&e))?;
    Ok(report)
}
