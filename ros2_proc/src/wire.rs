//! rmw_zenoh's wire format: data keys, CDR payloads, the per-sample
//! attachment, liveliness tokens and their QoS chunk. Line references are
//! to rmw_zenoh_cpp 0.2.10 (Jazzy; `D/` = `rmw_zenoh_cpp/src/detail/`),
//! read from `ros2-gbp/rmw_zenoh-release` tag `upstream/0.2.10`; see
//! `docs/ros2_wire_notes.md`.

use byteorder::{BigEndian, LittleEndian};
use serde::{Deserialize, Serialize};

use crate::types::TypeInfo;

/// What a payload or attachment on the wire gets wrong.
#[derive(Debug, thiserror::Error)]
pub enum WireError {
    /// Shorter than the 4-byte encapsulation header.
    #[error("a CDR payload of {0} bytes has no encapsulation header")]
    NoHeader(usize),
    /// An encapsulation other than plain CDR.
    #[error("encapsulation {0:02x} {1:02x} is not plain CDR (00 00 or 00 01)")]
    Encapsulation(u8, u8),
    /// The CDR codec's reason.
    #[error("malformed CDR: {0}")]
    Cdr(#[from] cdr_encoding::Error),
    /// A sequence that declares more elements than the payload holds.
    #[error("{what} declares {declared} bytes, the payload has {present}")]
    Short {
        /// The field.
        what: &'static str,
        /// Bytes it declares.
        declared: usize,
        /// Bytes left in the payload.
        present: usize,
    },
    /// No attachment: rmw_zenoh drops such a sample, and so do we.
    #[error("no attachment (rmw_zenoh drops such a sample)")]
    NoAttachment,
    /// An attachment not in the 33-byte layout.
    #[error("an attachment of {0} bytes, not rmw_zenoh's 33")]
    Attachment(usize),
}

/// The encapsulation header rmw_zenoh writes: plain CDR, little endian
/// (Fast-CDR `serialize_encapsulation`, called at `D/type_support.cpp:97-104`).
pub const CDR_LE: [u8; 4] = [0x00, 0x01, 0x00, 0x00];

/// A message as a CDR payload with its header. Alignment counts from after
/// the header, as Fast-CDR's `reset_alignment` makes it.
pub fn encode<M: Serialize>(message: &M) -> Result<Vec<u8>, WireError> {
    let mut out = CDR_LE.to_vec();
    out.extend(cdr_encoding::to_vec::<M, LittleEndian>(message)?);
    Ok(out)
}

/// A message from a CDR payload with its header, either byte order.
pub fn decode<'de, M: Deserialize<'de>>(payload: &'de [u8]) -> Result<M, WireError> {
    if payload.len() < 4 {
        return Err(WireError::NoHeader(payload.len()));
    }
    let body = &payload[4..];
    let (message, _) = match (payload[0], payload[1]) {
        (0, 1) => cdr_encoding::from_bytes::<M, LittleEndian>(body)?,
        (0, 0) => cdr_encoding::from_bytes::<M, BigEndian>(body)?,
        (a, b) => return Err(WireError::Encapsulation(a, b)),
    };
    Ok(message)
}

/// The attachment every rmw_zenoh sample carries (`D/attachment_helpers.cpp:67-82`):
/// zenoh-ext serialisation of `(i64 sequence, i64 source timestamp, [u8; 16] gid)`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Attachment {
    /// Per publisher, from 1 (`D/rmw_publisher_data.cpp:204,311-312`).
    pub sequence: i64,
    /// When it was published, ns since the epoch (`system_clock`).
    pub source_ns: i64,
    /// The publisher's GID.
    pub gid: [u8; 16],
}

impl Attachment {
    /// Its size on the wire.
    pub const LEN: usize = 33;

    /// The 33 bytes: two little-endian i64, then the GID with its LEB128
    /// length (16 = `0x10`) as zenoh-ext writes an array.
    pub fn to_bytes(&self) -> [u8; 33] {
        let mut out = [0u8; 33];
        out[..8].copy_from_slice(&self.sequence.to_le_bytes());
        out[8..16].copy_from_slice(&self.source_ns.to_le_bytes());
        out[16] = 16;
        out[17..].copy_from_slice(&self.gid);
        out
    }

    /// Parses the 33 bytes.
    pub fn parse(bytes: &[u8]) -> Result<Attachment, WireError> {
        if bytes.len() != Self::LEN || bytes[16] != 16 {
            return Err(WireError::Attachment(bytes.len()));
        }
        let i64_at = |i: usize| i64::from_le_bytes(bytes[i..i + 8].try_into().expect("8 bytes"));
        Ok(Attachment {
            sequence: i64_at(0),
            source_ns: i64_at(8),
            gid: bytes[17..].try_into().expect("16 bytes"),
        })
    }
}

