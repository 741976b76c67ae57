//! Reading a recording back: checks that each lossless channel holds a
//! layout this build understands, and reads messages in file order up to
//! the end or to the first damaged record (a killed recorder's last chunk,
//! a truncated or corrupted file), which is reported, never a panic.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use crate::channels::{Layout, MESSAGE_ENCODING, Message, Topic};

/// A recording that cannot be read at all.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{path}: {message}")]
pub struct ReadError {
    path: String,
    message: String,
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
    pub counts: BTreeMap<Topic, u64>,
    /// Log time of the first and last lossless message, ns.
    pub time_range: Option<(u64, u64)>,
    /// Messages on other channels (viewing channels).
    pub other_messages: u64,
    /// Set when the file ends early or is corrupt.
    pub damage: Option<Damage>,
}

impl Contents {
    /// Lossless messages in total.
    pub fn total(&self) -> u64 {
        self.counts.values().sum()
    }
}

/// A recording in memory, checked.
pub struct Recording {
    path: PathBuf,
    bytes: Vec<u8>,
    contents: Contents,
}

const MAGIC: &[u8] = b"\x89MCAP0\r\n";

fn options() -> enumset::EnumSet<mcap::read::Options> {
    mcap::read::Options::ValidateChunkCrcs.into()
}

/// Which lossless topic a channel carries, after checking its schema.
fn lossless_topic(channel: &mcap::Channel<'_>) -> Result<Option<Topic>, String> {
    if channel.message_encoding != MESSAGE_ENCODING {
        return Ok(None);
    }
    let Some(topic) = Topic::from_name(&channel.topic) else {
        return Err(format!(
            "channel `{}` is {MESSAGE_ENCODING} but not a topic this build knows",
            channel.topic
        ));
    };
    let expected = topic.layout();
    let found: Option<Layout> = channel
        .schema
        .as_ref()
        .and_then(|s| serde_json::from_slice(&s.data).ok());
    match found {
        Some(found) if found.type_name == expected.type_name && found.size == expected.size => {
            Ok(Some(topic))
        }
        Some(found) => Err(format!(
            "channel `{}` was recorded as {} ({} bytes); this build reads {} ({} bytes): \
             replay it with the version that recorded it",
            channel.topic, found.type_name, found.size, expected.type_name, expected.size
        )),
        None => Err(format!(
            "channel `{}` has no readable layout schema",
            channel.topic
        )),
    }
}

impl Recording {
    /// Reads and scans `path`.
    pub fn open(path: impl AsRef<Path>) -> Result<Self, ReadError> {
        let path = path.as_ref().to_path_buf();
        let fail = |message: String| ReadError {
            path: path.display().to_string(),
            message,
        };
        let bytes = std::fs::read(&path).map_err(|e| fail(format!("cannot read: {e}")))?;
        let mut recording = Self {
            path: path.clone(),
            bytes,
            contents: Contents::default(),
        };
        let mut contents = Contents::default();
        recording
            .visit(
                |log_time, message| {
                    *contents.counts.entry(message.topic()).or_default() += 1;
                    contents.time_range = Some(match contents.time_range {
                        None => (log_time, log_time),
                        Some((a, b)) => (a.min(log_time), b.max(log_time)),
                    });
                    Ok::<_, String>(true)
                },
                |n| contents.other_messages = n,
                |damage| contents.damage = Some(damage),
            )
            .map_err(fail)?;
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
    /// `Ok(false)` or the readable part ends.
    pub fn for_each<E: From<String>>(
        &self,
        f: impl FnMut(u64, Message<'_>) -> Result<bool, E>,
    ) -> Result<(), E> {
        self.visit(f, |_| {}, |_| {})
    }

    fn visit<E: From<String>>(
        &self,
        mut f: impl FnMut(u64, Message<'_>) -> Result<bool, E>,
        others: impl FnOnce(u64),
        on_damage: impl FnOnce(Damage),
    ) -> Result<(), E> {
        if !self.bytes.starts_with(MAGIC) {
            return Err(
                String::from("not an MCAP file (it does not start with the MCAP magic)").into(),
            );
        }
        let stream = mcap::MessageStream::new_with_options(&self.bytes, options())
            .map_err(|e| format!("not a readable MCAP file: {e}"))?;
        let (mut read, mut other) = (0u64, 0u64);
        let mut topics: BTreeMap<u16, Option<Topic>> = BTreeMap::new();
        for item in stream {
            let message = match item {
                Ok(m) => m,
                Err(e) => {
                    on_damage(Damage {
                        after_messages: read,
                        error: e.to_string(),
                    });
                    break;
                }
            };
            let topic = match topics.get(&message.channel.id) {
                Some(t) => *t,
                None => {
                    let t = lossless_topic(&message.channel)?;
                    topics.insert(message.channel.id, t);
                    t
                }
            };
            let Some(topic) = topic else {
                other += 1;
                continue;
            };
            let decoded = Message::decode(topic, &message.data).map_err(|e| {
                format!(
                    "message {} on `{}`: {e}",
                    message.sequence, message.channel.topic
                )
            })?;
            read += 1;
            if !f(message.log_time, decoded)? {
                break;
            }
        }
        others(other);
        Ok(())
    }
}
