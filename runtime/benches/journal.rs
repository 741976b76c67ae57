//! What journaling costs per sample: appending one `MirrorSample` to a
//! journal (its own CRC'd MCAP chunk, handed to the OS) against a baseline
//! measured in the same run, writing the same bytes to a plain file and
//! flushing it the same way.
//! Run: `cargo bench -p runtime --bench journal`.

use std::hint::black_box;
use std::io::Write;

use criterion::{Criterion, criterion_group, criterion_main};
use messages::MirrorSample;
use messages::topics::{self, Topic};
use runtime::journal::Journal;

fn bench(c: &mut Criterion) {
    let dir = tempfile::tempdir().unwrap();
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
    let (mut journal, _) =
        Journal::open(dir.path().join("journal.mcap"), &[topics::Samples::ID]).unwrap();
    group.bench_function("journal: one sample", |b| {
        b.iter(|| {
            journal
                .append::<topics::Samples>(black_box(&sample))
                .unwrap()
        })
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
