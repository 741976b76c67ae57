//! The writer thread: takes recorded messages from the IPC thread over two
//! bounded crossbeam channels (small messages, frames), writes them and the
//! viewing messages derived from them into one MCAP file, finishes a chunk
//! at least once a second, and feeds the live view.

use std::collections::{BTreeMap, HashMap};
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use crossbeam_channel::{Receiver, Sender, bounded};
use mcap::records::MessageHeader;

use crate::channels::{MESSAGE_ENCODING, Message, SCHEMA_ENCODING, TopicId};
use crate::live_view::LiveView;
use crate::view::{ViewBuilder, ViewMessage, ViewTopic};

pub use stages::recorder::Compression;

/// The MCAP writer's compression for `compression`.
fn mcap_compression(compression: Compression) -> Option<mcap::Compression> {
    match compression {
        Compression::Zstd => Some(mcap::Compression::Zstd),
        Compression::Lz4 => Some(mcap::Compression::Lz4),
        Compression::None => None,
    }
}

/// How the writer is set up.
#[derive(Debug, Clone)]
pub struct WriterOptions {
    /// Chunk compression.
    pub compression: Compression,
    /// A chunk is finished when it holds this many bytes (uncompressed)...
    pub chunk_bytes: u64,
    /// ...or this long after the previous one, whichever comes first: a
    /// killed recorder loses at most this much.
    pub flush_every: Duration,
    /// Frames waiting for the writer, at most (each one stereo frame).
    pub frame_queue: usize,
    /// Derive `foxglove.RawImage` viewing channels from frames.
    pub view_images: bool,
    /// `(name, entries)` metadata records.
    pub metadata: Vec<(String, BTreeMap<String, String>)>,
    /// Files to attach (name in the recording, path).
    pub attachments: Vec<(String, PathBuf)>,
}

impl Default for WriterOptions {
    fn default() -> Self {
        Self {
            compression: Compression::Zstd,
            chunk_bytes: 8 << 20,
            flush_every: Duration::from_secs(1),
            frame_queue: 64,
            view_images: true,
            metadata: Vec::new(),
            attachments: Vec::new(),
        }
    }
}

impl WriterOptions {
    /// Adds the `run` metadata record (the prefix, this recorder's version,
    /// what log time means, and `extra` KEY=VALUE entries) and the
    /// `layouts` record (every topic's layout, from the topic table).
    pub fn describe_run(&mut self, prefix: &str, extra: Vec<(String, String)>) {
        let mut run: BTreeMap<String, String> = extra.into_iter().collect();
        run.insert("prefix".into(), prefix.into());
        run.insert("recorder_version".into(), env!("CARGO_PKG_VERSION").into());
        run.insert(
            "log_time".into(),
            "message stamp, CLOCK_MONOTONIC ns".into(),
        );
        // What maps the stamps to wall-clock time (`replay export --ros2`).
        run.insert(
            "wall_minus_monotonic_ns".into(),
            messages::wall_minus_monotonic_ns().to_string(),
        );
        self.metadata.push(("run".into(), run));
        let layouts = TopicId::ALL
            .iter()
            .map(|t| {
                let layout = t.layout();
                (
                    t.name().to_string(),
                    format!("{} ({} bytes)", layout.type_name, layout.size),
                )
            })
            .collect();
        self.metadata.push(("layouts".into(), layouts));
    }

    /// Reads the rig at `path`, stores its text as the `rig` metadata
    /// record and the file as the attachment `rig.toml`, and attaches the
    /// files it refers to (calibration files, URDF) under their names, so
    /// the recording holds the whole robot description. Returns the rig.
    pub fn attach_rig(&mut self, path: &Path) -> Result<geometry::Rig, formats::FormatError> {
        let text = formats::read_text(path)?;
        let rig = formats::rig::parse(path, &text)?;
        let referenced = formats::rig::referenced_files(path, &text)?;
        self.metadata
            .push(("rig".into(), BTreeMap::from([("toml".into(), text)])));
        self.attachments
            .push(("rig.toml".into(), path.to_path_buf()));
        for file in referenced {
            self.attach(&file);
        }
        Ok(rig)
    }

