//! An append-only journal of a stage's state, so that a restarted stage
//! resumes with nothing it had collected lost.
//!
//! The journal is an MCAP file of lossless channels, the same encoding as a
//! recording (the exact message bytes, with a layout schema per channel),
//! so `mcap` tools and the recorder's reader open it. Each message is
//! written as its own chunk, with its CRC, and synced to the disk
//! (`fdatasync`) before [`Journal::append`] returns: a stage killed at any
//! moment, or a machine whose power is cut, loses at most the message it
//! was writing. Journals take a message per pose, never per frame, so the
//! sync (0.13 ms an append on our test machine's disk, against 9 us
//! flushed; `cargo bench -p runtime --bench journal`) is paid a few
//! times a second at most. [`Durability::SyncedBehind`] hands each message
//! to the operating system before `append` returns and syncs it from a
//! thread of its own right after, for a stage whose append is on a latency
//! path: while another process fills the disk's cache, one `fdatasync` can
//! wait tens of milliseconds. [`Durability::Flushed`] hands each message to
//! the operating system only.
//!
//! [`Journal::open`] reads what an earlier run wrote up to the first
//! incomplete or damaged chunk (a kill in the middle of a write), says what
//! it dropped, rewrites the complete records into a fresh file, and appends
//! after them.
//!
//! ```no_run
//! use runtime::journal::Journal;
//! use messages::topics::{self, Topic};
//! let (mut journal, recovered) = Journal::open("journal.mcap", &[topics::Samples::ID])?;
//! let samples: Vec<messages::MirrorSample> = recovered.messages::<topics::Samples>().collect();
//! journal.append::<topics::Samples>(&messages::MirrorSample::default())?;
//! # Ok::<(), runtime::journal::JournalError>(())
//! ```

use std::collections::{BTreeMap, HashMap};
use std::fs::File;
use std::io::{BufWriter, Read};
use std::path::{Path, PathBuf};

use mcap::records::{MessageHeader, Record};
use mcap::sans_io::{LinearReadEvent, LinearReader, LinearReaderOptions};

use messages::one_line;
use messages::topics::{Layout, MESSAGE_ENCODING, SCHEMA_ENCODING, SmallTopic, TopicId};

/// Largest record accepted when reading: a damaged length must not make the
/// reader allocate without bound (journals hold small messages).
const RECORD_LIMIT: usize = 16 << 20;

/// A journal that cannot be opened, read or written.
#[derive(Debug, thiserror::Error)]
pub enum JournalError {
    /// The file could not be read, created or renamed.
    #[error("{}: {what}", path.display())]
    Io {
        /// The journal.
        path: PathBuf,
        /// What was being done.
        what: &'static str,
        /// The cause.
        #[source]
        source: std::io::Error,
    },
    /// Writing MCAP failed.
    #[error("{}: {what}", path.display())]
    Mcap {
        /// The journal.
        path: PathBuf,
        /// What was being done.
        what: &'static str,
        /// The cause.
        #[source]
        source: mcap::McapError,
    },
    /// The journal holds a channel this build does not read the same way:
    /// resuming from it would misread the state.
    #[error("{}: {message}", path.display())]
    Foreign {
        /// The journal.
        path: PathBuf,
        /// What does not match.
        message: String,
    },
}

/// One journaled message.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Entry {
    /// Its topic.
    pub topic: TopicId,
    /// Its bytes, as they travel.
    pub bytes: Vec<u8>,
}

/// What [`Journal::open`] found of an earlier run.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Recovered {
    /// The complete messages, in the order they were written.
    pub entries: Vec<Entry>,
    /// Set when the file ended in an incomplete or damaged record, which
    /// was dropped: what the reader found there.
    pub dropped: Option<String>,
}

impl Recovered {
    /// The recovered messages of topic `T`, in order.
    pub fn messages<T: SmallTopic>(&self) -> impl Iterator<Item = T::Message> + '_ {
        self.entries
            .iter()
            .filter(|e| e.topic == T::ID && e.bytes.len() == size_of::<T::Message>())
            .map(|e| bytemuck::pod_read_unaligned(&e.bytes))
    }
}

