//! Reading a recording back: checks that each lossless channel holds a
//! layout this build understands, and reads messages in file order up to
//! the end or to the first damaged record (a killed recorder's last chunk,
//! a truncated or corrupted file), which is reported, never a panic.

use std::collections::BTreeMap;
use std::io::{Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};

use mcap::records::Record;
use mcap::sans_io::{LinearReadEvent, LinearReader, LinearReaderOptions};
use messages::one_line;

use crate::channels::{Layout, MESSAGE_ENCODING, Message, TopicId};

/// A recording that cannot be read at all.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{path}: {message}")]
pub struct ReadError {
    path: String,
    message: String,
}

impl ReadError {
    /// The error for `path`. Text taken from the file (channel names, a
    /// parser's message) is kept on one line: control characters are
    /// escaped.
    pub(crate) fn new(path: &Path, message: String) -> Self {
        Self {
            path: path.display().to_string(),
            message: one_line(&message),
        }
    }
}

/// Where reading stopped early, if it did.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Damage {
    /// Lossless messages read before the damage.
    pub after_messages: u64,
    /// What the MCAP reader reported.
    pub error: String,
}

/// What a scan of the file found.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Contents {
    /// Lossless messages per topic.
    pub counts: BTreeMap<TopicId, u64>,
    /// Log time of the first and last lossless message, ns.
    pub time_range: Option<(u64, u64)>,
    /// Messages on other channels (viewing channels).
    pub other_messages: u64,
    /// Lossless messages that do not decode (malformed when published),
    /// skipped.
    pub undecodable: u64,
    /// Pixel bytes (both images) of the largest frame.
    pub largest_frame_bytes: usize,
    /// Set when the file ends early or is corrupt.
    pub damage: Option<Damage>,
}

impl Contents {
    /// Lossless messages in total.
    pub fn total(&self) -> u64 {
        self.counts.values().sum()
    }
}

/// What a recording holds beside its messages.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Extras {
    /// The attached files, `(name, contents)`, in file order (the rig, the
    /// files it refers to, the plan, the run's config).
    pub attachments: Vec<(String, Vec<u8>)>,
    /// The metadata records by name (`run`, `rig`, `layouts`).
    pub metadata: BTreeMap<String, BTreeMap<String, String>>,
}

/// A recording, checked. Reading streams from the file: memory stays at
/// about one chunk whatever the file's size.
pub struct Recording {
    path: PathBuf,
    contents: Contents,
    /// Bytes of the file that may be read: up to the first chunk that
    /// cannot vouch for its contents (see [`trusted_length`]).
    trusted: u64,
}

