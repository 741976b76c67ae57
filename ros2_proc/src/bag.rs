//! rosbag2 bags: a directory holding `metadata.yaml` and one MCAP file,
//! as `ros2 bag record -s mcap` writes it (rosbag2 format version 9,
//! Jazzy): MCAP profile `ros2`, one `ros2msg` schema per type (the
//! definition with its dependencies, from rosbags), `cdr` channels with
//! their offered QoS and type hash, and the `rosbag2` metadata record.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};

use crate::types::RosType;
use crate::wire::{self, Qos, WireError};

/// Why a bag could not be written.
#[derive(Debug, thiserror::Error)]
pub enum BagError {
    /// The directory exists: a bag is never written over.
    #[error("{}: exists; a bag is written into a new directory", .0.display())]
    Exists(PathBuf),
    /// The file system.
    #[error("{}: {source}", path.display())]
    Io {
        /// The file or directory.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// The MCAP writer.
    #[error("{}: {source}", path.display())]
    Mcap {
        /// The MCAP file.
        path: PathBuf,
        /// The cause.
        source: mcap::McapError,
    },
    /// A message could not be encoded.
    #[error(transparent)]
    Wire(#[from] WireError),
}

/// One topic of the bag.
struct Topic {
    channel: u16,
    type_name: &'static str,
    hash: &'static str,
    qos: Qos,
    count: u64,
}

/// Writes a bag; [`BagWriter::finish`] completes it.
pub struct BagWriter {
    dir: PathBuf,
    file: PathBuf,
    mcap: mcap::Writer<BufWriter<File>>,
    schemas: BTreeMap<&'static str, u16>,
    topics: BTreeMap<String, Topic>,
    range: Option<(u64, u64)>,
}

/// What a finished bag holds.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct BagSummary {
    /// Messages per topic.
    pub counts: BTreeMap<String, u64>,
    /// The MCAP file.
    pub file: PathBuf,
}

/// rosbag2's QoS profile as version 9 writes it (`rosbag2_storage`
/// `qos.cpp`; the same as rosbags' `dump_qos_v9`): enums by name, zero
/// durations for the defaults.
fn qos_yaml(qos: Qos) -> String {
    format!(
        "- history: keep_last\n  depth: {}\n  reliability: {}\n  durability: {}\n  \
         deadline:\n    sec: 0\n    nsec: 0\n  lifespan:\n    sec: 0\n    nsec: 0\n  \
         liveliness: automatic\n  liveliness_lease_duration:\n    sec: 0\n    nsec: 0\n  \
         avoid_ros_namespace_conventions: false",
        qos.depth,
        if qos.reliable {
            "reliable"
        } else {
            "best_effort"
        },
        if qos.transient_local {
            "transient_local"
        } else {
            "volatile"
        },
    )
}

fn indent(text: &str, by: &str) -> String {
    text.lines()
        .map(|l| format!("{by}{l}\n"))
        .collect::<String>()
}

impl BagWriter {
    /// Creates the bag directory `dir` (which must not exist) and its MCAP
    /// file `<dir name>_0.mcap`.
    pub fn create(dir: &Path) -> Result<Self, BagError> {
        if dir.exists() {
            return Err(BagError::Exists(dir.to_path_buf()));
        }
        let io = |path: &Path| {
            let path = path.to_path_buf();
            move |source| BagError::Io { path, source }
        };
        std::fs::create_dir_all(dir).map_err(io(dir))?;
        let stem = dir
            .file_name()
            .map_or("bag".into(), |n| n.to_string_lossy().into_owned());
        let file = dir.join(format!("{stem}_0.mcap"));
        let out = File::create(&file).map_err(io(&file))?;
        let mcap = mcap::WriteOptions::new()
            .profile("ros2")
            .library(concat!("ros2_proc ", env!("CARGO_PKG_VERSION")))
            .create(BufWriter::new(out))
            .map_err(|source| BagError::Mcap {
                path: file.clone(),
                source,
            })?;
        Ok(BagWriter {
            dir: dir.to_path_buf(),
            file,
            mcap,
            schemas: BTreeMap::new(),
            topics: BTreeMap::new(),
            range: None,
        })
    }

    fn mcap_error(&self) -> impl FnOnce(mcap::McapError) -> BagError + use<> {
        let path = self.file.clone();
        move |source| BagError::Mcap { path, source }
    }