/// How far each appended message goes before [`Journal::append`] returns.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Durability {
    /// To the disk (`fdatasync`): survives a killed process and a power cut.
    #[default]
    Synced,
    /// To the operating system, and to the disk moments later: a thread of
    /// the journal's own syncs whatever was appended since its last sync
    /// (one sync for several appends when they come fast). Survives a
    /// killed process; a power cut loses what was appended in the last sync
    /// (a sync takes 0.1 ms, up to tens of ms while another process fills
    /// the disk's cache). For a stage whose append is on a latency path.
    SyncedBehind,
    /// To the operating system: survives a killed process, not a power cut.
    Flushed,
}

/// What the journal's sync thread and its appender share.
#[derive(Debug, Default)]
struct SyncState {
    /// Appends handed to the operating system.
    written: u64,
    /// Appends known to be on the disk.
    synced: u64,
    /// The last sync's failure, reported by the next append.
    failed: Option<std::io::Error>,
    /// Set when the journal closes: sync what is left, then stop.
    closing: bool,
}

/// The thread behind [`Durability::SyncedBehind`].
struct BackgroundSync {
    shared: std::sync::Arc<(std::sync::Mutex<SyncState>, std::sync::Condvar)>,
    thread: Option<std::thread::JoinHandle<()>>,
}

impl BackgroundSync {
    fn start(file: File) -> std::io::Result<Self> {
        let shared = std::sync::Arc::new((
            std::sync::Mutex::new(SyncState::default()),
            std::sync::Condvar::new(),
        ));
        let theirs = shared.clone();
        let thread = std::thread::Builder::new()
            .name("journal sync".into())
            .spawn(move || sync_loop(&file, &theirs))?;
        Ok(Self {
            shared,
            thread: Some(thread),
        })
    }

    /// Hands the sync thread one more append; an error if its last sync
    /// failed.
    fn written(&self) -> std::io::Result<()> {
        let (state, wake) = &*self.shared;
        let mut state = state.lock().unwrap_or_else(|p| p.into_inner());
        if let Some(e) = state.failed.take() {
            return Err(e);
        }
        state.written += 1;
        wake.notify_all();
        Ok(())
    }

    /// Waits until every append so far is on the disk.
    fn wait(&self) -> std::io::Result<()> {
        let (state, wake) = &*self.shared;
        let mut state = state.lock().unwrap_or_else(|p| p.into_inner());
        while state.synced < state.written && state.failed.is_none() {
            state = wake.wait(state).unwrap_or_else(|p| p.into_inner());
        }
        state.failed.take().map_or(Ok(()), Err)
    }
}

impl Drop for BackgroundSync {
    fn drop(&mut self) {
        let (state, wake) = &*self.shared;
        state.lock().unwrap_or_else(|p| p.into_inner()).closing = true;
        wake.notify_all();
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}

fn sync_loop(file: &File, shared: &(std::sync::Mutex<SyncState>, std::sync::Condvar)) {
    let (state, wake) = shared;
    loop {
        let target = {
            let mut s = state.lock().unwrap_or_else(|p| p.into_inner());
            while s.synced == s.written && !s.closing {
                s = wake.wait(s).unwrap_or_else(|p| p.into_inner());
            }
            if s.synced == s.written {
                return;
            }
            s.written
        };
        let result = file.sync_data();
        let mut s = state.lock().unwrap_or_else(|p| p.into_inner());
        s.synced = target;
        if let Err(e) = result {
            s.failed = Some(e);
        }
        wake.notify_all();
    }
}

/// An open journal, appending.
pub struct Journal {
    path: PathBuf,
    writer: mcap::Writer<BufWriter<File>>,
    /// The same open file, to sync what the writer flushed.
    file: File,
    durability: Durability,
    /// The sync thread, with [`Durability::SyncedBehind`].
    background: Option<BackgroundSync>,
    channels: HashMap<TopicId, u16>,
    sequence: u32,
}

impl Journal {
    /// Opens the journal at `path` for the small-message `topics`: recovers
    /// what an earlier run wrote (if the file exists), rewrites it without a
    /// damaged tail, and appends from there.
    pub fn open(
        path: impl AsRef<Path>,
        topics: &[TopicId],
    ) -> Result<(Self, Recovered), JournalError> {
        Self::open_with(path, topics, Durability::default())
    }

