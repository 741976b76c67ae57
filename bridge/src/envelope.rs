//! How one message crosses the link: a small envelope around the bytes it
//! has in shared memory, naming its layout so that the receiving side can
//! refuse what it would misread.
//!
//! ```text
//! magic      4 bytes  "MRB2"
//! name_len   1 byte
//! name       name_len bytes   the layout's versioned type name, e.g. mirror.JointState.v1
//! sender_len 1 byte
//! sender     sender_len bytes the sending bridge's zenoh id (hex): whose clock the times are
//! seq        8 bytes  u64 LE  the sender's count of messages on this topic, from 1
//! sent_ns    8 bytes  i64 LE  the sender's CLOCK_MONOTONIC when it sent
//! encoding   1 byte           0: as is; 1: zstd (lossless)
//! len        4 bytes  u32 LE  bytes of the (encoded) message
//! message    len bytes        as in shared memory (a frame: header, then both images)
//! ```
//!
//! Nothing from the network is trusted: every field is checked, and a
//! message whose layout is not this side's is refused with both names.

use messages::topics::{DecodeError, Message, TopicId};

/// The envelope's first bytes; the digit is the envelope's version.
pub const MAGIC: &[u8; 4] = b"MRB2";

/// How a message's bytes travel.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Encoding {
    /// As in shared memory.
    #[default]
    Raw,
    /// zstd at level [`ZSTD_LEVEL`]: lossless, for a slow link.
    Zstd,
}

/// zstd's fastest regular level: a stereo frame must not wait long.
pub const ZSTD_LEVEL: i32 = 1;

/// The most a message may be once decoded (a 4K stereo colour frame is
/// 50 MB): bytes from a network do not get to ask for more memory.
pub const MAX_MESSAGE: usize = 64 << 20;

/// Who sent a message, and which of theirs it is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct From<'a> {
    /// The sending bridge's zenoh id.
    pub sender: &'a str,
    /// Its count of messages on this topic, from 1.
    pub seq: u64,
    /// Its clock when it sent, ns.
    pub sent_ns: i64,
}

/// Appends a short string with its length (names and ids are short ASCII).
fn push_short(out: &mut Vec<u8>, s: &str) {
    let n = s.len().min(255);
    out.push(n as u8);
    out.extend_from_slice(&s.as_bytes()[..n]);
}

/// Wraps the bytes of a message on `topic`, encoded as `encoding`.
pub fn seal(topic: TopicId, from: From<'_>, encoding: Encoding, message: &[u8]) -> Vec<u8> {
    let encoded;
    let (code, message) = match encoding {
        Encoding::Raw => (0u8, message),
        Encoding::Zstd => {
            // Compressing a byte slice in memory cannot fail.
            encoded = zstd::bulk::compress(message, ZSTD_LEVEL).expect("zstd compresses");
            (1u8, &encoded[..])
        }
    };
    let name = topic.layout().type_name;
    let mut out = Vec::with_capacity(4 + 2 + name.len() + from.sender.len() + 20 + message.len());
    out.extend_from_slice(MAGIC);
    push_short(&mut out, &name);
    push_short(&mut out, from.sender);
    out.extend_from_slice(&from.seq.to_le_bytes());
    out.extend_from_slice(&from.sent_ns.to_le_bytes());
    out.push(code);
    out.extend_from_slice(&(message.len() as u32).to_le_bytes());
    out.extend_from_slice(message);
    out
}

/// A message taken out of its envelope and checked.
#[derive(Debug, Clone, Copy)]
pub struct Opened<'a> {
    /// Who sent it.
    pub from: From<'a>,
    /// The message, decoded and checked against its layout.
    pub message: Message<'a>,
}

