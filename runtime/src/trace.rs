//! Stage-step spans as Chrome trace events (the JSON that Perfetto and
//! `chrome://tracing` open), stamped with CLOCK_MONOTONIC like every message,
//! so the files of all processes merge into one timeline with no clock
//! offsets to estimate: the processes share the machine's monotonic clock.
//!
//! Enabled by `MIRROR_TRACE_DIR=DIR`: each process appends one event per
//! closed span to `DIR/<name>-<pid>.jsonl`; [`merge`] makes one trace file.
//! A hand-written layer rather than `tracing-chrome`, whose timestamps count
//! from each process's start and so cannot be lined up across processes.

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, OnceLock};

use tracing::span::{Attributes, Id, Record};
use tracing::{Subscriber, field::Field, field::Visit};
use tracing_subscriber::Layer;
use tracing_subscriber::layer::Context;
use tracing_subscriber::registry::LookupSpan;

/// The environment variable naming the trace directory.
pub const TRACE_DIR_ENV: &str = "MIRROR_TRACE_DIR";

type Sink = Arc<Mutex<BufWriter<File>>>;

static SINK: OnceLock<Sink> = OnceLock::new();

/// Writes closed spans of this process as trace events.
pub struct ChromeLayer {
    sink: Sink,
    pid: u32,
}

struct SpanData {
    start_ns: i64,
    /// This thread's CPU clock when the span opened.
    start_cpu: std::time::Duration,
    args: serde_json::Map<String, serde_json::Value>,
}

struct Args<'a>(&'a mut serde_json::Map<String, serde_json::Value>);

impl Visit for Args<'_> {
    fn record_u64(&mut self, field: &Field, value: u64) {
        self.0.insert(field.name().into(), value.into());
    }
    fn record_i64(&mut self, field: &Field, value: i64) {
        self.0.insert(field.name().into(), value.into());
    }
    fn record_f64(&mut self, field: &Field, value: f64) {
        self.0.insert(field.name().into(), value.into());
    }
    fn record_bool(&mut self, field: &Field, value: bool) {
        self.0.insert(field.name().into(), value.into());
    }
    fn record_str(&mut self, field: &Field, value: &str) {
        self.0.insert(field.name().into(), value.into());
    }
    fn record_debug(&mut self, field: &Field, value: &dyn std::fmt::Debug) {
        self.0
            .insert(field.name().into(), format!("{value:?}").into());
    }
}

#[allow(unsafe_code)]
fn thread_id() -> u64 {
    // SAFETY: gettid(2) has no preconditions.
    unsafe { libc::gettid() as u64 }
}

impl ChromeLayer {
    /// A layer writing to `dir/<name>-<pid>.jsonl` (the directory is created).
    pub fn create(dir: &Path, name: &str) -> std::io::Result<Self> {
        std::fs::create_dir_all(dir)?;
        let pid = std::process::id();
        let file = File::create(dir.join(format!("{name}-{pid}.jsonl")))?;
        let sink = Arc::new(Mutex::new(BufWriter::new(file)));
        let layer = Self {
            sink: sink.clone(),
            pid,
        };
        layer.write(&serde_json::json!({
            "name": "process_name", "ph": "M", "pid": pid, "tid": 0,
            "args": { "name": name },
        }));
        let _ = SINK.set(sink);
        Ok(layer)
    }

    fn write(&self, event: &serde_json::Value) {
        if let Ok(mut out) = self.sink.lock() {
            let _ = serde_json::to_writer(&mut *out, event);
            let _ = out.write_all(b"\n");
        }
    }
}

impl<S: Subscriber + for<'a> LookupSpan<'a>> Layer<S> for ChromeLayer {
    fn on_new_span(&self, attrs: &Attributes<'_>, id: &Id, ctx: Context<'_, S>) {
        let mut data = SpanData {
            start_ns: messages::now_ns(),
            start_cpu: crate::stats::thread_cpu(),
            args: serde_json::Map::new(),
        };
        attrs.record(&mut Args(&mut data.args));
        if let Some(span) = ctx.span(id) {
            span.extensions_mut().insert(data);
        }
    }

    fn on_record(&self, id: &Id, values: &Record<'_>, ctx: Context<'_, S>) {
        if let Some(span) = ctx.span(id)
            && let Some(data) = span.extensions_mut().get_mut::<SpanData>()
        {
            values.record(&mut Args(&mut data.args));
        }
    }

    fn on_close(&self, id: Id, ctx: Context<'_, S>) {
        let end = messages::now_ns();
        let Some(span) = ctx.span(&id) else { return };
        let extensions = span.extensions();
        let Some(data) = extensions.get::<SpanData>() else {
            return;
        };
        // Spans open and close on one thread (`.entered()` guards), so the
        // thread's CPU clock tells what the step cost.
        let cpu_ms = crate::stats::thread_cpu()
            .saturating_sub(data.start_cpu)
            .as_secs_f64()
            * 1e3;
        let mut args = data.args.clone();
        args.insert("cpu_ms".into(), cpu_ms.into());
        self.write(&serde_json::json!({
            "name": span.name(),
            "cat": span.metadata().target(),
            "ph": "X",
            "ts": data.start_ns as f64 / 1e3,
            "dur": (end - data.start_ns) as f64 / 1e3,
            "pid": self.pid,
            "tid": thread_id(),
            "args": args,
        }));
        // The same as a counter track per process: CPU ms of each step.
        self.write(&serde_json::json!({
            "name": "cpu_ms",
            "ph": "C",
            "ts": end as f64 / 1e3,
            "pid": self.pid,
            "args": { span.name(): cpu_ms },
        }));
    }
}

/// Writes out what this process's layer holds (call before exiting).
pub fn flush() {
    if let Some(sink) = SINK.get()
        && let Ok(mut out) = sink.lock()
    {
        let _ = out.flush();
    }
}

/// Merges every `*.jsonl` of `dir` into one Chrome trace file at `out`,
/// events sorted by time. Returns the number of events.
pub fn merge(dir: &Path, out: &Path) -> std::io::Result<usize> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "jsonl"))
        .collect();
    files.sort();
    let mut events = Vec::new();
    for f in files {
        for line in std::fs::read_to_string(&f)?.lines() {
            // A process killed mid-write leaves at most one partial line.
            if let Ok(v) = serde_json::from_str::<serde_json::Value>(line) {
                events.push(v);
            }
        }
    }
    events.sort_by(|a, b| {
        let ts = |v: &serde_json::Value| v["ts"].as_f64().unwrap_or(f64::MIN);
        ts(a).total_cmp(&ts(b))
    });
    let n = events.len();
    let json = serde_json::json!({ "traceEvents": events, "displayTimeUnit": "ms" });
    std::fs::write(out, serde_json::to_vec(&json)?)?;
    Ok(n)
}