    /// [`Journal::open`], each append going as far as `durability` says.
    pub fn open_with(
        path: impl AsRef<Path>,
        topics: &[TopicId],
        durability: Durability,
    ) -> Result<(Self, Recovered), JournalError> {
        let path = path.as_ref().to_path_buf();
        let recovered = if path.exists() {
            read(&path)?
        } else {
            Recovered::default()
        };
        let fresh = path.with_extension("mcap.new");
        let mut journal = Self::create(&fresh, &path, topics)?;
        for e in &recovered.entries {
            journal.write(e.topic, &e.bytes, Durability::Flushed)?;
        }
        journal.durability = durability;
        // The copy reaches the disk before it replaces the original, and
        // the rename before anything is appended.
        if durability != Durability::Flushed {
            journal.sync()?;
        }
        std::fs::rename(&fresh, &path).map_err(|source| JournalError::Io {
            path: path.clone(),
            what: "cannot replace it with its recovered copy",
            source,
        })?;
        if durability != Durability::Flushed {
            sync_directory_of(&path)?;
        }
        if durability == Durability::SyncedBehind {
            let started = journal
                .file
                .try_clone()
                .and_then(BackgroundSync::start)
                .map_err(|source| JournalError::Io {
                    path: path.clone(),
                    what: "cannot start its sync thread",
                    source,
                })?;
            journal.background = Some(started);
        }
        Ok((journal, recovered))
    }

    fn create(file: &Path, path: &Path, topics: &[TopicId]) -> Result<Self, JournalError> {
        let mcap_error = |what| {
            let path = path.to_path_buf();
            move |source| JournalError::Mcap { path, what, source }
        };
        let io_error = |what| {
            let path = path.to_path_buf();
            move |source| JournalError::Io { path, what, source }
        };
        let out = File::create(file).map_err(io_error("cannot create"))?;
        let sync_handle = out.try_clone().map_err(io_error("cannot create"))?;
        // One chunk per message (finished by the flush after each append),
        // uncompressed: each record carries its own CRC and is complete on
        // its own.
        let mut writer = mcap::WriteOptions::new()
            .compression(None)
            .chunk_size(None)
            .profile("")
            .library(format!("journal {}", env!("CARGO_PKG_VERSION")))
            .create(BufWriter::new(out))
            .map_err(mcap_error("cannot start"))?;
        let mut channels = HashMap::new();
        for &t in topics {
            let schema = writer
                .add_schema(&t.layout().type_name, SCHEMA_ENCODING, &t.schema_data())
                .map_err(mcap_error("cannot add a schema"))?;
            let id = writer
                .add_channel(schema, t.name(), MESSAGE_ENCODING, &BTreeMap::new())
                .map_err(mcap_error("cannot add a channel"))?;
            channels.insert(t, id);
        }
        writer.flush().map_err(mcap_error("cannot write"))?;
        Ok(Self {
            path: path.to_path_buf(),
            writer,
            file: sync_handle,
            durability: Durability::Flushed,
            background: None,
            channels,
            sequence: 0,
        })
    }

    /// Appends `message` on topic `T`; it is on the disk (or with the
    /// operating system, see [`Durability`]) when this returns.
    pub fn append<T: SmallTopic>(&mut self, message: &T::Message) -> Result<(), JournalError> {
        self.write(T::ID, bytemuck::bytes_of(message), self.durability)
    }

    fn sync(&mut self) -> Result<(), JournalError> {
        self.file.sync_data().map_err(|e| self.sync_failed(e))
    }

    fn sync_failed(&self, source: std::io::Error) -> JournalError {
        JournalError::Io {
            path: self.path.clone(),
            what: "cannot sync to disk",
            source,
        }
    }

    /// Waits until everything appended is on the disk (at once unless the
    /// journal syncs behind, see [`Durability::SyncedBehind`]).
    pub fn wait_synced(&self) -> Result<(), JournalError> {
        let Some(background) = &self.background else {
            return Ok(());
        };
        background.wait().map_err(|e| self.sync_failed(e))
    }

    fn write(
        &mut self,
        topic: TopicId,
        bytes: &[u8],
        durability: Durability,
    ) -> Result<(), JournalError> {
        let Some(&channel_id) = self.channels.get(&topic) else {
            return Err(JournalError::Foreign {
                path: self.path.clone(),
                message: format!("topic `{}` is not journaled here", topic.name()),
            });
        };
        self.sequence += 1;
        let mcap_error = |what| {
            let path = self.path.clone();
            move |source| JournalError::Mcap { path, what, source }
        };
        self.writer
            .write_to_known_channel(
                &MessageHeader {
                    channel_id,
                    sequence: self.sequence,
                    log_time: 0,
                    publish_time: 0,
                },
                bytes,
            )
            .map_err(mcap_error("cannot append"))?;
        self.writer.flush().map_err(mcap_error("cannot append"))?;
        match (durability, &self.background) {
            (Durability::Synced, _) => self.sync()?,
            (Durability::SyncedBehind, Some(background)) => {
                background.written().map_err(|e| self.sync_failed(e))?
            }
            _ => {}
        }
        Ok(())
    }

