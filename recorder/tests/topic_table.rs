//! Walks the topic table: every topic declared in `messages::topics` is
//! held open by `Bus::open_all`, recorded by the recorder's capture, and
//! replayed by `ReplayBus`, byte for byte. A topic added to the table is
//! covered here without editing this test.

use std::collections::BTreeMap;
use std::path::Path;
use std::time::{Duration, Instant};

use messages::topics::{FrameTopic, SmallTopic, TopicId, TopicVisitor};
use messages::{Encoding, FrameHeader};
use recorder::capture::Capture;
use recorder::reader::Recording;
use recorder::replay::{Pace, ReplayBus, ReplayOptions, replay};
use recorder::view::ViewBuilder;
use recorder::writer::{WriterOptions, start};
use runtime::Bus;

fn prefix(name: &str) -> String {
    format!("test{}_{name}", std::process::id())
}

/// Sends a message of topic `T` (small messages marked with their topic's
/// position, so no two topics send the same bytes; frames of 4x2) and
/// returns the publisher, which must outlive the message's reception.
struct Publish<'a>(&'a Bus);

impl TopicVisitor for Publish<'_> {
    type Output = Box<dyn std::any::Any>;
    fn small<T: SmallTopic>(self) -> Self::Output {
        let mut message = T::Message::default();
        // The first field of every message is a u64 or an i64 (a sequence
        // number, pose id or stamp): mark it with the topic.
        bytemuck::bytes_of_mut(&mut message)[0] = 1 + T::ID.index() as u8;
        let publisher = self.0.publisher::<T>().unwrap();
        publisher.send(message).unwrap();
        Box::new(publisher)
    }
    fn frames<T: FrameTopic>(self) -> Self::Output {
        let header = FrameHeader {
            seq: 0,
            stamp_ns: 5,
            published_ns: 0,
            width: 4,
            height: 2,
            stride: 4,
            encoding: Encoding::Mono8 as u32,
        };
        let publisher = self.0.frame_publisher::<T>(16).unwrap();
        publisher
            .publish(header, |left, right| {
                left.fill(1);
                right.fill(2);
                Ok::<_, ()>(true)
            })
            .unwrap()
            .unwrap();
        Box::new(publisher)
    }
}

/// Records what `capture` receives into `path` until `expected` messages came.
fn record(capture: &Capture, path: &Path, expected: usize) {
    let handle = start(
        path,
        WriterOptions::default(),
        ViewBuilder::new(None),
        None,
        false,
    )
    .unwrap();
    let deadline = Instant::now() + Duration::from_secs(20);
    let mut taken = 0;
    while taken < expected && Instant::now() < deadline {
        taken += capture.drain(&handle).unwrap();
        std::thread::sleep(Duration::from_millis(5));
    }
    handle.finish().unwrap();
}

fn lossless(path: &Path) -> BTreeMap<TopicId, Vec<Vec<u8>>> {
    Recording::open(path).unwrap().lossless_by_topic().unwrap()
}

#[test]
fn every_topic_of_the_table_is_held_open_recorded_and_replayed() {
    let dir = tempfile::tempdir().unwrap();

    // Held open: the services exist while `open_all`'s value lives.
    let live = prefix("table_live");
    let observer = Bus::new(&live, "observer").unwrap();
    for t in TopicId::ALL {
        assert!(!observer.service_exists(t).unwrap(), "{t:?} before");
    }
    let launcher = Bus::new(&live, "launcher").unwrap();
    let services = launcher.open_all().unwrap();
    for t in TopicId::ALL {
        assert!(observer.service_exists(t).unwrap(), "{t:?} not held open");
    }

    // Recorded: one message on every topic, each in its own channel.
    let capture = Capture::new(&Bus::new(&live, "recorder").unwrap()).unwrap();
    let source = Bus::new(&live, "source").unwrap();
    let _publishers: Vec<_> = TopicId::ALL
        .into_iter()
        .map(|t| t.visit(Publish(&source)))
        .collect();
    let first = dir.path().join("first.mcap");
    record(&capture, &first, TopicId::COUNT);
    let recorded = lossless(&first);
    for t in TopicId::ALL {
        assert_eq!(
            recorded.get(&t).map_or(0, Vec::len),
            1,
            "{t:?} not recorded"
        );
    }
    drop(services);

    // Replayed: every topic published again, the same bytes.
    let again = prefix("table_replay");
    let recording = Recording::open(&first).unwrap();
    let replay_bus = ReplayBus::create(&again, &recording, &TopicId::ALL).unwrap();
    let capture = Capture::new(&Bus::new(&again, "recorder").unwrap()).unwrap();
    let options = ReplayOptions {
        pace: Pace::Lockstep,
        start_s: 0.0,
        wait_subscribers: 1,
        wait_timeout: Duration::from_secs(10),
        progress: false,
    };
    let stats = replay(&replay_bus, &recording, &options, &|| false).unwrap();
    assert_eq!(stats.published, TopicId::COUNT as u64);
    let second = dir.path().join("second.mcap");
    record(&capture, &second, TopicId::COUNT);
    assert_eq!(lossless(&second), recorded);
}