    /// Attaches the file at `path` under its file name.
    pub fn attach(&mut self, path: &Path) {
        let name = path.file_name().map_or_else(
            || path.display().to_string(),
            |n| n.to_string_lossy().into_owned(),
        );
        self.attachments.push((name, path.to_path_buf()));
    }
}

/// One message on its way to the writer: the exact bytes received.
#[derive(Debug)]
pub struct Entry {
    /// Its topic.
    pub topic: TopicId,
    /// Log time (the message stamp), ns.
    pub log_time: u64,
    /// When the recorder received it (CLOCK_MONOTONIC ns).
    pub publish_time: u64,
    /// The bytes.
    pub data: Vec<u8>,
}

/// Counters shared between the IPC thread and the writer thread.
#[derive(Debug, Default)]
pub struct Counters {
    /// Messages written per lossless topic, in [`TopicId::ALL`] order.
    pub written: [AtomicU64; TopicId::COUNT],
    /// Frames dropped because the writer's queue was full.
    pub frames_dropped_queue_full: AtomicU64,
    /// Frames the recorder never received (gaps in the frame sequence:
    /// overwritten in shared memory before it could take them).
    pub frames_missed: AtomicU64,
    /// Messages that failed to decode (recorded anyway, not viewed).
    pub undecodable: AtomicU64,
    /// Bytes of message data written (lossless channels).
    pub lossless_bytes: AtomicU64,
    /// Bytes of message data written (viewing channels).
    pub view_bytes: AtomicU64,
    /// Chunks finished by the once-a-second flush.
    pub timed_flushes: AtomicU64,
}

/// A summary of a finished recording.
#[derive(Debug, Clone, serde::Serialize)]
pub struct RecordingSummary {
    /// The file.
    pub path: PathBuf,
    /// Messages per lossless topic.
    pub messages: BTreeMap<String, u64>,
    /// See [`Counters::frames_dropped_queue_full`].
    pub frames_dropped_queue_full: u64,
    /// See [`Counters::frames_missed`].
    pub frames_missed: u64,
    /// See [`Counters::undecodable`].
    pub undecodable: u64,
    /// Message bytes on lossless channels.
    pub lossless_bytes: u64,
    /// Message bytes on viewing channels.
    pub view_bytes: u64,
    /// Size of the file.
    pub file_bytes: u64,
}

/// Why a recording could not be written.
#[derive(Debug, thiserror::Error)]
pub enum WriterError {
    /// The file could not be created.
    #[error("{}: cannot create", path.display())]
    Create {
        /// The recording.
        path: PathBuf,
        /// The I/O error.
        #[source]
        source: std::io::Error,
    },
    /// A file to attach could not be read.
    #[error("{}: cannot attach", path.display())]
    Attach {
        /// The file to attach.
        path: PathBuf,
        /// The I/O error.
        #[source]
        source: std::io::Error,
    },
    /// Writing the MCAP file failed (the cause says why: disk full, file too large).
    #[error("{}: {what}", path.display())]
    Write {
        /// The recording.
        path: PathBuf,
        /// What was being written.
        what: String,
        /// The MCAP writer's error.
        #[source]
        source: mcap::McapError,
    },
    /// The writer thread could not be started.
    #[error("cannot start the writer thread")]
    Thread(#[source] std::io::Error),
    /// The writer thread panicked.
    #[error("the writer thread panicked")]
    Panicked,
}

impl RecordingSummary {
    /// Writes the recorder's counters where the launcher collects every
    /// stage's (see [`runtime::stats`]).
    pub fn write_stats(&self) {
        let mut stats = runtime::stats::StageStats::new("recorder");
        stats.count("frames_missed", self.frames_missed);
        stats.count("frames_dropped_queue_full", self.frames_dropped_queue_full);
        for (topic, n) in &self.messages {
            stats.count(&format!("{topic}_written"), *n);
        }
        stats.finish();
    }
}

/// The writer thread has stopped (its error comes from [`RecorderHandle::finish`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error("the writer stopped")]
pub struct WriterStopped;

/// The sending side, held by the IPC thread.
pub struct RecorderHandle {
    small: Sender<Entry>,
    frames: Sender<Entry>,
    drop_frames: bool,
    /// Shared counters.
    pub counters: Arc<Counters>,
    failed: Arc<AtomicBool>,
    thread: JoinHandle<Result<(), WriterError>>,
    path: PathBuf,
}

impl RecorderHandle {
    /// Hands a message to the writer. Small messages wait for room; a frame
    /// is dropped (and counted) when `drop_frames` and the queue is full.
    /// Fails once the writer has stopped (its error is returned by
    /// [`RecorderHandle::finish`]).
    pub fn send(&self, entry: Entry) -> Result<(), WriterStopped> {
        if self.failed.load(Ordering::Relaxed) {
            return Err(WriterStopped);
        }
        if entry.topic.carries_frames() {
            if self.drop_frames {
                match self.frames.try_send(entry) {
                    Ok(()) => Ok(()),
                    Err(crossbeam_channel::TrySendError::Full(_)) => {
                        self.counters
                            .frames_dropped_queue_full
                            .fetch_add(1, Ordering::Relaxed);
                        Ok(())
                    }
                    Err(crossbeam_channel::TrySendError::Disconnected(_)) => Err(WriterStopped),
                }
            } else {
                self.frames.send(entry).map_err(|_| WriterStopped)
            }
        } else {
            self.small.send(entry).map_err(|_| WriterStopped)
        }
    }

