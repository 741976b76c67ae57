//! Recorder throughput: rendered stereo frames (640x480 mono, the
//! simulator's images with sensor noise) and joint states pushed through
//! the writer thread as fast as it takes them (frames wait, none dropped),
//! against writing the same bytes to a plain file in the same run.
//!
//! Run: `cargo bench -p recorder --bench throughput` (writes
//! `target/bench/recorder_throughput.json`). Under `cargo test` it runs a
//! few frames only, to check that it works.

use std::io::Write;
use std::path::Path;
use std::time::Instant;

use bytemuck::bytes_of;
use geometry::sim::{Counts, generate, nico_noise, nico_scene};
use geometry::sim::{Facing, SimWorld};
use messages::{Encoding, FrameHeader, JointState};
use recorder::channels::TopicId;
use recorder::view::ViewBuilder;
use recorder::writer::{Compression, Entry, WriterOptions, start};
use renderer::Renderer;

const W: u32 = 640;
const H: u32 = 480;

fn rendered_frames(n: usize) -> Vec<Vec<u8>> {
    let data = generate(
        &nico_scene(),
        0,
        &nico_noise(),
        Counts {
            train: n,
            test: 0,
            direct: 0,
        },
        5,
    )
    .expect("simulated poses");
    let mut renderer = Renderer::new(SimWorld::nico(0).expect("world")).expect("renderer");
    data.train
        .iter()
        .enumerate()
        .map(|(i, s)| {
            let header = FrameHeader {
                seq: i as u64,
                stamp_ns: i as i64 * 33_333_333,
                published_ns: 0,
                width: W,
                height: H,
                stride: W,
                encoding: Encoding::Mono8 as u32,
            };
            let ([l, r], _) = renderer
                .render_pair(s.joints.as_ref().unwrap(), Facing::Mirror, i as u64)
                .expect("render");
            [bytes_of(&header), &l, &r].concat()
        })
        .collect()
}

fn joint_state(seq: u64) -> Vec<u8> {
    bytes_of(&JointState {
        seq,
        stamp_ns: seq as i64 * 10_000_000,
        dof: 4,
        ..Default::default()
    })
    .to_vec()
}

/// The same bytes, written to a plain file through a buffer: the baseline.
fn plain_write(path: &Path, frames: &[Vec<u8>], count: usize) -> f64 {
    let started = Instant::now();
    let mut f = std::io::BufWriter::with_capacity(1 << 20, std::fs::File::create(path).unwrap());
    for i in 0..count {
        f.write_all(&frames[i % frames.len()]).unwrap();
        for k in 0..3 {
            f.write_all(&joint_state((3 * i + k) as u64)).unwrap();
        }
    }
    f.flush().unwrap();
    drop(f);
    started.elapsed().as_secs_f64()
}

struct Run {
    seconds: f64,
    file_bytes: u64,
    message_bytes: u64,
    dropped: u64,
}

fn recorder_write(
    path: &Path,
    frames: &[Vec<u8>],
    count: usize,
    compression: Compression,
    view_images: bool,
) -> Run {
    let options = WriterOptions {
        compression,
        view_images,
        ..Default::default()
    };
    let started = Instant::now();
    let handle = start(path, options, ViewBuilder::new(None), None, false).unwrap();
    for i in 0..count {
        let frame = &frames[i % frames.len()];
        // A fresh copy per frame, as the IPC thread makes from shared memory.
        handle
            .send(Entry {
                topic: TopicId::Frames,
                log_time: i as u64 * 33_333_333,
                publish_time: 0,
                data: frame.clone(),
            })
            .unwrap();
        for k in 0..3 {
            let seq = (3 * i + k) as u64;
            handle
                .send(Entry {
                    topic: TopicId::JointState,
                    log_time: seq * 10_000_000,
                    publish_time: 0,
                    data: joint_state(seq),
                })
                .unwrap();
        }
    }
    let summary = handle.finish().unwrap();
    Run {
        seconds: started.elapsed().as_secs_f64(),
        file_bytes: summary.file_bytes,
        message_bytes: summary.lossless_bytes + summary.view_bytes,
        dropped: summary.frames_dropped_queue_full,
    }
}

fn main() {
    let full = std::env::args().any(|a| a == "--bench");
    let (distinct, count) = if full { (60, 900) } else { (3, 12) };
    let frames = rendered_frames(distinct);
    let dir = tempfile::tempdir().unwrap();
    let frame_bytes = frames[0].len() as f64;
    let input_mb = count as f64 * (frame_bytes + 3.0 * size_of::<JointState>() as f64) / 1e6;
    let plain = plain_write(&dir.path().join("plain.bin"), &frames, count);
    println!(
        "recorder throughput: {count} stereo frames {W}x{H} mono ({:.2} MB each) + 3 joint states per frame",
        frame_bytes / 1e6
    );
    println!(
        "  {:<34} {:>8.3} s {:>9.1} MB/s {:>8.0} frames/s",
        "baseline: plain buffered file write",
        plain,
        input_mb / plain,
        count as f64 / plain
    );
    let mut rows = Vec::new();
    for (name, compression, view_images) in [
        ("recorder zstd, view images", Compression::Zstd, true),
        ("recorder zstd, no view images", Compression::Zstd, false),
        ("recorder lz4, view images", Compression::Lz4, true),
        ("recorder none, view images", Compression::None, true),
    ] {
        let run = recorder_write(
            &dir.path().join("rec.mcap"),
            &frames,
            count,
            compression,
            view_images,
        );
        assert_eq!(run.dropped, 0, "frames wait for the writer");
        println!(
            "  {:<34} {:>8.3} s {:>9.1} MB/s {:>8.0} frames/s  {:>5.2}x baseline time  compression {:.2}:1 ({:.0} MB file)",
            name,
            run.seconds,
            input_mb / run.seconds,
            count as f64 / run.seconds,
            run.seconds / plain,
            run.message_bytes as f64 / run.file_bytes as f64,
            run.file_bytes as f64 / 1e6
        );
        rows.push(serde_json::json!({
            "name": name,
            "seconds": run.seconds,
            "input_mb_per_s": input_mb / run.seconds,
            "stereo_frames_per_s": count as f64 / run.seconds,
            "time_vs_baseline": run.seconds / plain,
            "compression_ratio": run.message_bytes as f64 / run.file_bytes as f64,
            "file_bytes": run.file_bytes,
            "dropped": run.dropped,
        }));
    }
    if full {
        let json = serde_json::json!({
            "frames": count,
            "frame_bytes": frame_bytes,
            "baseline_seconds": plain,
            "baseline_mb_per_s": input_mb / plain,
            "recorder": rows,
        });
        let out = Path::new(env!("CARGO_MANIFEST_DIR")).join("../target/bench");
        std::fs::create_dir_all(&out).unwrap();
        let path = out.join("recorder_throughput.json");
        std::fs::write(&path, serde_json::to_string_pretty(&json).unwrap() + "\n").unwrap();
        println!("  figures: {}", path.display());
    }
}
