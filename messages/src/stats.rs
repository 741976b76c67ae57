//! Per-stage timing and drop counters: each stage records its latencies in
//! HDR histograms and, on exit, logs a summary and writes it as JSON into
//! `MIRROR_STATS_DIR` (set by the launcher), which prints them as one table.

use std::collections::BTreeMap;
use std::path::Path;

use hdrhistogram::Histogram;
use serde::{Deserialize, Serialize};

/// The environment variable naming the stats directory.
pub const STATS_DIR_ENV: &str = "MIRROR_STATS_DIR";

/// Percentiles of one latency, ms.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LatencySummary {
    /// Samples.
    pub count: u64,
    /// Median.
    pub p50_ms: f64,
    /// 90th percentile.
    pub p90_ms: f64,
    /// 99th percentile.
    pub p99_ms: f64,
    /// Largest.
    pub max_ms: f64,
}

/// What one stage process measured.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct StageSummary {
    /// Stage name.
    pub stage: String,
    /// Process id.
    pub pid: u32,
    /// Latencies by name, e.g. `receive_to_publish`.
    pub latencies: BTreeMap<String, LatencySummary>,
    /// Counters by name, e.g. `frames_missed`.
    pub counters: BTreeMap<String, u64>,
}

/// A stage's histograms (microsecond resolution, up to a minute, 3
/// significant digits) and counters.
pub struct StageStats {
    stage: String,
    histograms: BTreeMap<String, Histogram<u64>>,
    counters: BTreeMap<String, u64>,
}

impl StageStats {
    /// Empty stats for `stage`.
    pub fn new(stage: &str) -> Self {
        Self {
            stage: stage.into(),
            histograms: BTreeMap::new(),
            counters: BTreeMap::new(),
        }
    }

    /// Records one latency of `ns` nanoseconds under `name`.
    pub fn record(&mut self, name: &str, ns: i64) {
        let h = self.histograms.entry(name.into()).or_insert_with(|| {
            Histogram::new_with_bounds(1, 60_000_000, 3).expect("valid histogram bounds")
        });
        h.saturating_record((ns / 1000).max(1) as u64);
    }

    /// Adds `n` to counter `name` (creating it at 0, so it shows).
    pub fn count(&mut self, name: &str, n: u64) {
        *self.counters.entry(name.into()).or_default() += n;
    }

    /// The summary of what was recorded.
    pub fn summary(&self) -> StageSummary {
        let ms = |us: u64| us as f64 / 1000.0;
        StageSummary {
            stage: self.stage.clone(),
            pid: std::process::id(),
            latencies: self
                .histograms
                .iter()
                .map(|(name, h)| {
                    (
                        name.clone(),
                        LatencySummary {
                            count: h.len(),
                            p50_ms: ms(h.value_at_quantile(0.5)),
                            p90_ms: ms(h.value_at_quantile(0.9)),
                            p99_ms: ms(h.value_at_quantile(0.99)),
                            max_ms: ms(h.max()),
                        },
                    )
                })
                .collect(),
            counters: self.counters.clone(),
        }
    }

    /// Logs the summary and writes it into `MIRROR_STATS_DIR`, if set.
    pub fn finish(&self) {
        let summary = self.summary();
        for (name, l) in &summary.latencies {
            tracing::info!(
                stage = self.stage,
                count = l.count,
                p50_ms = l.p50_ms,
                p99_ms = l.p99_ms,
                max_ms = l.max_ms,
                "latency {name}"
            );
        }
        if let Some(dir) = std::env::var_os(STATS_DIR_ENV) {
            let dir = Path::new(&dir);
            let path = dir.join(format!("{}-{}.json", self.stage, summary.pid));
            let written = std::fs::create_dir_all(dir).and_then(|()| {
                std::fs::write(
                    &path,
                    serde_json::to_vec_pretty(&summary).expect("a summary serialises"),
                )
            });
            if let Err(e) = written {
                tracing::warn!("{}: cannot write the stage stats: {e}", path.display());
            }
        }
    }
}

/// Reads every stage summary in `dir`.
pub fn read_all(dir: &Path) -> Vec<StageSummary> {
    let mut out: Vec<StageSummary> = std::fs::read_dir(dir)
        .into_iter()
        .flatten()
        .filter_map(|e| e.ok())
        .filter_map(|e| std::fs::read(e.path()).ok())
        .filter_map(|bytes| serde_json::from_slice(&bytes).ok())
        .collect();
    out.sort_by(|a, b| (&a.stage, a.pid).cmp(&(&b.stage, b.pid)));
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percentiles_come_from_the_histogram() {
        let mut s = StageStats::new("t");
        for ms in 1..=100 {
            s.record("step", ms * 1_000_000);
        }
        s.count("dropped", 2);
        let l = &s.summary().latencies["step"];
        assert_eq!(l.count, 100);
        assert!((l.p50_ms - 50.0).abs() < 0.1, "{l:?}");
        assert!((l.p99_ms - 99.0).abs() < 0.1, "{l:?}");
        assert!((l.max_ms - 100.0).abs() < 0.1, "{l:?}");
        assert_eq!(s.summary().counters["dropped"], 2);
    }
}