    /// Closes the queues, waits for the writer to write everything and
    /// finish the file (summary and index), and returns the summary.
    pub fn finish(self) -> Result<RecordingSummary, WriterError> {
        drop(self.small);
        drop(self.frames);
        self.thread.join().map_err(|_| WriterError::Panicked)??;
        let c = &self.counters;
        Ok(RecordingSummary {
            messages: TopicId::ALL
                .iter()
                .zip(&c.written)
                .map(|(t, n)| (t.name().to_string(), n.load(Ordering::Relaxed)))
                .collect(),
            frames_dropped_queue_full: c.frames_dropped_queue_full.load(Ordering::Relaxed),
            frames_missed: c.frames_missed.load(Ordering::Relaxed),
            undecodable: c.undecodable.load(Ordering::Relaxed),
            lossless_bytes: c.lossless_bytes.load(Ordering::Relaxed),
            view_bytes: c.view_bytes.load(Ordering::Relaxed),
            file_bytes: std::fs::metadata(&self.path).map_or(0, |m| m.len()),
            path: self.path,
        })
    }
}

/// Creates `path` and starts the writer thread. `drop_frames` selects the
/// frame policy when the writer falls behind: drop (live) or wait (replay).
pub fn start(
    path: &Path,
    options: WriterOptions,
    view: ViewBuilder,
    live: Option<LiveView>,
    drop_frames: bool,
) -> Result<RecorderHandle, WriterError> {
    let file = File::create(path).map_err(|source| WriterError::Create {
        path: path.to_path_buf(),
        source,
    })?;
    let mut mcap = Mcap::new(BufWriter::with_capacity(1 << 20, file), &options, path)?;
    for (name, attached) in &options.attachments {
        mcap.attach(name, attached)?;
    }
    for (name, entries) in &options.metadata {
        mcap.writer
            .write_metadata(&mcap::records::Metadata {
                name: name.clone(),
                metadata: entries.clone(),
            })
            .map_err(mcap.failed(format!("writing metadata {name}")))?;
    }
    let (small_tx, small_rx) = bounded::<Entry>(16 * 1024);
    let (frames_tx, frames_rx) = bounded::<Entry>(options.frame_queue.max(1));
    let counters = Arc::new(Counters::default());
    let failed = Arc::new(AtomicBool::new(false));
    let thread = {
        let counters = counters.clone();
        let failed = failed.clone();
        let mut view = view;
        view.images = options.view_images;
        std::thread::Builder::new()
            .name("mcap-writer".into())
            .spawn(move || {
                let result = write_loop(
                    &mut mcap, small_rx, frames_rx, &options, view, live, &counters,
                )
                .and_then(|()| mcap.finish());
                if result.is_err() {
                    failed.store(true, Ordering::Relaxed);
                }
                result
            })
            .map_err(WriterError::Thread)?
    };
    Ok(RecorderHandle {
        small: small_tx,
        frames: frames_tx,
        drop_frames,
        counters,
        failed,
        thread,
        path: path.to_path_buf(),
    })
}

fn write_loop(
    mcap: &mut Mcap,
    small: Receiver<Entry>,
    frames: Receiver<Entry>,
    options: &WriterOptions,
    mut view: ViewBuilder,
    live: Option<LiveView>,
    counters: &Counters,
) -> Result<(), WriterError> {
    let mut last_flush = Instant::now();
    let (mut small_open, mut frames_open) = (true, true);
    while small_open || frames_open {
        // Small messages first: they are never dropped and cheap to write.
        let entry = match small.try_recv() {
            Ok(e) => Some(e),
            Err(_) => {
                let wait = options
                    .flush_every
                    .saturating_sub(last_flush.elapsed())
                    .max(Duration::from_millis(1));
                let mut sel = crossbeam_channel::Select::new();
                let si = small_open.then(|| sel.recv(&small));
                let fi = frames_open.then(|| sel.recv(&frames));
                match sel.select_timeout(wait) {
                    Ok(op) if Some(op.index()) == si => match op.recv(&small) {
                        Ok(e) => Some(e),
                        Err(_) => {
                            small_open = false;
                            None
                        }
                    },
                    Ok(op) if Some(op.index()) == fi => match op.recv(&frames) {
                        Ok(e) => Some(e),
                        Err(_) => {
                            frames_open = false;
                            None
                        }
                    },
                    Ok(_) => None,
                    Err(_) => None,
                }
            }
        };
        if let Some(entry) = entry {
            mcap.write_entry(&entry, &mut view, live.as_ref(), counters)?;
        }
        if last_flush.elapsed() >= options.flush_every {
            mcap.writer
                .flush()
                .map_err(mcap.failed("finishing a chunk"))?;
            counters.timed_flushes.fetch_add(1, Ordering::Relaxed);
            last_flush = Instant::now();
        }
    }
    Ok(())
}

/// The MCAP writer with every channel registered up front.
struct Mcap {
    path: PathBuf,
    writer: mcap::Writer<BufWriter<File>>,
    lossless: HashMap<TopicId, (u16, u32)>,
    views: HashMap<ViewTopic, (u16, u32)>,
}

impl Mcap {
    fn new(
        out: BufWriter<File>,
        options: &WriterOptions,
        path: &Path,
    ) -> Result<Self, WriterError> {
        let mut mcap = Self::create(out, options).map_err(|source| WriterError::Write {
            path: path.to_path_buf(),
            what: "starting the file".into(),
            source,
        })?;
        mcap.path = path.to_path_buf();
        Ok(mcap)
    }

