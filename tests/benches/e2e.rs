//! End to end through the real processes: the launcher runs camera (the
//! simulated head), tracker, kinematics and mirror stage on one mirror
//! placement, without the recorder, at a sweep of stereo frame rates.
//!
//! - Latency, from the moment the camera publishes a frame into shared
//!   memory to the mirror stage having handled its detections
//!   (`frame_to_processed`, every frame) or published the sample paired
//!   from it (`frame_to_sample`, one per pose). The simulated capture
//!   (rendering, about 10 ms) comes before publication and is reported
//!   apart, as a real camera's exposure and transfer would be.
//! - Baseline, measured in the same run: the stages' own work on a frame
//!   (tracker receive-to-publish plus mirror stage receive-to-publish,
//!   medians). The ratio is what the hops, wake-ups and scheduling add.
//! - Sustained: a rate is sustained when the camera made every frame on
//!   schedule, the tracker missed none, and every pose was paired.
//!
//! Rates 30 to 150 fps. Run: `cargo bench -p tests --bench e2e` (builds the stage binaries
//! optimised; writes `target/bench/e2e.json`); under `cargo test` one short
//! run at 30 fps only, to check it works. `MIRROR_BENCH_BINS=DIR` runs the
//! binaries in DIR instead (another build, e.g. an earlier commit's, to
//! compare in the same session); `MIRROR_BENCH_RATES=90,120` runs only
//! those rates.

use std::path::Path;
use std::process::Command;

use serde_json::{Value, json};
use tests::report::{stage_counter_or_zero, stage_stats};

/// Calibration, mirror test and direct test poses of one run.
const POSES_FULL: (usize, usize, usize) = (12, 5, 3);
const POSES_QUICK: (usize, usize, usize) = (8, 2, 1);

fn run_pipeline(bins: &Path, fps: f64, poses: (usize, usize, usize)) -> Value {
    let dir = tempfile::tempdir().unwrap();
    let config = dir.path().join("pipeline.toml");
    std::fs::write(
        &config,
        format!(
            "preset = \"nico\"\nmirrors = [0]\ntrain_poses = {}\ntest_poses = {}\ndirect_poses = {}\n\
             method = \"joint+kinematics\"\nsource = \"sim\"\nfps = {fps}\nmove_ms = 100\ndwell_ms = 250\n\
             seed = 3\nmin_train = 8\n",
            poses.0, poses.1, poses.2
        ),
    )
    .unwrap();
    let output = Command::new(bins.join("pipeline"))
        .args(["--config", config.to_str().unwrap()])
        .args(["--out", dir.path().join("out").to_str().unwrap()])
        .args(["--prefix", &tests::unique_prefix(&format!("e2ebench{fps}"))])
        .args(["--no-record", "--report", "json"])
        .output()
        .expect("the launcher runs");
    assert!(
        output.status.success(),
        "pipeline at {fps} fps failed: {}",
        String::from_utf8_lossy(&output.stderr)
    );
    let report: Value = serde_json::from_slice(&output.stdout).expect("a JSON report");
    report["placements"][0].clone()
}

/// The summary of `stage`'s latency `name`, or null.
fn latency<'a>(placement: &'a Value, stage: &str, name: &str) -> &'a Value {
    stage_stats(placement, stage).map_or(&Value::Null, |s| &s["latencies"][name])
}

fn ms(v: &Value, key: &str) -> f64 {
    v[key].as_f64().unwrap_or(f64::NAN)
}

/// `MIRROR_BENCH_RATES`, e.g. `90,120`: the rates to run instead of all.
fn rates_from_env() -> Result<Option<Vec<f64>>, String> {
    let Some(list) = std::env::var_os("MIRROR_BENCH_RATES") else {
        return Ok(None);
    };
    let list = list.to_string_lossy();
    list.split(',')
        .map(|r| match r.trim().parse::<f64>() {
            Ok(fps) if fps > 0.0 && fps.is_finite() => Ok(fps),
            _ => Err(format!(
                "MIRROR_BENCH_RATES={list}: {r:?} is not a frame rate (fps > 0)"
            )),
        })
        .collect::<Result<Vec<_>, _>>()
        .map(Some)
}

