//! How stamps cross between hosts. Every stamp is its host's
//! `CLOCK_MONOTONIC`, which means nothing on another host, so the receiving
//! side moves each message's times onto its own clock by the offset between
//! the two clocks, estimated all the time from round trips.
//!
//! A round trip is the classic four times: this side's clock when it asks
//! (`t1`) and when the answer comes (`t4`), the other side's when the
//! question arrives (`t2`) and when it answers (`t3`). If the way there
//! takes as long as the way back, the other clock is ahead of this one by
//! `((t2 - t1) + (t3 - t4)) / 2`; however the two ways split the trip, the
//! error is at most half the time spent on the link,
//! `((t4 - t1) - (t3 - t2)) / 2`. Of the recent round trips the estimate
//! keeps the one with the smallest bound (a trip delayed by a busy link or
//! scheduler has a large one), aged by how far two clocks may drift apart
//! since it was made.
//!
//! A new estimate does not move messages already stamped: it is [`Applied`]
//! to stamps the sender makes from then on. So two messages with the same
//! stamp (a frame and its detections, crossing milliseconds apart) are
//! always moved by the same offset, stay paired, and a recording of them
//! replays as it was made.

use std::collections::VecDeque;

/// How far two hosts' clocks may drift apart, ns per second (100 ppm: a
/// generous bound for a computer's crystal).
pub const DRIFT_NS_PER_S: f64 = 100_000.0;

/// Round trips an estimate is chosen from.
pub const WINDOW: usize = 16;

/// One round trip's four times (see the module's documentation).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RoundTrip {
    /// Asked, this side's clock.
    pub t1: i64,
    /// Question arrived, the other side's clock.
    pub t2: i64,
    /// Answered, the other side's clock.
    pub t3: i64,
    /// Answer arrived, this side's clock.
    pub t4: i64,
}

impl RoundTrip {
    /// What it says, or `None` if its times cannot be (the answer came
    /// before the question, or the other side took longer than the trip):
    /// the other side's answer is not trusted.
    pub fn offset(&self) -> Option<Offset> {
        let trip = self.t4.checked_sub(self.t1)?;
        let held = self.t3.checked_sub(self.t2)?;
        if trip < 0 || held < 0 || held > trip {
            return None;
        }
        let there = (self.t2 as i128) - (self.t1 as i128);
        let back = (self.t3 as i128) - (self.t4 as i128);
        Some(Offset {
            ahead_ns: i64::try_from((there + back) / 2).ok()?,
            uncertainty_ns: (trip - held + 1) / 2,
        })
    }
}

/// How far the other clock is ahead of this one.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Offset {
    /// Other clock minus this clock, ns: a time `t` of the other side is
    /// `t - ahead_ns` here.
    pub ahead_ns: i64,
    /// The error is at most this, ns.
    pub uncertainty_ns: i64,
}

/// The offset to one other host, from its recent round trips.
#[derive(Debug, Default, Clone)]
pub struct Estimator {
    /// Recent offsets and when (this side's clock, ns) they were measured.
    recent: VecDeque<(i64, Offset)>,
    /// Round trips whose times could not be.
    pub refused: u64,
}

impl Estimator {
    /// Adds a round trip; one whose times cannot be is counted and ignored.
    pub fn add(&mut self, trip: RoundTrip) {
        let Some(offset) = trip.offset() else {
            self.refused += 1;
            return;
        };
        if self.recent.len() == WINDOW {
            self.recent.pop_front();
        }
        self.recent.push_back((trip.t4, offset));
    }

    /// When (this clock, ns) the last round trip that counted came back.
    pub fn last_trip_ns(&self) -> Option<i64> {
        self.recent.back().map(|&(at, _)| at)
    }

    /// The best estimate at `now_ns` (this side's clock), if any round trip
    /// has been made.
    pub fn estimate(&self, now_ns: i64) -> Option<Offset> {
        self.recent
            .iter()
            .map(|&(at, o)| {
                let age_s = (now_ns.saturating_sub(at)).max(0) as f64 * 1e-9;
                Offset {
                    ahead_ns: o.ahead_ns,
                    uncertainty_ns: o
                        .uncertainty_ns
                        .saturating_add((age_s * DRIFT_NS_PER_S).ceil() as i64),
                }
            })
            .min_by_key(|o| o.uncertainty_ns)
    }
}

/// How long (on the sender's clock) an offset stays on record after a newer
/// one took over, for messages that cross late.
pub const KEEP_APPLIED_NS: i64 = 60_000_000_000;

/// The offsets applied to one sender's stamps, each from a stamp (on the
/// sender's clock) on.
#[derive(Debug, Default, Clone)]
pub struct Applied {
    /// First stamp it applies to, and the offset; in order.
    segments: VecDeque<(i64, Offset)>,
}

impl Applied {
    /// Adopts `estimate`, made at `now_ns` on this clock, if it moves stamps
    /// otherwise than the offset in force: for every stamp after any a
    /// message sent so far can carry (the sender's now, plus the estimate's
    /// uncertainty and `slack_ns`; a later stamp is refused as ahead of
    /// its time). The first estimate applies to every stamp.
    pub fn adopt(&mut self, estimate: Offset, now_ns: i64, slack_ns: i64) {
        let sender_now = now_ns.saturating_add(estimate.ahead_ns);
        match self.segments.back() {
            None => self.segments.push_back((i64::MIN, estimate)),
            Some((_, o)) if o.ahead_ns == estimate.ahead_ns => {}
            Some(_) => {
                let from = sender_now
                    .saturating_add(estimate.uncertainty_ns)
                    .saturating_add(slack_ns);
                self.segments.push_back((from, estimate));
            }
        }
        while self.segments.len() > 1
            && self.segments[1].0 < sender_now.saturating_sub(KEEP_APPLIED_NS)
        {
            self.segments.pop_front();
        }
    }