/// Called with the topic, log time and bytes of each message.
type RawVisitor<'a> = &'a mut dyn FnMut(&str, u64, &[u8]);
/// Called with each attachment and metadata record.
type ExtraVisitor<'a> = &'a mut dyn FnMut(&Record<'_>);

const MAGIC: &[u8] = b"\x89MCAP0\r\n";

/// Opens `path` if it starts with the MCAP magic, positioned at its start.
fn open_mcap(path: &Path) -> Result<std::fs::File, String> {
    let mut file = std::fs::File::open(path).map_err(|e| format!("cannot read: {e}"))?;
    let mut magic = [0u8; 8];
    if file.read_exact(&mut magic).is_err() || magic != MAGIC {
        return Err("not an MCAP file (it does not start with the MCAP magic)".into());
    }
    file.seek(SeekFrom::Start(0))
        .map_err(|e| format!("cannot read: {e}"))?;
    Ok(file)
}
/// How many bytes of the file, from its start, are framed so that every
/// message in them is checked: the offset of the first chunk without a CRC
/// (our recorder always writes one, so a zero there is damage, and MCAP
/// readers skip the check for it) or of the first message outside a chunk,
/// with what was found there; else the whole file.
fn trusted_length(path: &Path) -> Result<(u64, Option<String>), String> {
    let mut file = open_mcap(path)?;
    let mut reader = LinearReader::new_with_options(
        LinearReaderOptions::default()
            .with_emit_chunks(true)
            .with_record_length_limit(RECORD_LIMIT),
    );
    let mut offset = MAGIC.len() as u64;
    while let Some(event) = reader.next_event() {
        let (opcode, data) = match event {
            // Damage the reading pass reports itself.
            Err(_) => break,
            Ok(LinearReadEvent::ReadRequest(need)) => {
                let n = file
                    .read(reader.insert(need))
                    .map_err(|e| format!("cannot read: {e}"))?;
                if n == 0 {
                    break;
                }
                reader.notify_read(n);
                continue;
            }
            Ok(LinearReadEvent::Record { opcode, data }) => (opcode, data),
        };
        let unchecked = match opcode {
            mcap::records::op::CHUNK => match mcap::parse_record(opcode, data) {
                Ok(Record::Chunk { header, .. }) if header.uncompressed_crc == 0 => {
                    Some(format!("the chunk at byte {offset} has no CRC"))
                }
                Ok(_) => None,
                Err(e) => Some(format!("the chunk at byte {offset}: {e}")),
            },
            mcap::records::op::MESSAGE => {
                Some(format!("a message outside a chunk at byte {offset}"))
            }
            _ => None,
        };
        if let Some(why) = unchecked {
            return Ok((offset, Some(why)));
        }
        offset += 1 + 8 + data.len() as u64;
    }
    Ok((u64::MAX, None))
}

/// The largest record or decompressed chunk accepted: a corrupt length
/// field must not make the reader allocate without bound.
const RECORD_LIMIT: usize = 512 << 20;

/// A lossless channel's topic, and the size of the earlier layout it was
/// recorded with, if it was.
type LosslessChannel = (TopicId, Option<usize>);

/// Which lossless topic a channel carries, after checking its schema, and
/// the size of its earlier layout if it was recorded with one.
fn lossless_topic(
    channel: &mcap::records::Channel,
    schema: Option<&(String, Vec<u8>)>,
) -> Result<Option<LosslessChannel>, String> {
    if channel.message_encoding != MESSAGE_ENCODING {
        return Ok(None);
    }
    // Names from the file, on one line whatever bytes they hold.
    let name = one_line(&channel.topic);
    let Some(topic) = TopicId::from_name(&channel.topic) else {
        return Err(format!(
            "channel `{name}` is {MESSAGE_ENCODING} but not a topic this build knows"
        ));
    };
    let found: Option<Layout> = schema.and_then(|(_, data)| serde_json::from_slice(data).ok());
    match found {
        Some(found) => match topic.recorded_as(&found) {
            Ok(legacy) => Ok(Some((topic, legacy))),
            Err(why) => Err(format!(
                "channel `{name}` {}: replay it with the version that recorded it",
                one_line(&why)
            )),
        },
        None => Err(format!("channel `{name}` has no readable layout schema")),
    }
}

impl Recording {
    /// Checks that `path` can be read and starts like an MCAP file, without
    /// scanning it.
    pub fn probe(path: impl AsRef<Path>) -> Result<(), ReadError> {
        let path = path.as_ref();
        let fail = |message: String| ReadError::new(path, message);
        open_mcap(path).map(|_| ()).map_err(fail)
    }

    /// Opens and scans `path`.
    pub fn open(path: impl AsRef<Path>) -> Result<Self, ReadError> {
        let path = path.as_ref().to_path_buf();
        let fail = |message: String| ReadError::new(&path, message);
        let (trusted, unchecked) = trusted_length(&path).map_err(fail)?;
        let mut recording = Self {
            path: path.clone(),
            contents: Contents::default(),
            trusted,
        };
        let mut contents = Contents::default();
        recording.visit(
            |log_time, message| {
                *contents.counts.entry(message.topic()).or_default() += 1;
                if let Message::Frames(_, pixels) = message {
                    contents.largest_frame_bytes = contents.largest_frame_bytes.max(pixels.len());
                }
                contents.time_range = Some(match contents.time_range {
                    None => (log_time, log_time),
                    Some((a, b)) => (a.min(log_time), b.max(log_time)),
                });
                Ok::<_, ReadError>(true)
            },
            |other, undecodable| {
                contents.other_messages = other;
                contents.undecodable = undecodable;
            },
            |damage| contents.damage = Some(damage),
            None,
            None,
        )?;
        // Reading stops where the file stops vouching for its messages.
        if let (Some(why), Some(damage)) = (unchecked, contents.damage.as_mut()) {
            damage.error = format!("{why} ({})", damage.error);
        }
        recording.contents = contents;
        Ok(recording)
    }

    /// The file.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// What the scan found.
    pub fn contents(&self) -> &Contents {
        &self.contents
    }

    /// Calls `f` on each lossless message in file order until it returns
    /// `Ok(false)` or the readable part ends; the file's errors come as
    /// [`ReadError`]s, `f`'s as they are.
    pub fn for_each<E: From<ReadError>>(
        &self,
        f: impl FnMut(u64, Message<'_>) -> Result<bool, E>,
    ) -> Result<(), E> {
        self.visit(f, |_, _| {}, |_| {}, None, None)
    }

    /// Every lossless message, as its bytes, per topic in file order: what
    /// two recordings are compared by.
    pub fn lossless_by_topic(&self) -> Result<BTreeMap<TopicId, Vec<Vec<u8>>>, ReadError> {
        let mut out: BTreeMap<TopicId, Vec<Vec<u8>>> = BTreeMap::new();
        self.for_each(|_, m| {
            out.entry(m.topic()).or_default().push(m.to_bytes());
            Ok::<_, ReadError>(true)
        })?;
        Ok(out)
    }

    /// Calls `f` with the topic, log time and bytes of every message of
    /// every channel (viewing channels too), in file order, up to the end of
    /// the readable part. A lossless message recorded with an earlier layout
    /// comes as this build reads it (zero-filled to the current layout).
    pub fn for_each_raw(&self, mut f: impl FnMut(&str, u64, &[u8])) -> Result<(), ReadError> {
        self.visit(
            |_, _| Ok::<_, ReadError>(true),
            |_, _| {},
            |_| {},
            Some(&mut f),
            None,
        )
    }

    /// The attached files and the metadata records, read in one pass.
    pub fn extras(&self) -> Result<Extras, ReadError> {
        let mut out = Extras::default();
        self.for_each_extra(|r| match r {
            Record::Attachment { header, data, .. } => {
                out.attachments.push((header.name.clone(), data.to_vec()));
            }
            Record::Metadata(m) => {
                out.metadata.insert(m.name.clone(), m.metadata.clone());
            }
            _ => {}
        })?;
        Ok(out)
    }

    /// Calls `f` with each attachment and metadata record of the readable part.
    fn for_each_extra(&self, mut f: impl FnMut(&Record<'_>)) -> Result<(), ReadError> {
        self.visit(
            |_, _| Ok::<_, ReadError>(true),
            |_, _| {},
            |_| {},
            None,
            Some(&mut f),
        )
    }

    /// Reads the trusted part of the file, calling `f` on each lossless
    /// message (until it returns `Ok(false)`), `raw` on every message and
    /// `extras` on every attachment and metadata record; then `on_damage`
    /// if reading stopped at damage, and `others` with the counts of
    /// messages on other channels and of undecodable ones.
    fn visit<E: From<ReadError>>(
        &self,
        mut f: impl FnMut(u64, Message<'_>) -> Result<bool, E>,
        others: impl FnOnce(u64, u64),
        on_damage: impl FnOnce(Damage),
        mut raw: Option<RawVisitor<'_>>,
        mut extras: Option<ExtraVisitor<'_>>,
    ) -> Result<(), E> {
        let fail = |message: String| ReadError::new(&self.path, message);
        let mut file = open_mcap(&self.path).map_err(fail)?.take(self.trusted);
        let mut reader = LinearReader::new_with_options(
            LinearReaderOptions::default()
                .with_prevalidate_chunk_crcs(true)
                .with_record_length_limit(RECORD_LIMIT),
        );
        let (mut read, mut other, mut undecodable) = (0u64, 0u64, 0u64);
        let mut schemas: BTreeMap<u16, (String, Vec<u8>)> = BTreeMap::new();
        let mut channels: BTreeMap<u16, (Option<LosslessChannel>, String)> = BTreeMap::new();
        let mut damage = None;
        while let Some(event) = reader.next_event() {
            let event = match event {
                Ok(e) => e,
                Err(e) => {
                    damage = Some(one_line(&e.to_string()));
                    break;
                }
            };
            let (opcode, data) = match event {
                LinearReadEvent::ReadRequest(need) => {
                    let n = file
                        .read(reader.insert(need))
                        .map_err(|e| fail(format!("cannot read: {e}")))?;
                    if n == 0 {
                        damage = Some("the file ends in the middle of a record".into());
                        break;
                    }
                    reader.notify_read(n);
                    continue;
                }
                LinearReadEvent::Record { opcode, data } => (opcode, data),
            };
            let record = match mcap::parse_record(opcode, data) {
                Ok(r) => r,
                Err(e) => {
                    damage = Some(one_line(&e.to_string()));
                    break;
                }
            };
            match record {
                Record::Schema { header, data } => {
                    schemas.insert(header.id, (header.name, data.into_owned()));
                }
                Record::Channel(channel) => {
                    let topic =
                        lossless_topic(&channel, schemas.get(&channel.schema_id)).map_err(fail)?;
                    channels.insert(channel.id, (topic, channel.topic));
                }
                Record::Message { header, data } => {
                    let Some((topic, name)) = channels.get(&header.channel_id) else {
                        damage = Some(format!(
                            "message {} on channel {} that was never declared",
                            header.sequence, header.channel_id
                        ));
                        break;
                    };
                    if let Some(raw) = raw.as_mut() {
                        let upgraded = match topic {
                            Some((t, Some(size))) => Message::decode_legacy(*t, &data, *size)
                                .ok()
                                .map(|m| m.to_bytes()),
                            _ => None,
                        };
                        raw(name, header.log_time, upgraded.as_deref().unwrap_or(&data));
                    }
                    let Some((topic, legacy)) = *topic else {
                        other += 1;
                        continue;
                    };
                    // A malformed message recorded as published (a frame whose
                    // header does not match its size) is counted and skipped.
                    let decoded = match legacy {
                        None => Message::decode(topic, &data),
                        Some(size) => Message::decode_legacy(topic, &data, size),
                    };
                    let Ok(decoded) = decoded else {
                        undecodable += 1;
                        continue;
                    };
                    read += 1;
                    if !f(header.log_time, decoded)? {
                        break;
                    }
                }
                record @ (Record::Attachment { .. } | Record::Metadata(_)) => {
                    if let Some(extras) = extras.as_mut() {
                        extras(&record);
                    }
                }
                _ => {}
            }
        }
        if let Some(error) = damage {
            on_damage(Damage {
                after_messages: read,
                error,
            });
        }
        others(other, undecodable);
        Ok(())
    }
}
