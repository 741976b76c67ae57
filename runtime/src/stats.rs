//! Per-stage timing, CPU and drop counters: each stage records its
//! latencies and the CPU time of its steps (the thread's CPU clock) in HDR
//! histograms and, on exit, logs a summary with its process's share of a
//! core and writes it as JSON into `MIRROR_STATS_DIR` (set by the
//! launcher), which prints them as tables.

use std::collections::BTreeMap;
use std::path::Path;
use std::sync::OnceLock;
use std::time::{Duration, Instant};

use cpu_time::{ProcessTime, ThreadTime};

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

/// Where a stage process's CPU went.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CpuSummary {
    /// CPU time of each step on the thread that ran it, ms (absent for a
    /// stage without steps).
    pub per_step: Option<LatencySummary>,
    /// CPU time of the whole process (every thread), ms.
    pub process_ms: f64,
    /// Wall time from the process's start to its summary, ms.
    pub wall_ms: f64,
    /// `process_ms / wall_ms`: the share of one core the process used.
    pub core_share: f64,
    /// How the kernel scheduled the process (absent in summaries of older
    /// builds, or where `/proc` does not say).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scheduling: Option<Scheduling>,
}

/// A process's scheduling policy, as `/proc/self/stat` gives it.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct Scheduling {
    /// `normal`, `fifo`, `rr`, `batch`, `idle` or `deadline`.
    pub policy: String,
    /// Real-time priority (1 to 99) under `fifo` and `rr`, else 0.
    pub rt_priority: u32,
    /// Niceness (-20 to 19).
    pub nice: i32,
}

impl Scheduling {
    /// This process's (its main thread's: for the recorder, the thread that
    /// takes messages out of shared memory).
    pub fn of_this_process() -> Option<Self> {
        Self::parse(&std::fs::read_to_string("/proc/self/stat").ok()?)
    }

    /// The calling thread's.
    pub fn of_this_thread() -> Option<Self> {
        Self::parse(&std::fs::read_to_string("/proc/thread-self/stat").ok()?)
    }

    /// From the text of `/proc/PID/stat`: fields 19 (nice), 40 (rt_priority)
    /// and 41 (policy), counted after the command name, which may hold
    /// spaces and parentheses.
    fn parse(stat: &str) -> Option<Self> {
        let fields: Vec<&str> = stat
            .get(stat.rfind(')')? + 1..)?
            .split_whitespace()
            .collect();
        // fields[0] is field 3 (the state).
        let field = |n: usize| fields.get(n - 3).copied();
        let policy = match field(41)?.parse::<u32>().ok()? {
            0 => "normal",
            1 => "fifo",
            2 => "rr",
            3 => "batch",
            5 => "idle",
            6 => "deadline",
            _ => return None,
        };
        Some(Self {
            policy: policy.into(),
            rt_priority: field(40)?.parse().ok()?,
            nice: field(19)?.parse().ok()?,
        })
    }
}

impl std::fmt::Display for Scheduling {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.policy)?;
        if matches!(self.policy.as_str(), "fifo" | "rr") {
            write!(f, " {}", self.rt_priority)?;
        }
        if self.nice != 0 {
            write!(f, " nice {}", self.nice)?;
        }
        Ok(())
    }
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
    /// CPU per step and over the run (absent in summaries of older builds).
    #[serde(default)]
    pub cpu: Option<CpuSummary>,
}

static PROCESS_STARTED: OnceLock<Instant> = OnceLock::new();

/// Marks the start of this process for [`CpuSummary::wall_ms`]
/// ([`crate::init_logging`] calls it; later calls change nothing).
pub fn mark_process_start() {
    PROCESS_STARTED.get_or_init(Instant::now);
}

/// The start of one step on this thread's CPU clock: pass it to
/// [`StageStats::cpu_step`] when the step is done.
#[derive(Debug, Clone, Copy)]
pub struct StepStart(Duration);

impl StepStart {
    /// Now, on this thread's CPU clock.
    pub fn now() -> Self {
        Self(thread_cpu())
    }
}

/// This thread's CPU time so far (zero if the clock cannot be read).
pub fn thread_cpu() -> Duration {
    ThreadTime::try_now().map_or(Duration::ZERO, |t| t.as_duration())
}

fn histogram() -> Histogram<u64> {
    Histogram::new_with_bounds(1, 60_000_000, 3).expect("valid histogram bounds")
}

/// A stage's histograms (microsecond resolution, up to a minute, 3
/// significant digits) and counters.
pub struct StageStats {
    stage: String,
    histograms: BTreeMap<String, Histogram<u64>>,
    counters: BTreeMap<String, u64>,
    cpu_steps: Option<Histogram<u64>>,
}

impl StageStats {
    /// Empty stats for `stage`.
    pub fn new(stage: &str) -> Self {
        mark_process_start();
        Self {
            stage: stage.into(),
            histograms: BTreeMap::new(),
            counters: BTreeMap::new(),
            cpu_steps: None,
        }
    }

    /// Records one latency of `ns` nanoseconds under `name`.
    pub fn record(&mut self, name: &str, ns: i64) {
        let h = self.histograms.entry(name.into()).or_insert_with(histogram);
        h.saturating_record((ns / 1000).max(1) as u64);
    }