    /// The offset that moves a stamp `stamp_ns` of the sender's clock (one
    /// older than the oldest on record: the oldest).
    pub fn at(&self, stamp_ns: i64) -> Option<Offset> {
        self.segments
            .iter()
            .rev()
            .find(|(from, _)| *from <= stamp_ns)
            .or(self.segments.front())
            .map(|&(_, o)| o)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A round trip to a clock `ahead` ns ahead, `there` and `back` ns on the
    /// way, `held` ns answering.
    fn trip(t1: i64, ahead: i64, there: i64, held: i64, back: i64) -> RoundTrip {
        let t2 = t1 + there + ahead;
        let t3 = t2 + held;
        RoundTrip {
            t1,
            t2,
            t3,
            t4: t3 - ahead + back,
        }
    }

    #[test]
    fn a_symmetric_trip_gives_the_offset_exactly() {
        let ahead = 86_400_000_000_000;
        let o = trip(5_000, ahead, 300, 20, 300).offset().unwrap();
        assert_eq!(o.ahead_ns, ahead);
        assert_eq!(o.uncertainty_ns, 300);
        // Behind works the same.
        let o = trip(5_000, -ahead, 300, 20, 300).offset().unwrap();
        assert_eq!(o.ahead_ns, -ahead);
    }

    #[test]
    fn the_error_of_a_lopsided_trip_stays_within_its_bound() {
        for (there, back) in [(10, 990), (990, 10), (1, 1), (500, 0)] {
            let o = trip(1_000_000, 7_777, there, 5, back).offset().unwrap();
            let error = (o.ahead_ns - 7_777).abs();
            assert!(
                error <= o.uncertainty_ns,
                "{there}/{back}: error {error} > bound {}",
                o.uncertainty_ns
            );
        }
    }

    #[test]
    fn impossible_times_are_refused() {
        let mut e = Estimator::default();
        // The answer before the question.
        e.add(RoundTrip {
            t1: 100,
            t2: 0,
            t3: 0,
            t4: 50,
        });
        // The other side held it longer than the trip took.
        e.add(RoundTrip {
            t1: 0,
            t2: 0,
            t3: 1000,
            t4: 10,
        });
        // Times at the ends of the range do not overflow.
        e.add(RoundTrip {
            t1: i64::MIN,
            t2: i64::MAX,
            t3: i64::MAX,
            t4: i64::MAX,
        });
        assert_eq!(e.refused, 3);
        assert_eq!(e.estimate(0), None);
    }

    #[test]
    fn the_estimate_keeps_the_tightest_recent_trip_and_ages_it() {
        let mut e = Estimator::default();
        let ahead = -3_000_000_000;
        // A slow trip, a fast lopsided one, a slow one.
        e.add(trip(0, ahead, 40_000, 10, 60_000));
        e.add(trip(1_000_000, ahead, 100, 10, 300));
        e.add(trip(2_000_000, ahead, 70_000, 10, 10_000));
        let now = 2_100_000;
        let o = e.estimate(now).unwrap();
        assert!((o.ahead_ns - ahead).abs() <= 200);
        // The fast trip's bound, 200 ns, aged 1.1 ms at 100 ppm (110 ns).
        assert_eq!(o.uncertainty_ns, 200 + 110);
        // Old trips leave the window.
        for k in 0..WINDOW as i64 {
            e.add(trip(10_000_000 + k, ahead, 5_000, 10, 5_000));
        }
        // The newest: made at 10_010_025, aged 9.99 ms (999 ns).
        assert_eq!(e.estimate(20_000_000).unwrap().uncertainty_ns, 5_000 + 999);
    }

    #[test]
    fn a_new_offset_moves_only_stamps_made_after_it() {
        let offset = |ahead_ns| Offset {
            ahead_ns,
            uncertainty_ns: 1_000,
        };
        let mut applied = Applied::default();
        assert_eq!(applied.at(0), None);
        let ahead = 86_400_000_000_000;
        applied.adopt(offset(ahead), 1_000_000_000, 20_000_000);
        // The first applies to everything, even stamps older than it.
        assert_eq!(applied.at(i64::MIN).unwrap().ahead_ns, ahead);
        // Two estimates later (the second the same) the offset is 5 us
        // more: stamps the sender has made up to now, and its uncertainty
        // and the slack beyond, keep the old one.
        applied.adopt(offset(ahead), 1_500_000_000, 20_000_000);
        applied.adopt(offset(ahead + 5_000), 2_000_000_000, 20_000_000);
        let boundary = 2_000_000_000 + ahead + 5_000 + 1_000 + 20_000_000;
        assert_eq!(applied.at(boundary - 1).unwrap().ahead_ns, ahead);
        assert_eq!(applied.at(boundary).unwrap().ahead_ns, ahead + 5_000);
        // A frame and its detections (the same stamp) crossing on either
        // side of the change are moved alike.
        let stamp = 1_999_000_000 + ahead;
        assert_eq!(applied.at(stamp), applied.at(stamp));
        assert_eq!(applied.at(stamp).unwrap().ahead_ns, ahead);
        // A minute on, the old offset is dropped; older stamps take the oldest kept.
        applied.adopt(offset(ahead + 9_000), 70_000_000_000, 20_000_000);
        assert_eq!(applied.at(stamp).unwrap().ahead_ns, ahead + 5_000);
    }
}
