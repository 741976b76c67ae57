//! What journaling costs per sample: appending one `MirrorSample` to a
//! journal (its own CRC'd MCAP chunk), synced to disk (the default) and
//! handed to the OS only (as before syncing), against a baseline measured
//! in the same run: the same bytes written to a plain file and flushed.
//! Run: `cargo bench -p runtime --bench journal`.

use std::hint::black_box;
use std::io::Write;

use criterion::{Criterion, criterion_group, criterion_main};
use messages::MirrorSample;
use messages::topics::{self, Topic};
use runtime::journal::{Durability, Journal};

fn bench(c: &mut Criterion) {
    // In the target directory, on the disk the build is on: /tmp may be a
    // tmpfs, where a sync costs nothing.
    let dir = tempfile::tempdir_in(env!("CARGO_TARGET_TMPDIR")).unwrap();
    let sample = MirrorSample {
        pose: 7,
        stamp_ns: 123_456_789,
        dof: 4,
        q: [0.25; messages::MAX_JOINTS],
        ..Default::default()
    };
    let mut group = c.benchmark_group("journal_append");
    let mut plain =
        std::io::BufWriter::new(std::fs::File::create(dir.path().join("plain.bin")).unwrap());
    group.bench_function("baseline: plain write and flush", |b| {
        b.iter(|| {
            plain
                .write_all(bytemuck::bytes_of(black_box(&sample)))
                .unwrap();
            plain.flush().unwrap();
        })
    });
    for (name, durability) in [
        (
            "journal: one sample, flushed to the OS",
            Durability::Flushed,
        ),
        ("journal: one sample, synced to disk", Durability::Synced),
        (
            "journal: one sample, synced behind by its thread",
            Durability::SyncedBehind,
        ),
    ] {
        let path = dir.path().join(format!("{durability:?}.mcap"));
        let (mut journal, _) =
            Journal::open_with(path, &[topics::Samples::ID], durability).unwrap();
        group.bench_function(name, |b| {
            b.iter(|| {
                journal
                    .append::<topics::Samples>(black_box(&sample))
                    .unwrap()
            })
        });
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
