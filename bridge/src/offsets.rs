//! The offsets to the clocks of the bridges that send here ([`Clocks`]):
//! asked of a new sender by round trips on its clock key, kept fresh by the
//! clock thread, and applied to its stamps (see [`crate::clock`]).

use std::collections::HashMap;
use std::sync::Mutex;
use std::sync::atomic::AtomicBool;
use std::time::{Duration, Instant};

use messages::now_ns;
use zenoh::Wait;

use crate::clock::{Applied, Estimator, Offset, RoundTrip};
use crate::options::Options;
use crate::{ROUND_TRIP_WITHIN, STAMP_SLACK_NS, any_set};

/// How often the clock thread makes a round trip to each sender: 16 of them
/// (the estimator's window) span 4 s.
const CLOCK_EVERY: Duration = Duration::from_millis(250);

/// The offsets to the clocks of the bridges that send here.
pub(crate) struct Clocks<'a> {
    session: &'a zenoh::Session,
    options: &'a Options,
    /// By sender's zenoh id.
    senders: Mutex<HashMap<String, SenderClock>>,
    /// When (this clock, ns) a sender without an offset last failed to
    /// answer: its messages are refused at once for a while, so that a
    /// sender that never answers (or a stream of made-up ids) cannot hold
    /// the receiving side in round trips.
    unanswered: Mutex<HashMap<String, i64>>,
}

/// What is known of one sender's clock: the estimate, and the offsets
/// applied to its stamps.
#[derive(Default)]
struct SenderClock {
    estimator: Estimator,
    applied: Applied,
}

/// How long a sender without an offset that did not answer is not asked
/// again.
const ASK_AGAIN_AFTER_NS: i64 = 5_000_000_000;

/// A sender that answered no round trip for this long is forgotten (it has
/// gone; if it comes back, it is asked again).
const FORGET_AFTER_NS: i64 = 10_000_000_000;

impl<'a> Clocks<'a> {
    /// No sender known yet; round trips go through `session`.
    pub(crate) fn new(session: &'a zenoh::Session, options: &'a Options) -> Self {
        Self {
            session,
            options,
            senders: Mutex::new(HashMap::new()),
            unanswered: Mutex::new(HashMap::new()),
        }
    }

    /// One round trip to `zid`, if it answers in time.
    fn round_trip(&self, zid: &str) -> Option<RoundTrip> {
        let t1 = now_ns();
        let replies = self
            .session
            .get(self.options.clock_key(zid))
            .timeout(ROUND_TRIP_WITHIN)
            .wait()
            .ok()?;
        let reply = replies.recv().ok()?;
        let t4 = now_ns();
        let payload = reply.result().ok()?.payload().to_bytes();
        let times: &[u8; 16] = payload.as_ref().try_into().ok()?;
        let time = |k: usize| i64::from_le_bytes(times[k..k + 8].try_into().expect("8 bytes"));
        Some(RoundTrip {
            t1,
            t2: time(0),
            t3: time(8),
            t4,
        })
    }

    fn add(&self, zid: &str, trip: RoundTrip) {
        let mut senders = self.senders.lock().unwrap_or_else(|p| p.into_inner());
        senders
            .entry(zid.to_string())
            .or_default()
            .estimator
            .add(trip);
    }

    fn estimate(&self, zid: &str) -> Option<Offset> {
        let senders = self.senders.lock().unwrap_or_else(|p| p.into_inner());
        senders.get(zid)?.estimator.estimate(now_ns())
    }

    /// The offset that moves a stamp `stamp_ns` of `zid` onto this clock
    /// (see [`Applied`]), and the bound on its error now; a sender not
    /// heard from before is asked a few round trips first.
    pub(crate) fn offset(&self, zid: &str, stamp_ns: i64) -> Option<(Offset, i64)> {
        let current = self.current(zid)?;
        let mut senders = self.senders.lock().unwrap_or_else(|p| p.into_inner());
        let sender = senders.get_mut(zid)?;
        sender.applied.adopt(current, now_ns(), STAMP_SLACK_NS);
        let applied = sender.applied.at(stamp_ns)?;
        let bound = current
            .uncertainty_ns
            .saturating_add(applied.ahead_ns.abs_diff(current.ahead_ns) as i64);
        Some((applied, bound))
    }

    /// The current estimate of the offset to the clock of `zid`; a sender
    /// not heard from before is asked a few round trips first.
    fn current(&self, zid: &str) -> Option<Offset> {
        if let Some(o) = self.estimate(zid) {
            return Some(o);
        }
        let asked_at = {
            let unanswered = self.unanswered.lock().unwrap_or_else(|p| p.into_inner());
            unanswered.get(zid).copied()
        };
        if asked_at.is_some_and(|at| now_ns() - at < ASK_AGAIN_AFTER_NS) {
            return None;
        }
        for _ in 0..4 {
            if let Some(trip) = self.round_trip(zid) {
                self.add(zid, trip);
            }
        }
        let Some(o) = self.estimate(zid) else {
            let mut unanswered = self.unanswered.lock().unwrap_or_else(|p| p.into_inner());
            let now = now_ns();
            unanswered.retain(|_, at| now - *at < ASK_AGAIN_AFTER_NS);
            unanswered.insert(zid.to_string(), now);
            return None;
        };
        tracing::info!(
            sender = zid,
            ahead_s = o.ahead_ns as f64 * 1e-9,
            uncertainty_us = o.uncertainty_ns as f64 * 1e-3,
            "clock of a new sender"
        );
        Some(o)
    }

    /// Keeps every known sender's offset fresh until one of `stops`.
    pub(crate) fn keep(&self, stops: &[&AtomicBool]) {
        let mut logged = Instant::now();
        while !any_set(stops) {
            let zids: Vec<String> = {
                let senders = self.senders.lock().unwrap_or_else(|p| p.into_inner());
                senders.keys().cloned().collect()
            };
            for zid in zids {
                if let Some(trip) = self.round_trip(&zid) {
                    self.add(&zid, trip);
                }
            }
            let mut senders = self.senders.lock().unwrap_or_else(|p| p.into_inner());
            senders.retain(|zid, e| {
                let answered = e
                    .estimator
                    .last_trip_ns()
                    .is_some_and(|at| now_ns() - at < FORGET_AFTER_NS);
                if !answered {
                    tracing::info!(
                        sender = zid,
                        "a sender stopped answering round trips: forgotten"
                    );
                }
                answered
            });
            drop(senders);
            if logged.elapsed() > Duration::from_secs(30) {
                self.log("now");
                logged = Instant::now();
            }
            std::thread::sleep(CLOCK_EVERY);
        }
    }

    /// Logs every sender's offset `when` (e.g. "now").
    pub(crate) fn log(&self, when: &str) {
        let senders = self.senders.lock().unwrap_or_else(|p| p.into_inner());
        for (zid, e) in senders.iter().map(|(z, s)| (z, &s.estimator)) {
            if let Some(o) = e.estimate(now_ns()) {
                tracing::info!(
                    sender = zid,
                    ahead_s = o.ahead_ns as f64 * 1e-9,
                    uncertainty_us = o.uncertainty_ns as f64 * 1e-3,
                    refused_round_trips = e.refused,
                    "clock offset {when}"
                );
            }
        }
    }
}
