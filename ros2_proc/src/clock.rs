//! ROS 2 stamps are wall-clock time (`CLOCK_REALTIME`, ns since the epoch);
//! the pipeline's are `CLOCK_MONOTONIC` ([`messages::now_ns`]). A stamp
//! crosses by the offset between the two clocks read at that moment: a
//! wall-clock step (NTP) moves ROS stamps and not ours, and the offset read
//! at the crossing follows it.

pub use messages::{wall_minus_monotonic_ns as wall_minus_monotonic, wall_ns};

/// A wall-clock stamp on the monotonic clock.
pub fn to_monotonic(wall: i64) -> i64 {
    wall - wall_minus_monotonic()
}

/// A monotonic stamp on the wall clock.
pub fn to_wall(monotonic: i64) -> i64 {
    monotonic + wall_minus_monotonic()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_stamp_crosses_and_comes_back() {
        let now = messages::now_ns();
        let wall = to_wall(now);
        assert!((wall - wall_ns()).abs() < 50_000_000);
        assert!((to_monotonic(wall) - now).abs() < 1_000_000);
    }
}
