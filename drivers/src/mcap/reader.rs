//! A streaming MCAP reader over a file: records are read a chunk at a time (memory stays at one
//! chunk however long the recording), messages come with their channel's topic, schema name and
//! per-channel message index, and every error names the file and where it happened.

use std::collections::{BTreeMap, HashMap};
use std::fs::File;
use std::io::Read;
use std::path::{Path, PathBuf};

use mcap::records::Record;
use mcap::sans_io::linear_reader::{LinearReadEvent, LinearReader, LinearReaderOptions};

/// The metadata record `name` of a finished file, found through its summary section (the
/// messages are not read): `Ok(None)` when the file has no summary (the recorder did not finish
/// it) or no such record. Errors name the file.
pub fn summary_metadata(path: &Path, name: &str) -> Result<Option<BTreeMap<String, String>>, ReadError> {
    use std::io::{Seek, SeekFrom};

    use mcap::sans_io::summary_reader::{SummaryReadEvent, SummaryReader};
    let fail = |reason: String| ReadError { path: path.display().to_string(), reason, truncated: false };
    let mut file = File::open(path).map_err(|e| fail(format!("cannot open: {e}")))?;
    let mut reader = SummaryReader::new();
    while let Some(event) = reader.next_event() {
        match event {
            Ok(SummaryReadEvent::ReadRequest(need)) => {
                let read = file.read(reader.insert(need)).map_err(|e| fail(format!("reading the summary: {e}")))?;
                reader.notify_read(read);
            }
            Ok(SummaryReadEvent::SeekRequest(to)) => {
                let at = file.seek(to).map_err(|e| fail(format!("seeking to the summary: {e}")))?;
                reader.notify_seeked(at);
            }
            // No footer or summary: a file the recorder did not finish.
            Err(_) => return Ok(None),
        }
    }
    let Some(summary) = reader.finish() else { return Ok(None) };
    let Some(index) = summary.metadata_indexes.iter().find(|m| m.name == name) else { return Ok(None) };
    // The index spans the whole record: opcode (1 byte), length (8), body.
    let mut record = vec![0u8; usize::try_from(index.length).map_err(|_| fail("metadata record too long".into()))?];
    file.seek(SeekFrom::Start(index.offset)).map_err(|e| fail(format!("seeking to metadata {name}: {e}")))?;
    file.read_exact(&mut record).map_err(|e| fail(format!("reading metadata {name}: {e}")))?;
    if record.len() < 9 {
        return Err(fail(format!("metadata {name}: a record of {} bytes", record.len())));
    }
    match mcap::parse_record(record[0], &record[9..]) {
        Ok(Record::Metadata(metadata)) => Ok(Some(metadata.metadata)),
        Ok(_) => Err(fail(format!("metadata index of {name} points at another record"))),
        Err(e) => Err(fail(format!("metadata {name}: {e}"))),
    }
}

/// A channel as declared in the file.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ChannelInfo {
    /// Channel id.
    pub id: u16,
    /// Topic.
    pub topic: String,
    /// Schema name (`""` without a schema).
    pub schema_name: String,
    /// Schema encoding (`jsonschema`).
    pub schema_encoding: String,
    /// Message encoding (`json`).
    pub message_encoding: String,
}

/// Where a message is: its channel and its index among that channel's messages (0-based).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MessageAt {
    /// Channel id.
    pub channel_id: u16,
    /// Index of the message on its channel, from 0.
    pub index: u64,
    /// Log time, nanoseconds.
    pub log_time: u64,
}

/// What [`McapReader::next`] found.
#[derive(Debug)]
pub enum Item {
    /// A message; its bytes are in the buffer passed to `next`.
    Message(MessageAt),
    /// A metadata record.
    Metadata {
        /// Record name.
        name: String,
        /// Its key-value pairs.
        entries: BTreeMap<String, String>,
    },
}

/// Reading failed; the message names the file.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("{path}: {reason}")]
pub struct ReadError {
    /// The file.
    pub path: String,
    /// What went wrong, and where.
    pub reason: String,
    /// Whether the file ended inside a record (a recording cut off by a crash or a full disk):
    /// everything before was read.
    pub truncated: bool,
}

/// A streaming reader of one MCAP file.
pub struct McapReader {
    path: PathBuf,
    file: File,
    reader: LinearReader,
    schemas: HashMap<u16, (String, String)>,
    channels: HashMap<u16, ChannelInfo>,
    counts: HashMap<u16, u64>,
    last: Option<MessageAt>,
    finished: bool,
}