/// A topic's data key, `<domain>/<name>/<dds type>/<hash>`, with one leading
/// and one trailing `/` of the name dropped (`D/liveliness_utils.cpp:61-93`).
pub fn topic_key(domain: u32, topic: &str, ty: &TypeInfo) -> String {
    format!(
        "{domain}/{}/{}/{}",
        strip_slashes(topic),
        ty.dds_name,
        ty.hash
    )
}

/// The same key for any type hash: what a subscriber listens on, so that a
/// publisher of another hash (another definition, or Humble) is named
/// rather than silently missed.
pub fn topic_key_any_hash(domain: u32, topic: &str, ty: &TypeInfo) -> String {
    format!("{domain}/{}/{}/*", strip_slashes(topic), ty.dds_name)
}

fn strip_slashes(name: &str) -> &str {
    let name = name.strip_prefix('/').unwrap_or(name);
    name.strip_suffix('/').unwrap_or(name)
}

/// A fully qualified topic name: a relative one is put under `namespace`.
pub fn qualified(namespace: &str, topic: &str) -> String {
    if topic.starts_with('/') {
        topic.to_string()
    } else if namespace == "/" || namespace.is_empty() {
        format!("/{topic}")
    } else {
        format!("{}/{topic}", namespace.trim_end_matches('/'))
    }
}

/// The QoS an endpoint declares in its token.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Qos {
    /// RELIABLE, else BEST_EFFORT.
    pub reliable: bool,
    /// TRANSIENT_LOCAL, else VOLATILE.
    pub transient_local: bool,
    /// KEEP_LAST depth.
    pub depth: u32,
}

impl Qos {
    /// Reliable, volatile, keep last `depth`: rclcpp's default with depth 10.
    pub const fn reliable(depth: u32) -> Qos {
        Qos {
            reliable: true,
            transient_local: false,
            depth,
        }
    }

    /// Reliable, transient local, keep last 1: `/tf_static`'s QoS.
    pub const LATCHED: Qos = Qos {
        reliable: true,
        transient_local: true,
        depth: 1,
    };

    /// The token's QoS chunk `R:D:H,depth:DLs,DLns:LSs,LSns:LV,LEASEs,LEASEns`,
    /// each component empty when it is rmw_zenoh's default (RELIABLE,
    /// VOLATILE, KEEP_LAST, infinite deadline, lifespan and lease,
    /// AUTOMATIC) and otherwise the rmw enum's value
    /// (`D/liveliness_utils.cpp:290-351`, `D/qos.cpp:17-47`; Jazzy
    /// `rmw/types.h`: BEST_EFFORT 2, TRANSIENT_LOCAL 1).
    pub fn keyexpr(&self) -> String {
        let reliability = if self.reliable { "" } else { "2" };
        let durability = if self.transient_local { "1" } else { "" };
        format!("{reliability}:{durability}:,{}:,:,:,,", self.depth)
    }
}

/// What an endpoint is, in its token (`D/liveliness_utils.cpp:99-131`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EntityKind {
    /// `NN`.
    Node,
    /// `MP`.
    Publisher,
    /// `MS`.
    Subscription,
}

impl EntityKind {
    fn code(self) -> &'static str {
        match self {
            EntityKind::Node => "NN",
            EntityKind::Publisher => "MP",
            EntityKind::Subscription => "MS",
        }
    }
}

/// The admin space of rmw_zenoh's liveliness tokens.
pub const ADMIN_SPACE: &str = "@ros2_lv";

/// `/` → `%`, as in every name chunk of a token (`D/liveliness_utils.cpp:697-708`).
pub fn mangle(name: &str) -> String {
    name.replace('/', "%")
}

/// A node's identity in the graph.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct NodeId {
    /// `ROS_DOMAIN_ID`.
    pub domain: u32,
    /// The zenoh session's id, as `ZenohId`'s `Display` writes it.
    pub zid: String,
    /// The node's id in its context.
    pub nid: u32,
    /// Its namespace, `/` for the root.
    pub namespace: String,
    /// Its name.
    pub name: String,
}

impl NodeId {
    /// The node's token, `@ros2_lv/<domain>/<zid>/<nid>/<nid>/NN/<enclave>/<ns>/<name>`
    /// (rmw_zenoh `docs/design.md:179`; `D/rmw_node_data.cpp:43-47`); the
    /// default enclave `/` is `%`.
    pub fn token(&self) -> String {
        format!(
            "{ADMIN_SPACE}/{}/{}/{}/{}/{}/%/{}/{}",
            self.domain,
            self.zid,
            self.nid,
            self.nid,
            EntityKind::Node.code(),
            mangle(&self.namespace),
            mangle(&self.name)
        )
    }

