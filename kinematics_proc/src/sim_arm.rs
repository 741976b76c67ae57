//! The simulated arm: a driver that moves to each goal it receives by a
//! smooth step of fixed duration and reads its positions exactly. Pure:
//! time is passed in.

/// A simulated arm's motion.
#[derive(Debug, Clone)]
pub struct SimArm {
    from: Vec<f64>,
    to: Vec<f64>,
    started_ns: i64,
    move_ns: i64,
    pose: Option<u64>,
}

impl SimArm {
    /// An arm resting at `home` that takes `move_ns` for each move.
    pub fn new(home: Vec<f64>, move_ns: i64) -> Self {
        Self {
            from: home.clone(),
            to: home,
            started_ns: 0,
            move_ns: move_ns.max(1),
            pose: None,
        }
    }

    /// Moves to `q` for pose `pose` from where it is at `now_ns`; a goal for
    /// the pose it is already moving to changes nothing.
    pub fn go_to(&mut self, pose: u64, q: &[f64], now_ns: i64) {
        if self.pose == Some(pose) {
            return;
        }
        self.from = self.at(now_ns);
        self.to = q.to_vec();
        self.started_ns = now_ns;
        self.pose = Some(pose);
    }

    /// Joint positions at `now_ns`.
    pub fn at(&self, now_ns: i64) -> Vec<f64> {
        let s = ((now_ns - self.started_ns) as f64 / self.move_ns as f64).clamp(0.0, 1.0);
        let smooth = s * s * (3.0 - 2.0 * s);
        self.from
            .iter()
            .zip(&self.to)
            .map(|(a, b)| a + (b - a) * smooth)
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn moves_smoothly_in_the_move_time_and_ignores_repeated_goals() {
        let mut arm = SimArm::new(vec![0.0, 0.0], 100_000_000);
        assert_eq!(arm.at(5), vec![0.0, 0.0]);
        arm.go_to(1, &[1.0, -1.0], 0);
        assert!(
            (arm.at(50_000_000)[0] - 0.5).abs() < 1e-12,
            "half way in time is half way"
        );
        arm.go_to(1, &[1.0, -1.0], 60_000_000);
        assert_eq!(arm.at(100_000_000), vec![1.0, -1.0]);
        arm.go_to(2, &[2.0, 0.0], 200_000_000);
        assert_eq!(arm.at(200_000_000), vec![1.0, -1.0]);
        assert_eq!(arm.at(300_000_001), vec![2.0, 0.0]);
    }
}