    /// The error of `what` failing on this file.
    fn failed(&self, what: impl Into<String>) -> impl FnOnce(mcap::McapError) -> WriterError {
        let (path, what) = (self.path.clone(), what.into());
        move |source| WriterError::Write { path, what, source }
    }

    fn create(out: BufWriter<File>, options: &WriterOptions) -> Result<Self, mcap::McapError> {
        let mut writer = mcap::WriteOptions::new()
            .compression(mcap_compression(options.compression))
            .chunk_size(Some(options.chunk_bytes))
            .profile("")
            .library(format!("recorder {}", env!("CARGO_PKG_VERSION")))
            .create(out)?;
        let mut lossless = HashMap::new();
        for t in TopicId::ALL {
            let schema =
                writer.add_schema(&t.layout().type_name, SCHEMA_ENCODING, &t.schema_data())?;
            let id = writer.add_channel(schema, t.name(), MESSAGE_ENCODING, &BTreeMap::new())?;
            lossless.insert(t, (id, 0));
        }
        let mut views = HashMap::new();
        for v in ViewTopic::ALL {
            let s = v.schema();
            let schema = writer.add_schema(&s.name, &s.encoding, &s.data)?;
            let id = writer.add_channel(
                schema,
                &v.name(),
                &ViewTopic::message_encoding(),
                &BTreeMap::new(),
            )?;
            views.insert(v, (id, 0));
        }
        Ok(Self {
            path: PathBuf::new(),
            writer,
            lossless,
            views,
        })
    }