    /// A publisher's or subscription's token: the node's chunks, then the
    /// fully qualified topic, type, hash and QoS (`docs/design.md:185`,
    /// `D/liveliness_utils.cpp:449-484`).
    pub fn endpoint_token(
        &self,
        id: u32,
        kind: EntityKind,
        topic: &str,
        ty: &TypeInfo,
        qos: Qos,
    ) -> String {
        format!(
            "{ADMIN_SPACE}/{}/{}/{}/{id}/{}/%/{}/{}/{}/{}/{}/{}",
            self.domain,
            self.zid,
            self.nid,
            kind.code(),
            mangle(&self.namespace),
            mangle(&self.name),
            mangle(topic),
            mangle(&ty.dds_name),
            mangle(ty.hash),
            qos.keyexpr()
        )
    }
}

/// An endpoint's GID: XXH3-128 of its token, low 64 bits then high 64, each
/// in host (little-endian) order (`D/liveliness_utils.cpp:486-496`).
pub fn gid(token: &str) -> [u8; 16] {
    xxhash_rust::xxh3::xxh3_128(token.as_bytes()).to_le_bytes()
}

/// A publisher's or subscription's token, parsed.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct EndpointToken {
    /// Publisher or subscription.
    pub kind: EntityKind,
    /// The node's name.
    pub node: String,
    /// The fully qualified topic.
    pub topic: String,
    /// The DDS type name.
    pub dds_type: String,
    /// The type hash (`RIHS01_...`, or Humble's `TypeHashNotSupported`).
    pub hash: String,
}

impl EndpointToken {
    /// Parses a token; `None` for a node's or another admin key.
    pub fn parse(token: &str) -> Option<EndpointToken> {
        let parts: Vec<&str> = token.split('/').collect();
        if parts.len() < 13 || parts[0] != ADMIN_SPACE {
            return None;
        }
        let kind = match parts[5] {
            "MP" => EntityKind::Publisher,
            "MS" => EntityKind::Subscription,
            _ => return None,
        };
        let unmangle = |s: &str| s.replace('%', "/");
        Some(EndpointToken {
            kind,
            node: unmangle(parts[8]),
            topic: unmangle(parts[9]),
            dds_type: unmangle(parts[10]),
            hash: parts[11].to_string(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::msgs::{JointState, Time};
    use crate::types::{RosType, TypeInfo};

    #[test]
    fn keys_tokens_and_qos_are_rmw_zenohs() {
        // rmw_zenoh docs/design.md:150: `0/chatter/std_msgs::msg::dds_::String_/RIHS01_df66…`
        let string = TypeInfo {
            name: "std_msgs/msg/String",
            dds_name: crate::types::dds_name("std_msgs/msg/String"),
            hash: "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18",
            ros2msg: "string data",
        };
        assert_eq!(
            topic_key(0, "/chatter", &string),
            "0/chatter/std_msgs::msg::dds_::String_/RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"
        );
        // docs/design.md:218,230 (zid shortened there; the layout is the point).
        let node = NodeId {
            domain: 0,
            zid: "8b20".into(),
            nid: 0,
            namespace: "/".into(),
            name: "talker".into(),
        };
        assert_eq!(node.token(), "@ros2_lv/0/8b20/0/0/NN/%/%/talker");
        assert_eq!(
            node.endpoint_token(
                10,
                EntityKind::Publisher,
                "/chatter",
                &string,
                Qos::reliable(7)
            ),
            "@ros2_lv/0/8b20/0/10/MP/%/%/talker/%chatter/std_msgs::msg::dds_::String_/RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18/::,7:,:,:,,"
        );
        assert_eq!(Qos::LATCHED.keyexpr(), ":1:,1:,:,:,,");
        let parsed = EndpointToken::parse(&node.endpoint_token(
            3,
            EntityKind::Subscription,
            "/a/b",
            &JointState::info(),
            Qos::reliable(10),
        ))
        .unwrap();
        assert_eq!(parsed.topic, "/a/b");
        assert_eq!(parsed.kind, EntityKind::Subscription);
        assert_eq!(parsed.hash, JointState::info().hash);
    }

    #[test]
    fn attachments_round_trip_and_bad_payloads_are_errors() {
        let a = Attachment {
            sequence: 1,
            source_ns: 1_700_000_000_123_456_789,
            gid: [7; 16],
        };
        assert_eq!(Attachment::parse(&a.to_bytes()).unwrap(), a);
        assert!(Attachment::parse(&[0; 32]).is_err());
        let state = JointState {
            header: crate::msgs::Header {
                stamp: Time { sec: 1, nanosec: 2 },
                frame_id: "base".into(),
            },
            name: vec!["j1".into()],
            position: vec![0.5],
            ..Default::default()
        };
        let bytes = encode(&state).unwrap();
        assert_eq!(decode::<JointState>(&bytes).unwrap(), state);
        assert!(matches!(
            decode::<JointState>(&bytes[..2]),
            Err(WireError::NoHeader(2))
        ));
        assert!(decode::<JointState>(&bytes[..bytes.len() - 3]).is_err());
        let mut xcdr2 = bytes.clone();
        xcdr2[1] = 0x07;
        assert!(matches!(
            decode::<JointState>(&xcdr2),
            Err(WireError::Encapsulation(0, 7))
        ));
    }
}
