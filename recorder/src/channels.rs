//! The lossless channels: one per topic of the [`messages::topics`] table,
//! holding the message bytes exactly as they travel in shared memory, with a
//! schema that names the type and its layout so that a reader can refuse a
//! layout it does not know.

pub use messages::topics::{Layout, MESSAGE_ENCODING, Message, SCHEMA_ENCODING, TopicId};

/// Log time of a stamp: stamps before the clock's epoch (malformed) map to 0.
pub fn log_time(stamp_ns: i64) -> u64 {
    stamp_ns.max(0) as u64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_schema_is_its_layout() {
        for t in TopicId::ALL {
            let layout: Layout = serde_json::from_slice(&t.schema_data()).unwrap();
            assert_eq!(layout, t.layout());
        }
    }
}