    /// The journal's file.
    pub fn path(&self) -> &Path {
        &self.path
    }
}

/// Syncs the directory holding `path`, so that a rename into it survives a
/// power cut.
fn sync_directory_of(path: &Path) -> Result<(), JournalError> {
    let dir = match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    File::open(dir)
        .and_then(|d| d.sync_all())
        .map_err(|source| JournalError::Io {
            path: path.to_path_buf(),
            what: "cannot sync its directory",
            source,
        })
}

/// Reads the complete messages of the journal at `path`, stopping at the
/// first record that is incomplete or whose chunk fails its CRC.
pub fn read(path: &Path) -> Result<Recovered, JournalError> {
    let mut recovered = read_messages(path)?;
    if recovered.dropped.is_none() {
        recovered.dropped = torn_tail(path)?;
    }
    Ok(recovered)
}

/// What follows the last complete record, if anything: the MCAP reader
/// takes a file that ends right after a record's opcode and length as
/// ending cleanly, so the top-level records are measured against the file.
fn torn_tail(path: &Path) -> Result<Option<String>, JournalError> {
    let io_error = |what| {
        let path = path.to_path_buf();
        move |source| JournalError::Io { path, what, source }
    };
    let mut file = File::open(path).map_err(io_error("cannot read"))?;
    let length = file.metadata().map_err(io_error("cannot read"))?.len();
    let mut reader = LinearReader::new_with_options(
        LinearReaderOptions::default()
            .with_skip_end_magic(true)
            .with_emit_chunks(true)
            .with_record_length_limit(RECORD_LIMIT),
    );
    let magic = 8;
    let mut complete = magic;
    while let Some(event) = reader.next_event() {
        match event {
            Err(_) => break,
            Ok(LinearReadEvent::ReadRequest(need)) => {
                let n = file
                    .read(reader.insert(need))
                    .map_err(io_error("cannot read"))?;
                reader.notify_read(n);
            }
            Ok(LinearReadEvent::Record { data, .. }) => complete += 1 + 8 + data.len() as u64,
        }
    }
    // A journal closed cleanly ends with the footer and the end magic.
    let tail = length.saturating_sub(complete);
    Ok((tail > 0 && tail != magic)
        .then(|| format!("{tail} bytes of an incomplete record at the end")))
}

fn read_messages(path: &Path) -> Result<Recovered, JournalError> {
    let io_error = |what| {
        let path = path.to_path_buf();
        move |source| JournalError::Io { path, what, source }
    };
    let mut file = File::open(path).map_err(io_error("cannot read"))?;
    let mut reader = LinearReader::new_with_options(
        // A journal of a killed stage has no footer: the end of its last
        // complete record is a clean end.
        LinearReaderOptions::default()
            .with_skip_end_magic(true)
            .with_prevalidate_chunk_crcs(true)
            .with_record_length_limit(RECORD_LIMIT),
    );
    let mut recovered = Recovered::default();
    let mut schemas: HashMap<u16, Vec<u8>> = HashMap::new();
    let mut channels: HashMap<u16, TopicId> = HashMap::new();
    while let Some(event) = reader.next_event() {
        let (opcode, data) = match event {
            Err(e) => {
                recovered.dropped = Some(one_line(&e.to_string()));
                break;
            }
            Ok(LinearReadEvent::ReadRequest(need)) => {
                let n = file
                    .read(reader.insert(need))
                    .map_err(io_error("cannot read"))?;
                // 0 is the end of the file: the reader says whether it came
                // in the middle of a record.
                reader.notify_read(n);
                continue;
            }
            Ok(LinearReadEvent::Record { opcode, data }) => (opcode, data),
        };
        let record = match mcap::parse_record(opcode, data) {
            Ok(record) => record,
            Err(e) => {
                recovered.dropped = Some(one_line(&e.to_string()));
                break;
            }
        };
        match record {
            Record::Schema { header, data } => {
                schemas.insert(header.id, data.into_owned());
            }
            Record::Channel(channel) => {
                let topic = journaled_topic(path, &channel, schemas.get(&channel.schema_id))?;
                channels.insert(channel.id, topic);
            }
            Record::Message { header, data } => {
                let Some(&topic) = channels.get(&header.channel_id) else {
                    recovered.dropped = Some(format!(
                        "message {} on channel {} that was never declared",
                        header.sequence, header.channel_id
                    ));
                    break;
                };
                recovered.entries.push(Entry {
                    topic,
                    bytes: data.into_owned(),
                });
            }
            _ => {}
        }
    }
    Ok(recovered)
}

/// The topic of a journal channel, if this build reads its layout.
fn journaled_topic(
    path: &Path,
    channel: &mcap::records::Channel,
    schema: Option<&Vec<u8>>,
) -> Result<TopicId, JournalError> {
    let foreign = |message: String| JournalError::Foreign {
        path: path.to_path_buf(),
        message,
    };
    let name = one_line(&channel.topic);
    let topic = TopicId::from_name(&channel.topic)
        .filter(|t| !t.carries_frames() && channel.message_encoding == MESSAGE_ENCODING)
        .ok_or_else(|| foreign(format!("channel `{name}` is not a journal topic")))?;
    let expected = topic.layout();
    match schema.and_then(|data| serde_json::from_slice::<Layout>(data).ok()) {
        Some(found) if found == expected => Ok(topic),
        Some(found) => Err(foreign(format!(
            "channel `{name}` was journaled as {} ({} bytes); this build reads {} ({} bytes): \
             resume with the version that wrote it, or start a new journal",
            one_line(&found.type_name),
            found.size,
            expected.type_name,
            expected.size
        ))),
        None => Err(foreign(format!(
            "channel `{name}` has no readable layout schema"
        ))),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use messages::topics::{self, Topic};
    use messages::{CalibrationMsg, MirrorSample};

    fn sample(pose: u64) -> MirrorSample {
        MirrorSample {
            pose,
            stamp_ns: 1_000 * pose as i64,
            dof: 4,
            q: [0.25 * pose as f64; messages::MAX_JOINTS],
            ..Default::default()
        }
    }

    const TOPICS: [TopicId; 2] = [topics::Samples::ID, topics::Calibration::ID];

    /// Writes samples 0..n and a calibration after the third; returns the
    /// file's length after each message.
    fn write(path: &Path, n: u64) -> Vec<u64> {
        let (mut journal, recovered) = Journal::open(path, &TOPICS).unwrap();
        assert_eq!(recovered, Recovered::default());
        let mut ends = Vec::new();
        for pose in 0..n {
            journal.append::<topics::Samples>(&sample(pose)).unwrap();
            ends.push(std::fs::metadata(path).unwrap().len());
            if pose == 2 {
                let calibration = CalibrationMsg {
                    revision: 1,
                    samples: 3,
                    ..Default::default()
                };
                journal.append::<topics::Calibration>(&calibration).unwrap();
                ends.push(std::fs::metadata(path).unwrap().len());
            }
        }
        ends
    }

    #[test]
    fn a_journal_reopens_with_everything_and_appends_after_it() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("journal.mcap");
        write(&path, 5);
        let (mut journal, recovered) = Journal::open(&path, &TOPICS).unwrap();
        assert_eq!(recovered.dropped, None);
        let poses: Vec<u64> = recovered
            .messages::<topics::Samples>()
            .map(|s| s.pose)
            .collect();
        assert_eq!(poses, vec![0, 1, 2, 3, 4]);
        assert_eq!(
            recovered.messages::<topics::Samples>().nth(4),
            Some(sample(4))
        );
        let revisions: Vec<u64> = recovered
            .messages::<topics::Calibration>()
            .map(|c| c.revision)
            .collect();
        assert_eq!(revisions, vec![1]);
        assert_eq!(recovered.entries[3].topic, TopicId::Calibration);
        journal.append::<topics::Samples>(&sample(5)).unwrap();
        drop(journal);
        let again = read(&path).unwrap();
        assert_eq!(again.entries.len(), 7);
        assert_eq!(again.dropped, None);
    }

    #[test]
    fn a_torn_last_record_is_dropped_at_every_byte_and_the_rest_kept() {
        let dir = tempfile::tempdir().unwrap();
        let whole = dir.path().join("whole.mcap");
        let ends = write(&whole, 4);
        let bytes = std::fs::read(&whole).unwrap();
        // The journal was closed cleanly (a summary and footer follow the
        // records); a kill leaves the file ending anywhere in a record.
        let (last_start, last_end) = (ends[ends.len() - 2], ends[ends.len() - 1]);
        // The last append wrote the message's chunk (with its CRC), then the
        // chunk's index. A cut anywhere in the chunk loses that message and
        // keeps the four before; a cut in the index after it keeps all five.
        let path = dir.path().join("torn.mcap");
        let mut chunk_end = None;
        for cut in last_start..last_end {
            std::fs::write(&path, &bytes[..cut as usize]).unwrap();
            let (_journal, recovered) = Journal::open(&path, &TOPICS).unwrap();
            let poses: Vec<u64> = recovered
                .messages::<topics::Samples>()
                .map(|s| s.pose)
                .collect();
            match recovered.entries.len() {
                4 => {
                    assert!(chunk_end.is_none(), "cut at {cut}: lost after kept");
                    assert_eq!(poses, vec![0, 1, 2], "cut at {cut}");
                }
                5 => {
                    let end = *chunk_end.get_or_insert(cut);
                    assert_eq!(poses, vec![0, 1, 2, 3], "cut at {cut}");
                    assert!(cut == end || recovered.dropped.is_some(), "cut at {cut}");
                }
                n => panic!("cut at {cut}: {n} entries"),
            }
            if cut > last_start && recovered.entries.len() == 4 {
                assert!(recovered.dropped.is_some(), "cut at {cut}: no warning");
            }
            // The rewritten journal is whole again.
            assert_eq!(read(&path).unwrap().dropped, None, "cut at {cut}");
        }
        let chunk_end = chunk_end.expect("the chunk ends before its index");
        assert!(chunk_end - last_start > size_of::<MirrorSample>() as u64);
        std::fs::write(&path, &bytes).unwrap();
        let (_journal, recovered) = Journal::open(&path, &TOPICS).unwrap();
        assert_eq!(recovered.entries.len(), 5);
    }

    #[test]
    fn a_journal_synced_behind_has_each_append_in_the_file_when_it_returns() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("journal.mcap");
        let (mut journal, _) =
            Journal::open_with(&path, &TOPICS, Durability::SyncedBehind).unwrap();
        for pose in 0..200 {
            journal.append::<topics::Samples>(&sample(pose)).unwrap();
            // What a killed stage leaves: the file as it is now.
            if pose % 50 == 0 {
                let poses: Vec<u64> = read(&path)
                    .unwrap()
                    .messages::<topics::Samples>()
                    .map(|s| s.pose)
                    .collect();
                assert_eq!(poses, (0..=pose).collect::<Vec<_>>());
            }
        }
        journal.wait_synced().unwrap();
        let shared = &journal.background.as_ref().unwrap().shared;
        let state = shared.0.lock().unwrap();
        assert_eq!((state.written, state.synced), (200, 200));
        drop(state);
        drop(journal);
        let (_, recovered) = Journal::open(&path, &TOPICS).unwrap();
        assert_eq!(recovered.messages::<topics::Samples>().count(), 200);
        assert_eq!(recovered.dropped, None);
    }

