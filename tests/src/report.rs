//! Reading a placement of the launcher's report (`report.json`, or what
//! `--report json` prints): the stages' stats and their counters, and the
//! calibrated plane against the simulator's truth.
//!
//! A placement lists one stats entry per process: a stage the launcher
//! restarted has one for each of its processes.

use serde_json::Value;

/// The stats of `stage`'s first process in `placement`, or `None` if the
/// placement has no stats of that stage.
pub fn stage_stats<'a>(placement: &'a Value, stage: &str) -> Option<&'a Value> {
    placement["stages"]
        .as_array()?
        .iter()
        .find(|s| s["stage"] == stage)
}

/// Counter `name` of `stage`'s first process in `placement`. Panics if the
/// placement has no stats of `stage` or they have no such counter.
pub fn stage_counter(placement: &Value, stage: &str, name: &str) -> u64 {
    let stats =
        stage_stats(placement, stage).unwrap_or_else(|| panic!("no {stage} stats in {placement}"));
    stats["counters"][name]
        .as_u64()
        .unwrap_or_else(|| panic!("no {name} in {stats}"))
}

/// Counter `name` of `stage`'s first process in `placement`, or 0 if the
/// placement has no stats of `stage` or they have no such counter.
pub fn stage_counter_or_zero(placement: &Value, stage: &str, name: &str) -> u64 {
    stage_stats(placement, stage)
        .and_then(|s| s["counters"][name].as_u64())
        .unwrap_or(0)
}

/// Counter `name` summed over every process of `stage` in `placement` (the
/// first and any the launcher restarted); 0 if none has it. Panics if the
/// placement has no list of stats.
pub fn stage_counter_summed_over_processes(placement: &Value, stage: &str, name: &str) -> u64 {
    placement["stages"]
        .as_array()
        .unwrap_or_else(|| panic!("no stage stats in {placement}"))
        .iter()
        .filter(|s| s["stage"] == stage)
        .filter_map(|s| s["counters"][name].as_u64())
        .sum()
}

/// Asserts that `placement`'s calibrated plane is within 0.5 deg and 5 mm
/// of the simulator's truth (`plane_angle_deg`, `plane_distance_mm`).
/// Panics if either is missing.
pub fn assert_plane_near_truth(placement: &Value) {
    let off = |key: &str| {
        placement[key]
            .as_f64()
            .unwrap_or_else(|| panic!("no {key} in {placement}"))
    };
    let (angle, distance) = (off("plane_angle_deg"), off("plane_distance_mm"));
    assert!(
        angle < 0.5 && distance < 5.0,
        "plane off the truth by {angle} deg / {distance} mm"
    );
}