/// Why an envelope does not open; its text is one line naming what is
/// wrong (it is logged).
#[derive(Debug, thiserror::Error)]
pub enum OpenError {
    /// The bytes end before one of the envelope's fields.
    #[error("{len} bytes end before the {field} ({need} bytes)")]
    Truncated {
        /// Bytes of the envelope.
        len: usize,
        /// The field.
        field: &'static str,
        /// Bytes of the field.
        need: usize,
    },
    /// Not [`MAGIC`].
    #[error("not a pipeline bridge message (bad magic)")]
    BadMagic,
    /// The layout's name is not UTF-8.
    #[error("the layout name is not UTF-8")]
    LayoutNameNotUtf8,
    /// The sender's layout is not this side's.
    #[error(
        "layout mismatch on {}: the sender's is {theirs}, this side's is {ours}",
        .topic.name()
    )]
    LayoutMismatch {
        /// The topic it came on.
        topic: TopicId,
        /// The sender's layout (its versioned type name).
        theirs: String,
        /// This side's.
        ours: String,
    },
    /// The sender's id is empty or not hex digits.
    #[error("the sender's id is not a zenoh id (hex digits)")]
    BadSender,
    /// Bytes after the message.
    #[error("{0} bytes after the message")]
    Trailing(usize),
    /// A compressed message that does not decompress (within
    /// [`MAX_MESSAGE`]).
    #[error("{} message does not decompress: {error}", .topic.name())]
    Decompress {
        /// The topic it came on.
        topic: TopicId,
        /// zstd's error.
        error: std::io::Error,
    },
    /// An encoding this side does not know.
    #[error("unknown encoding {0}")]
    UnknownEncoding(u8),
    /// The message does not decode as its layout.
    #[error("{} of layout {layout}: {error}", .topic.name())]
    Decode {
        /// The topic it came on.
        topic: TopicId,
        /// Its layout (the versioned type name).
        layout: String,
        /// Why.
        error: DecodeError,
    },
}

