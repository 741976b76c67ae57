//! ROS 2 type names, their DDS names and RIHS01 hashes. The hashes and the
//! ros2msg definitions come from `ros2_types.json`, which
//! `scripts/ros2_types.py` writes with rosbags from the Jazzy definitions
//! (a test fails when it is stale): none is typed by hand.

use std::collections::BTreeMap;
use std::sync::OnceLock;

use serde::{Deserialize, Serialize, de::DeserializeOwned};

/// A ROS 2 message type.
pub trait RosType: Serialize + DeserializeOwned {
    /// Its name, `pkg/msg/Name`.
    const NAME: &'static str;

    /// Its DDS name and type hash.
    fn info() -> TypeInfo {
        TypeInfo::of(Self::NAME)
    }
}

/// What the wire needs of a type.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TypeInfo {
    /// `pkg/msg/Name`.
    pub name: &'static str,
    /// `pkg::msg::dds_::Name_`.
    pub dds_name: String,
    /// `RIHS01_<64 hex>`.
    pub hash: &'static str,
    /// Its ros2msg definition with its dependencies (rosbag2's schema).
    pub ros2msg: &'static str,
}

#[derive(Deserialize)]
struct Table {
    types: BTreeMap<String, Entry>,
}

#[derive(Deserialize)]
struct Entry {
    rihs01: String,
    ros2msg: String,
}

/// The checked-in table.
pub const TABLE_JSON: &str = include_str!("../ros2_types.json");

fn table() -> &'static BTreeMap<String, Entry> {
    static TABLE: OnceLock<BTreeMap<String, Entry>> = OnceLock::new();
    TABLE.get_or_init(|| {
        serde_json::from_str::<Table>(TABLE_JSON)
            .expect("ros2_types.json is checked in and parsed by a test")
            .types
    })
}

impl TypeInfo {
    /// The wire facts of `name`, one of the types of [`msgs`](crate::msgs).
    /// Every such type is in the table (a unit test checks it).
    pub fn of(name: &'static str) -> TypeInfo {
        let entry = &table()[name];
        TypeInfo {
            name,
            dds_name: dds_name(name),
            hash: entry.rihs01.as_str(),
            ros2msg: entry.ros2msg.as_str(),
        }
    }
}

/// `pkg/msg/Name` → `pkg::msg::dds_::Name_`, as rmw_zenoh names a type on
/// the wire (rmw_zenoh `rmw_zenoh_cpp/src/detail/type_support_common.cpp:42-48`).
pub fn dds_name(name: &str) -> String {
    match name.rsplit_once('/') {
        Some((namespace, short)) => format!("{}::dds_::{short}_", namespace.replace('/', "::")),
        None => format!("dds_::{name}_"),
    }
}

/// The hash chunk a Humble graph puts where the type hash goes (rmw_zenoh
/// Humble 0.1.9 `rmw_zenoh_cpp/src/detail/rmw_publisher_data.cpp:73-75`).
pub const HUMBLE_HASH: &str = "TypeHashNotSupported";

#[cfg(test)]
mod tests {
    use super::*;
    use crate::msgs::*;

    #[test]
    fn every_message_type_is_in_the_table() {
        for info in [
            JointState::info(),
            JointTrajectory::info(),
            Image::info(),
            CameraInfo::info(),
            TfMessage::info(),
            PointStamped::info(),
        ] {
            assert!(
                info.hash.starts_with("RIHS01_") && info.hash.len() == 7 + 64,
                "{info:?}"
            );
            assert!(!info.ros2msg.is_empty());
        }
        assert_eq!(
            JointState::info().dds_name,
            "sensor_msgs::msg::dds_::JointState_"
        );
    }
}