    #[test]
    fn a_failed_background_sync_is_reported() {
        // fsync of a character device fails (EINVAL).
        let sync = BackgroundSync::start(File::open("/dev/null").unwrap()).unwrap();
        sync.written().unwrap();
        assert!(sync.wait().is_err());
        sync.written().unwrap();
        let (state, wake) = &*sync.shared;
        let mut s = state.lock().unwrap();
        while s.synced < s.written {
            s = wake.wait(s).unwrap();
        }
        drop(s);
        assert!(
            sync.written().is_err(),
            "the failure reaches the next append"
        );
    }

    #[test]
    fn a_journal_of_another_layout_is_refused() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("journal.mcap");
        let mut writer = mcap::WriteOptions::new()
            .create(BufWriter::new(File::create(&path).unwrap()))
            .unwrap();
        let layout = serde_json::to_vec(&Layout {
            type_name: "mirror.MirrorSample.v0".into(),
            ..TopicId::Samples.layout()
        })
        .unwrap();
        let schema = writer
            .add_schema("mirror.MirrorSample.v0", SCHEMA_ENCODING, &layout)
            .unwrap();
        writer
            .add_channel(schema, "samples", MESSAGE_ENCODING, &BTreeMap::new())
            .unwrap();
        writer.finish().unwrap();
        drop(writer);
        let e = Journal::open(&path, &TOPICS).err().unwrap().to_string();
        assert!(
            e.contains("mirror.MirrorSample.v0") && e.contains("mirror.MirrorSample.v1"),
            "{e}"
        );
    }
}