    /// Records the CPU time this thread spent since `started`, as one step.
    pub fn cpu_step(&mut self, started: StepStart) {
        let used = thread_cpu().saturating_sub(started.0);
        self.cpu_steps
            .get_or_insert_with(histogram)
            .saturating_record((used.as_micros() as u64).max(1));
    }

    /// Adds `n` to counter `name` (creating it at 0, so it shows).
    pub fn count(&mut self, name: &str, n: u64) {
        *self.counters.entry(name.into()).or_default() += n;
    }

    /// The summary of what was recorded.
    pub fn summary(&self) -> StageSummary {
        let wall_ms = PROCESS_STARTED
            .get()
            .map_or(0.0, |t| t.elapsed().as_secs_f64() * 1e3);
        let process_ms =
            ProcessTime::try_now().map_or(0.0, |t| t.as_duration().as_secs_f64() * 1e3);
        StageSummary {
            stage: self.stage.clone(),
            pid: std::process::id(),
            latencies: self
                .histograms
                .iter()
                .map(|(name, h)| (name.clone(), percentiles(h)))
                .collect(),
            counters: self.counters.clone(),
            cpu: Some(CpuSummary {
                per_step: self.cpu_steps.as_ref().map(percentiles),
                process_ms,
                wall_ms,
                core_share: if wall_ms > 0.0 {
                    process_ms / wall_ms
                } else {
                    0.0
                },
                scheduling: Scheduling::of_this_process(),
            }),
        }
    }

    /// Logs the summary and writes it into `MIRROR_STATS_DIR`, if set.
    pub fn finish(&self) {
        let summary = self.summary();
        if let Some(cpu) = &summary.cpu {
            tracing::info!(
                stage = self.stage,
                steps = cpu.per_step.as_ref().map_or(0, |s| s.count),
                step_p50_ms = cpu.per_step.as_ref().map_or(0.0, |s| s.p50_ms),
                process_ms = cpu.process_ms,
                core_share = cpu.core_share,
                "cpu"
            );
        }
        if !summary.counters.is_empty() {
            let counters: Vec<String> = summary
                .counters
                .iter()
                .map(|(k, v)| format!("{k}={v}"))
                .collect();
            tracing::info!(stage = self.stage, "counters {}", counters.join(" "));
        }
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

fn percentiles(h: &Histogram<u64>) -> LatencySummary {
    let ms = |us: u64| us as f64 / 1000.0;
    LatencySummary {
        count: h.len(),
        p50_ms: ms(h.value_at_quantile(0.5)),
        p90_ms: ms(h.value_at_quantile(0.9)),
        p99_ms: ms(h.value_at_quantile(0.99)),
        max_ms: ms(h.max()),
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

    #[test]
    fn cpu_per_step_is_the_threads_cpu_time_and_sleep_costs_none() {
        let mut s = StageStats::new("t");
        for _ in 0..5 {
            let t = StepStart::now();
            // About 20 ms of work, then a sleep that uses no CPU.
            let began = Instant::now();
            let mut x = 0u64;
            while began.elapsed() < Duration::from_millis(20) {
                x = std::hint::black_box(x.wrapping_mul(31).wrapping_add(7));
            }
            std::thread::sleep(Duration::from_millis(30));
            s.cpu_step(t);
        }
        let cpu = s.summary().cpu.unwrap();
        let steps = cpu.per_step.clone().unwrap();
        assert_eq!(steps.count, 5);
        // Busy 20 ms a step: at most that on the CPU (less if preempted),
        // and the 30 ms asleep is not counted.
        assert!(steps.p50_ms > 5.0 && steps.p50_ms < 25.0, "{steps:?}");
        assert!(cpu.process_ms >= 5.0 * 5.0, "{cpu:?}");
        // (Other tests of this process may run beside it: no upper bound.)
        assert!(cpu.wall_ms >= 250.0 && cpu.core_share > 0.0, "{cpu:?}");
    }

    #[test]
    fn scheduling_is_read_from_proc_stat_whatever_the_command_name() {
        // A command name with a space and a parenthesis, FIFO 10, nice 0.
        let stat = "4242 (tracker (x) y) S 1 4242 4242 0 -1 4194560 100 0 0 0 5 1 0 0 \
                    -11 0 3 0 12345 1000000 200 18446744073709551615 1 1 0 0 0 0 0 0 0 0 0 0 17 1 \
                    10 1 0 0 0";
        let s = Scheduling::parse(stat).unwrap();
        assert_eq!((s.policy.as_str(), s.rt_priority, s.nice), ("fifo", 10, 0));
        assert_eq!(s.to_string(), "fifo 10");
        let niced = stat
            .replace(" 0 3 0 12345", " 10 3 0 12345")
            .replace(" 10 1 0 0 0", " 0 0 0 0 0");
        let s = Scheduling::parse(&niced).unwrap();
        assert_eq!((s.policy.as_str(), s.nice), ("normal", 10));
        assert_eq!(s.to_string(), "normal nice 10");
        // This process: readable, and a test runs at normal or batch policy.
        let own = Scheduling::of_this_process().unwrap();
        assert!(["normal", "batch", "fifo", "rr", "idle"].contains(&own.policy.as_str()));
        assert!(Scheduling::parse("garbage").is_none());
    }
}
