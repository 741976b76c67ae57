//! The camera's frame schedule: a frame is due every period from the first
//! one; a camera that falls a whole period behind (rendering or decoding
//! too slow for the rate) counts the frames it could not make and starts
//! its schedule again from now, rather than bursting to catch up.

/// A fixed-rate frame schedule on a clock given in ns.
#[derive(Debug, Clone)]
pub struct FrameClock {
    period_ns: i64,
    next_due: Option<i64>,
    late: u64,
}

impl FrameClock {
    /// A schedule of `fps` frames a second.
    pub fn new(fps: f64) -> Self {
        Self {
            period_ns: ((1e9 / fps) as i64).max(1),
            next_due: None,
            late: 0,
        }
    }

    /// The period, ns.
    pub fn period_ns(&self) -> i64 {
        self.period_ns
    }

    /// Whether a frame is due at `now_ns`; if so, the schedule moves on
    /// one period (and the frames missed while behind are counted).
    pub fn due(&mut self, now_ns: i64) -> bool {
        let next = *self.next_due.get_or_insert(now_ns);
        if now_ns < next {
            return false;
        }
        let behind = (now_ns - next) / self.period_ns;
        let next = if behind > 0 {
            self.late += behind as u64;
            now_ns
        } else {
            next
        };
        self.next_due = Some(next + self.period_ns);
        true
    }

    /// Frames that could not be made on schedule.
    pub fn late(&self) -> u64 {
        self.late
    }
}

#[cfg(test)]
mod tests {
    use super::FrameClock;

    #[test]
    fn frames_come_every_period_and_a_stall_counts_the_missed_ones() {
        let mut clock = FrameClock::new(100.0); // 10 ms
        let ms = 1_000_000;
        assert!(clock.due(0), "the first frame at once");
        assert!(!clock.due(5 * ms));
        assert!(clock.due(10 * ms));
        assert!(clock.due(21 * ms), "a little late is on time");
        assert!(!clock.due(25 * ms));
        assert_eq!(clock.late(), 0);
        // Stalled 35 ms past the frame due at 30 ms: 3 whole periods missed.
        assert!(clock.due(65 * ms));
        assert_eq!(clock.late(), 3);
        assert!(!clock.due(70 * ms), "the schedule restarts from the stall");
        assert!(clock.due(75 * ms));
    }
}