    fn attach(&mut self, name: &str, path: &Path) -> Result<(), WriterError> {
        let data = std::fs::read(path).map_err(|source| WriterError::Attach {
            path: path.to_path_buf(),
            source,
        })?;
        let now = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.as_nanos() as u64);
        self.writer
            .attach(&mcap::Attachment {
                log_time: now,
                create_time: now,
                name: name.into(),
                media_type: if name.ends_with(".toml") {
                    "application/toml"
                } else if name.ends_with(".csv") {
                    "text/csv"
                } else {
                    "application/octet-stream"
                }
                .into(),
                data: data.into(),
            })
            .map_err(self.failed(format!("attaching {name}")))
    }

    fn write_entry(
        &mut self,
        entry: &Entry,
        view: &mut ViewBuilder,
        live: Option<&LiveView>,
        counters: &Counters,
    ) -> Result<(), WriterError> {
        let (id, seq) = self.lossless.get_mut(&entry.topic).expect("registered");
        *seq += 1;
        self.writer
            .write_to_known_channel(
                &MessageHeader {
                    channel_id: *id,
                    sequence: *seq,
                    log_time: entry.log_time,
                    publish_time: entry.publish_time,
                },
                &entry.data,
            )
            .map_err(|source| WriterError::Write {
                path: self.path.clone(),
                what: format!("writing a {} message", entry.topic.name()),
                source,
            })?;
        counters.written[entry.topic.index()].fetch_add(1, Ordering::Relaxed);
        counters
            .lossless_bytes
            .fetch_add(entry.data.len() as u64, Ordering::Relaxed);
        match Message::decode(entry.topic, &entry.data) {
            Ok(message) => {
                for v in view.view(&message) {
                    self.write_view(&v, entry.publish_time, counters)?;
                    if let Some(live) = live {
                        live.log(&v);
                    }
                }
            }
            Err(_) => {
                counters.undecodable.fetch_add(1, Ordering::Relaxed);
            }
        }
        Ok(())
    }

    fn write_view(
        &mut self,
        v: &ViewMessage,
        publish_time: u64,
        counters: &Counters,
    ) -> Result<(), WriterError> {
        let (id, seq) = self.views.get_mut(&v.topic).expect("registered");
        *seq += 1;
        counters
            .view_bytes
            .fetch_add(v.data.len() as u64, Ordering::Relaxed);
        self.writer
            .write_to_known_channel(
                &MessageHeader {
                    channel_id: *id,
                    sequence: *seq,
                    log_time: v.log_time,
                    publish_time,
                },
                &v.data,
            )
            .map_err(|source| WriterError::Write {
                path: self.path.clone(),
                what: format!("writing {}", v.topic.name()),
                source,
            })
    }

    fn finish(&mut self) -> Result<(), WriterError> {
        self.writer
            .finish()
            .map(|_summary| ())
            .map_err(self.failed("finishing the file (summary and index)"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_rig_is_attached_with_the_files_it_refers_to() {
        let rig =
            Path::new(env!("CARGO_MANIFEST_DIR")).join("../tests/data/rigs/nico_urdf/rig.toml");
        let mut options = WriterOptions::default();
        let read = options.attach_rig(&rig).unwrap();
        assert_eq!(read.arm.unwrap().dof(), 4);
        let names: Vec<&str> = options
            .attachments
            .iter()
            .map(|(n, _)| n.as_str())
            .collect();
        assert_eq!(
            names,
            ["rig.toml", "left.yaml", "right.yaml", "nico_arm.urdf"]
        );
        assert!(options.attachments.iter().all(|(_, p)| p.exists()));
    }
}