fn main() {
    let full = std::env::args().any(|a| a == "--bench");
    let rates = match rates_from_env() {
        Ok(rates) => rates,
        Err(e) => {
            eprintln!("e2e bench: {e}");
            std::process::exit(2);
        }
    };
    let (bins, rates, poses): (_, &[f64], _) = if full {
        (
            std::env::var_os("MIRROR_BENCH_BINS")
                .map_or_else(tests::release_stage_binaries, Into::into),
            rates
                .as_deref()
                .unwrap_or(&[30.0, 60.0, 90.0, 120.0, 150.0]),
            POSES_FULL,
        )
    } else {
        (tests::stage_binaries(), &[30.0], POSES_QUICK)
    };
    let planned = poses.0 + poses.1 + poses.2;
    println!(
        "end to end, simulated head, mirror 0, {planned} poses per run, no recorder\n\
         {:>5} | {:>6} {:>5} | {:>24} | {:>17} | {:>9} | {:>6} {:>6} {:>6} | sustained",
        "fps",
        "frame",
        "late",
        "frame -> processed ms",
        "frame -> sample",
        "base ms",
        "missed",
        "paired",
        "x base"
    );
    println!(
        "{:>5} | {:>6} {:>5} | {:>7} {:>7} {:>8} | {:>8} {:>8} | {:>9} | {:>6} {:>6} {:>6} |",
        "", "int ms", "", "p50", "p99", "max", "p50", "p99", "", "", "", ""
    );
    let mut rows = Vec::new();
    let mut highest_sustained = None;
    for &fps in rates {
        let placement = run_pipeline(&bins, fps, poses);
        let processed = latency(&placement, "mirror_proc", "frame_to_processed");
        let sample = latency(&placement, "mirror_proc", "frame_to_sample");
        let interval = latency(&placement, "camera_proc", "frame_interval");
        let capture = latency(&placement, "camera_proc", "capture_to_publish");
        let tracker_work = latency(&placement, "tracker_proc", "receive_to_publish");
        let mirror_work = latency(&placement, "mirror_proc", "receive_to_publish");
        let baseline_ms = ms(tracker_work, "p50_ms") + ms(mirror_work, "p50_ms");
        let late = stage_counter_or_zero(&placement, "camera_proc", "frames_late");
        let missed = stage_counter_or_zero(&placement, "tracker_proc", "frames_missed")
            + stage_counter_or_zero(&placement, "mirror_proc", "poses_missed");
        let live = &placement["report"];
        let paired = live["train_samples"].as_u64().unwrap_or(0) as usize
            + live["test_samples"].as_u64().unwrap_or(0) as usize;
        let sustained = late == 0 && missed == 0 && paired == planned;
        if sustained {
            highest_sustained = Some(fps);
        }
        println!(
            "{fps:>5.0} | {:>6.1} {late:>5} | {:>7.2} {:>7.2} {:>8.2} | {:>8.2} {:>8.2} | {baseline_ms:>9.2} | {missed:>6} {paired:>3}/{planned:<2} {:>6.2} | {}",
            ms(interval, "p50_ms"),
            ms(processed, "p50_ms"),
            ms(processed, "p99_ms"),
            ms(processed, "max_ms"),
            ms(sample, "p50_ms"),
            ms(sample, "p99_ms"),
            ms(processed, "p50_ms") / baseline_ms,
            if sustained { "yes" } else { "no" }
        );
        rows.push(json!({
            "fps": fps,
            "frames": stage_counter_or_zero(&placement, "camera_proc", "frames"),
            "frames_late": late,
            "frame_interval": interval,
            "simulated_capture": capture,
            "frame_to_processed": processed,
            "frame_to_sample": sample,
            "baseline_stage_work_p50_ms": baseline_ms,
            "tracker_receive_to_publish": tracker_work,
            "mirror_receive_to_publish": mirror_work,
            "frames_missed": stage_counter_or_zero(&placement, "tracker_proc", "frames_missed"),
            "poses_missed": stage_counter_or_zero(&placement, "mirror_proc", "poses_missed"),
            "poses_paired": paired,
            "poses_planned": planned,
            "sustained": sustained,
        }));
        // The measurement itself must be there, or the figures mean nothing.
        assert!(
            processed["count"].as_u64().unwrap_or(0) > 0,
            "no frame_to_processed at {fps} fps: {placement}"
        );
    }
    match highest_sustained {
        Some(fps) => println!("highest rate sustained with nothing missed: {fps} fps"),
        None => println!("no rate was sustained with nothing missed"),
    }
    if full {
        let out = Path::new(env!("CARGO_MANIFEST_DIR")).join("../target/bench");
        std::fs::create_dir_all(&out).unwrap();
        let path = out.join("e2e.json");
        let doc = json!({ "runs": rows, "highest_sustained_fps": highest_sustained });
        std::fs::write(&path, serde_json::to_string_pretty(&doc).unwrap() + "\n").unwrap();
        println!("figures: {}", path.display());
    }
}
