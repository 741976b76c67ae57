//! The pipeline on a ROS 2 graph running on rmw_zenoh, with no ROS
//! installed: rmw_zenoh's wire format ([`wire`]: keys, CDR, attachments,
//! liveliness tokens), the ROS 2 messages we speak ([`msgs`], their hashes
//! in [`types`]), a node ([`node`]), the wall/monotonic stamp mapping
//! ([`clock`]), the arm driver ([`arm`]), the camera ([`camera`], its
//! images read in place by [`image`]), the results out ([`tf`]), and
//! rosbag2 bags of recordings ([`bag`]).

pub mod arm;
pub mod bag;
pub mod camera;
pub mod clock;
pub mod image;
pub mod msgs;
pub mod node;
pub mod tf;
pub mod types;
pub mod wire;
