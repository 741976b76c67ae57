//! What a bridge did, per topic, and its latencies ([`Counters`]).

use std::sync::Mutex;
use std::sync::atomic::{AtomicU64, Ordering};

use messages::topics::TopicId;
use runtime::stats::StageStats;

use crate::options::Options;

/// What a bridge did, per topic (by [`TopicId::index`]), and its latencies.
pub struct Counters {
    /// Messages put on the link.
    pub sent: [AtomicU64; TopicId::COUNT],
    /// Of those, messages put while no receiver was on the link (lost).
    pub unheard: [AtomicU64; TopicId::COUNT],
    /// Messages taken from shared memory but dropped because the queue to
    /// the link was full (a link stalled for long).
    pub dropped: [AtomicU64; TopicId::COUNT],
    /// Messages received and published here.
    pub received: [AtomicU64; TopicId::COUNT],
    /// Messages the sender numbered but that never came (gaps in its
    /// sequence numbers: a cut link, a full link or queue).
    pub lost: [AtomicU64; TopicId::COUNT],
    /// Messages from the link refused (they did not open, came out of
    /// order, or their stamps cannot be).
    pub refused: AtomicU64,
    /// Frames dropped because the receiving queue was full.
    pub queue_full: AtomicU64,
    /// Latencies: `link` (sent there to received here, on this clock) and
    /// `clock_uncertainty` (of the offset each received message was moved by).
    pub stats: Mutex<StageStats>,
}

impl Default for Counters {
    fn default() -> Self {
        Self {
            sent: Default::default(),
            unheard: Default::default(),
            dropped: Default::default(),
            received: Default::default(),
            lost: Default::default(),
            refused: AtomicU64::new(0),
            queue_full: AtomicU64::new(0),
            stats: Mutex::new(StageStats::new("bridge")),
        }
    }
}

impl Counters {
    pub(crate) fn add(slot: &AtomicU64, n: u64) {
        slot.fetch_add(n, Ordering::Relaxed);
    }

    fn get(slots: &[AtomicU64; TopicId::COUNT], topic: TopicId) -> u64 {
        slots[topic.index()].load(Ordering::Relaxed)
    }

    /// The stage stats with every counter of `options`' topics added.
    pub fn into_stats(self, options: &Options) -> StageStats {
        let mut stats = self.stats.into_inner().unwrap_or_else(|p| p.into_inner());
        for t in TopicId::ALL {
            let name = t.name();
            if options.send.contains(&t) {
                stats.count(&format!("sent_{name}"), Self::get(&self.sent, t));
                stats.count(&format!("unheard_{name}"), Self::get(&self.unheard, t));
                stats.count(&format!("dropped_{name}"), Self::get(&self.dropped, t));
            }
            if options.receive.contains(&t) {
                stats.count(&format!("received_{name}"), Self::get(&self.received, t));
                stats.count(&format!("lost_{name}"), Self::get(&self.lost, t));
            }
        }
        stats.count("refused", self.refused.load(Ordering::Relaxed));
        stats.count("queue_full", self.queue_full.load(Ordering::Relaxed));
        stats
    }
}
