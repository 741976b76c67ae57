//! How a topic's iceoryx2 services are named and opened: every process of
//! a pipeline, in any language, must open them alike (iceoryx2 refuses a
//! service opened with other limits).

/// Buffer of each subscriber of small messages: deep enough that nothing is
/// lost while a stage is busy for seconds (a calibration, a slow start).
pub const SMALL_BUFFER: usize = 1024;
/// Buffer of each frame subscriber: old frames are overwritten, newest
/// kept. Eight frames (89 ms at 90 fps): a tracker kept off both cores by a
/// burst of work above it (the simulated camera drawing the card near the
/// head as the arm moves, at 90 fps) catches up afterwards instead of
/// missing frames (with 4 it missed 2 to 6 in 4 of 5 runs of the e2e
/// bench's plan at 90 fps; with 8 none in 3 of 3).
pub const FRAME_BUFFER: usize = 8;
/// Publishers, subscribers, notifiers and listeners a service takes at
/// most (and twice as many nodes). Every process opening a service must
/// give the same limits: iceoryx2 refuses a service opened with others.
pub const MAX_PORTS: usize = 16;

/// The iceoryx2 service of `topic` in pipeline `prefix`; its event service
/// is this followed by [`EVENT_SUFFIX`].
pub fn name(prefix: &str, topic: &str) -> String {
    format!("mirror/{prefix}/{topic}")
}

/// What follows a topic's service name to name its event service.
pub const EVENT_SUFFIX: &str = "/event";