impl std::fmt::Debug for McapReader {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("McapReader").field("path", &self.path).field("channels", &self.channels.len()).finish()
    }
}

impl McapReader {
    /// Opens `path`.
    pub fn open(path: &Path) -> Result<Self, ReadError> {
        let file = File::open(path).map_err(|e| ReadError {
            path: path.display().to_string(),
            reason: format!("cannot open: {e}"),
            truncated: false,
        })?;
        let options = LinearReaderOptions::default().with_validate_chunk_crcs(true);
        Ok(Self {
            path: path.to_owned(),
            file,
            reader: LinearReader::new_with_options(options),
            schemas: HashMap::new(),
            channels: HashMap::new(),
            counts: HashMap::new(),
            last: None,
            finished: false,
        })
    }

    /// The file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The channel with id `id`, once declared.
    pub fn channel(&self, id: u16) -> Option<&ChannelInfo> {
        self.channels.get(&id)
    }

    /// Channels declared so far.
    pub fn channels(&self) -> impl Iterator<Item = &ChannelInfo> {
        self.channels.values()
    }

    fn error(&self, reason: String, truncated: bool) -> ReadError {
        let at = match self.last.and_then(|m| self.channels.get(&m.channel_id).map(|c| (c, m))) {
            Some((channel, m)) => format!(" (after message {} of channel {})", m.index, channel.topic),
            None => " (before the first message)".to_owned(),
        };
        ReadError { path: self.path.display().to_string(), reason: format!("{reason}{at}"), truncated }
    }

    /// The next message (its bytes copied into `data`) or metadata record; `None` at the end.
    pub fn next(&mut self, data: &mut Vec<u8>) -> Result<Option<Item>, ReadError> {
        if self.finished {
            return Ok(None);
        }
        loop {
            let event = match self.reader.next_event() {
                None => {
                    self.finished = true;
                    return Ok(None);
                }
                Some(Err(mcap::McapError::UnexpectedEof)) => {
                    self.finished = true;
                    return Err(self.error("truncated: the file ends inside a record".to_owned(), true));
                }
                Some(Err(e)) => {
                    self.finished = true;
                    let truncated = matches!(e, mcap::McapError::BadChunkCrc { .. });
                    return Err(self.error(e.to_string(), truncated));
                }
                Some(Ok(event)) => event,
            };
            let (opcode, bytes) = match event {
                LinearReadEvent::ReadRequest(need) => {
                    let buf = self.reader.insert(need);
                    let read = match self.file.read(buf) {
                        Ok(n) => n,
                        Err(e) => {
                            let reason = format!("read failed: {e}");
                            self.finished = true;
                            return Err(self.error(reason, false));
                        }
                    };
                    self.reader.notify_read(read);
                    continue;
                }
                LinearReadEvent::Record { opcode, data } => (opcode, data),
            };
            let record = match mcap::parse_record(opcode, bytes) {
                Ok(record) => record,
                Err(e) => {
                    let reason = format!("bad record (opcode {opcode:#x}): {e}");
                    self.finished = true;
                    return Err(self.error(reason, false));
                }
            };
            match record {
                Record::Schema { header, .. } => {
                    self.schemas.insert(header.id, (header.name, header.encoding));
                }
                Record::Channel(channel) => {
                    let (schema_name, schema_encoding) =
                        self.schemas.get(&channel.schema_id).cloned().unwrap_or_default();
                    self.channels.insert(
                        channel.id,
                        ChannelInfo {
                            id: channel.id,
                            topic: channel.topic,
                            schema_name,
                            schema_encoding,
                            message_encoding: channel.message_encoding,
                        },
                    );
                }
                Record::Message { header, data: message } => {
                    if !self.channels.contains_key(&header.channel_id) {
                        let reason = format!("message on undeclared channel id {}", header.channel_id);
                        self.finished = true;
                        return Err(self.error(reason, false));
                    }
                    let count = self.counts.entry(header.channel_id).or_default();
                    let at = MessageAt { channel_id: header.channel_id, index: *count, log_time: header.log_time };
                    *count += 1;
                    self.last = Some(at);
                    data.clear();
                    data.extend_from_slice(&message);
                    return Ok(Some(Item::Message(at)));
                }
                Record::Metadata(metadata) => {
                    return Ok(Some(Item::Metadata { name: metadata.name, entries: metadata.metadata }));
                }
                _ => {}
            }
        }
    }
}