/// Opens an envelope that came on `topic`'s key, decoding into `scratch`
/// if the message was compressed; the error is one line naming what is
/// wrong.
pub fn open<'a>(
    topic: TopicId,
    bytes: &'a [u8],
    scratch: &'a mut Vec<u8>,
) -> Result<Opened<'a>, OpenError> {
    let mut rest = bytes;
    let mut take = |n: usize, what: &'static str| -> Result<&[u8], OpenError> {
        if rest.len() < n {
            return Err(OpenError::Truncated {
                len: bytes.len(),
                field: what,
                need: n,
            });
        }
        let (head, tail) = rest.split_at(n);
        rest = tail;
        Ok(head)
    };
    if take(4, "magic")? != MAGIC {
        return Err(OpenError::BadMagic);
    }
    let name_len = take(1, "layout name's length")?[0] as usize;
    let name = std::str::from_utf8(take(name_len, "layout name")?)
        .map_err(|_| OpenError::LayoutNameNotUtf8)?;
    let ours = topic.layout().type_name;
    if name != ours {
        return Err(OpenError::LayoutMismatch {
            topic,
            theirs: name.to_string(),
            ours,
        });
    }
    let sender_len = take(1, "sender's length")?[0] as usize;
    let sender = std::str::from_utf8(take(sender_len, "sender")?)
        .ok()
        .filter(|s| !s.is_empty() && s.bytes().all(|b| b.is_ascii_hexdigit()))
        .ok_or(OpenError::BadSender)?;
    let seq = u64::from_le_bytes(take(8, "sequence number")?.try_into().expect("8 bytes"));
    let sent_ns = i64::from_le_bytes(take(8, "send time")?.try_into().expect("8 bytes"));
    let code = take(1, "encoding")?[0];
    let len = u32::from_le_bytes(take(4, "length")?.try_into().expect("4 bytes")) as usize;
    let message = take(len, "message")?;
    if !rest.is_empty() {
        return Err(OpenError::Trailing(rest.len()));
    }
    let message = match code {
        0 => message,
        1 => {
            *scratch = zstd::bulk::decompress(message, MAX_MESSAGE)
                .map_err(|error| OpenError::Decompress { topic, error })?;
            &scratch[..]
        }
        other => return Err(OpenError::UnknownEncoding(other)),
    };
    let message = Message::decode(topic, message).map_err(|error| OpenError::Decode {
        topic,
        layout: ours,
        error,
    })?;
    Ok(Opened {
        from: From {
            sender,
            seq,
            sent_ns,
        },
        message,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use messages::JointState;

    fn joint_state() -> JointState {
        JointState {
            seq: 7,
            stamp_ns: 123_456,
            ..JointState::default()
        }
    }

    const FROM: From<'static> = From {
        sender: "a1b2",
        seq: 3,
        sent_ns: 99,
    };

    #[test]
    fn a_sealed_message_opens_to_the_same_bytes() {
        let js = joint_state();
        let bytes = seal(
            TopicId::JointState,
            FROM,
            Encoding::Raw,
            bytemuck::bytes_of(&js),
        );
        let mut scratch = Vec::new();
        let opened = open(TopicId::JointState, &bytes, &mut scratch).unwrap();
        assert_eq!(opened.from, FROM);
        assert_eq!(opened.message, Message::JointState(js));
    }

    #[test]
    fn a_compressed_frame_opens_to_the_same_bytes() {
        let header = messages::FrameHeader {
            seq: 4,
            stamp_ns: 10,
            published_ns: 11,
            width: 64,
            height: 8,
            stride: 64,
            encoding: messages::Encoding::Mono8 as u32,
        };
        let mut frame = bytemuck::bytes_of(&header).to_vec();
        frame.extend((0..2 * 64 * 8).map(|i| (i / 16) as u8));
        let sealed = seal(TopicId::Frames, FROM, Encoding::Zstd, &frame);
        assert!(sealed.len() < frame.len() / 2, "{} bytes", sealed.len());
        let mut scratch = Vec::new();
        let opened = open(TopicId::Frames, &sealed, &mut scratch).unwrap();
        assert_eq!(opened.message.to_bytes(), frame);
    }

    #[test]
    fn every_malformed_envelope_is_refused_in_one_line() {
        let open = |bytes: &[u8]| {
            open(TopicId::JointState, bytes, &mut Vec::new())
                .map(|_| ())
                .map_err(|e| e.to_string())
        };
        let js = joint_state();
        let good = seal(
            TopicId::JointState,
            FROM,
            Encoding::Raw,
            bytemuck::bytes_of(&js),
        );
        let zstd = seal(
            TopicId::JointState,
            FROM,
            Encoding::Zstd,
            bytemuck::bytes_of(&js),
        );
        // Cut anywhere: refused, never a panic; compressed too.
        for sealed in [&good, &zstd] {
            for n in 0..sealed.len() {
                let e = open(&sealed[..n]).unwrap_err();
                assert!(!e.contains('\n'), "{e}");
            }
        }
        // Compressed bytes that are not zstd; an unknown encoding.
        let mut garbled = zstd.clone();
        let at = garbled.len() - 6;
        garbled[at..].fill(0xAB);
        assert!(open(&garbled).is_err());
        let mut unknown = good.clone();
        let code_at = good.len() - size_of::<JointState>() - 5;
        unknown[code_at] = 9;
        assert!(open(&unknown).unwrap_err().contains("encoding 9"));
        let mut extra = good.clone();
        extra.push(0);
        assert!(open(&extra).unwrap_err().contains("after"));
        let mut magic = good.clone();
        magic[0] = b'X';
        assert!(open(&magic).unwrap_err().contains("magic"));
        // A sender that is not an id.
        let odd = From {
            sender: "a/b",
            ..FROM
        };
        let bytes = seal(
            TopicId::JointState,
            odd,
            Encoding::Raw,
            bytemuck::bytes_of(&joint_state()),
        );
        assert!(open(&bytes).unwrap_err().contains("sender"));
        // A length that disagrees with the layout's size.
        let short = seal(TopicId::JointState, FROM, Encoding::Raw, &[0u8; 8]);
        let e = open(&short).unwrap_err();
        assert!(e.contains("mirror.JointState"), "{e}");
    }

    #[test]
    fn another_layout_is_refused_with_both_names() {
        // A joint state sent where samples are expected: same bytes, other layout.
        let bytes = seal(
            TopicId::JointState,
            FROM,
            Encoding::Raw,
            bytemuck::bytes_of(&joint_state()),
        );
        let e = open(TopicId::Samples, &bytes, &mut Vec::new())
            .unwrap_err()
            .to_string();
        let ours = TopicId::Samples.layout().type_name;
        let theirs = TopicId::JointState.layout().type_name;
        assert!(e.contains(&ours) && e.contains(&theirs), "{e}");
    }
}