    /// Writes `message` on `topic` (offered with `qos`), received at
    /// `time_ns` (wall clock, ns since the epoch).
    pub fn write<M: RosType>(
        &mut self,
        topic: &str,
        qos: Qos,
        time_ns: u64,
        message: &M,
    ) -> Result<(), BagError> {
        let payload = wire::encode(message)?;
        if !self.topics.contains_key(topic) {
            let info = M::info();
            let schema = match self.schemas.get(info.name) {
                Some(&id) => id,
                None => {
                    let id = self
                        .mcap
                        .add_schema(info.name, "ros2msg", info.ros2msg.as_bytes())
                        .map_err(self.mcap_error())?;
                    self.schemas.insert(info.name, id);
                    id
                }
            };
            let metadata = BTreeMap::from([
                ("offered_qos_profiles".to_string(), qos_yaml(qos)),
                ("topic_type_hash".to_string(), info.hash.to_string()),
            ]);
            let channel = self
                .mcap
                .add_channel(schema, topic, "cdr", &metadata)
                .map_err(self.mcap_error())?;
            self.topics.insert(
                topic.to_string(),
                Topic {
                    channel,
                    type_name: info.name,
                    hash: info.hash,
                    qos,
                    count: 0,
                },
            );
        }
        let t = self.topics.get_mut(topic).expect("added above");
        let header = mcap::records::MessageHeader {
            channel_id: t.channel,
            sequence: t.count as u32,
            log_time: time_ns,
            publish_time: time_ns,
        };
        t.count += 1;
        self.range = Some(match self.range {
            None => (time_ns, time_ns),
            Some((a, b)) => (a.min(time_ns), b.max(time_ns)),
        });
        let error = self.mcap_error();
        self.mcap
            .write_to_known_channel(&header, &payload)
            .map_err(error)
    }

    /// rosbag2's `metadata.yaml` content for what was written.
    fn metadata_yaml(&self) -> String {
        let (start, end) = self.range.unwrap_or((0, 0));
        let duration = end - start;
        let total: u64 = self.topics.values().map(|t| t.count).sum();
        let name = self
            .file
            .file_name()
            .map_or(String::new(), |n| n.to_string_lossy().into_owned());
        let mut topics = String::new();
        for (topic, t) in &self.topics {
            topics.push_str(&format!(
                "  - message_count: {}\n    topic_metadata:\n      name: {topic}\n      \
                 offered_qos_profiles:\n{}      serialization_format: cdr\n      \
                 type: {}\n      type_description_hash: {}\n",
                t.count,
                indent(&qos_yaml(t.qos), "        "),
                t.type_name,
                t.hash
            ));
        }
        format!(
            "rosbag2_bagfile_information:\n  version: 9\n  storage_identifier: mcap\n  \
             duration:\n    nanoseconds: {duration}\n  starting_time:\n    \
             nanoseconds_since_epoch: {start}\n  message_count: {total}\n  \
             topics_with_message_count:\n{topics}  compression_format: ''\n  \
             compression_mode: ''\n  relative_file_paths:\n  - {name}\n  files:\n  \
             - path: {name}\n    starting_time:\n      nanoseconds_since_epoch: {start}\n    \
             duration:\n      nanoseconds: {duration}\n    message_count: {total}\n  \
             custom_data: ~\n  ros_distro: jazzy\n"
        )
    }

    /// Writes the `rosbag2` metadata record and the MCAP summary, then
    /// `metadata.yaml` beside the file.
    pub fn finish(mut self) -> Result<BagSummary, BagError> {
        let yaml = self.metadata_yaml();
        // The record holds the same content without its top-level key, as
        // rosbag2_storage_mcap writes it.
        let serialized = yaml
            .strip_prefix("rosbag2_bagfile_information:\n")
            .unwrap_or(&yaml)
            .lines()
            .map(|l| format!("{}\n", l.strip_prefix("  ").unwrap_or(l)))
            .collect::<String>();
        let error = self.mcap_error();
        self.mcap
            .write_metadata(&mcap::records::Metadata {
                name: "rosbag2".into(),
                metadata: BTreeMap::from([("serialized_metadata".into(), serialized)]),
            })
            .map_err(error)?;
        let error = self.mcap_error();
        self.mcap.finish().map_err(error)?;
        let path = self.dir.join("metadata.yaml");
        std::fs::write(&path, yaml).map_err(|source| BagError::Io {
            path: path.clone(),
            source,
        })?;
        Ok(BagSummary {
            counts: self
                .topics
                .iter()
                .map(|(k, t)| (k.clone(), t.count))
                .collect(),
            file: self.file,
        })
    }
}
