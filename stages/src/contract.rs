//! The arm driver contract as data, for processes outside the workspace.
//!
//! `python/mirror_driver` reads `contract.json`, which [`arm_driver`]
//! writes from the topic table, the bus's service settings and the arm
//! driver's declaration; a test fails when the checked-in file is stale.
//! So the SDK hardcodes no service name, topic, type name, size or limit.

use messages::service::{EVENT_SUFFIX, MAX_PORTS, SMALL_BUFFER};
use messages::topics::TopicId;
use messages::{MAX_JOINTS, PoseGoal, Role};
use serde_json::{Value, json};

use crate::{FixedPorts, arm_driver::ArmDriver};

/// The checked-in contract, relative to the workspace root.
pub const PATH: &str = "python/mirror_driver/mirror_driver/contract.json";

/// The environment variable that makes the staleness test write the
/// contract instead of failing.
pub const WRITE_ENV: &str = "MIRROR_WRITE_CONTRACT";

/// The arm driver contract: how services are named and opened, the
/// driver's topics with their layouts, the arguments it is given, and the
/// wire values it reads.
pub fn arm_driver() -> Value {
    let ports = ArmDriver::PORTS;
    let topic = |t: TopicId| {
        let layout = t.layout();
        json!({ "type_name": layout.type_name, "size": layout.size, "align": layout.align })
    };
    let topics: serde_json::Map<String, Value> = ports
        .subscribes
        .iter()
        .chain(ports.publishes)
        .map(|&t| (t.name().to_string(), topic(t)))
        .collect();
    let arguments: Vec<Value> = <crate::arm_driver::Args as clap::Args>::augment_args(
        clap::Command::new(<ArmDriver as crate::Stage>::BINARY),
    )
    .get_arguments()
    .filter_map(|a| a.get_long())
    .map(|long| json!(format!("--{long}")))
    .collect();
    json!({
        "generated_by": "cargo test -p stages (MIRROR_WRITE_CONTRACT=1 rewrites it); do not edit",
        "service": {
            "name": messages::service::name("{prefix}", "{topic}"),
            "event_name": messages::service::name("{prefix}", "{topic}") + EVENT_SUFFIX,
            "subscriber_buffer": SMALL_BUFFER,
            "history_size": 0,
            "max_ports": MAX_PORTS,
            "max_nodes": 2 * MAX_PORTS,
        },
        "subscribes": ports.subscribes.iter().map(|t| t.name()).collect::<Vec<_>>(),
        "publishes": ports.publishes.iter().map(|t| t.name()).collect::<Vec<_>>(),
        "topics": topics,
        "arguments": arguments,
        "max_joints": MAX_JOINTS,
        "roles": Role::ALL.iter().map(|r| (r.as_str(), *r as u32)).collect::<std::collections::BTreeMap<_, _>>(),
        "pose_goal_flags": { "finished": PoseGoal::FINISHED },
    })
}

/// The contract as written to [`PATH`].
pub fn arm_driver_text() -> String {
    serde_json::to_string_pretty(&arm_driver()).expect("a JSON value prints") + "\n"
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    /// The checked-in contract is the one the code writes; with
    /// `MIRROR_WRITE_CONTRACT=1` the test writes it instead.
    #[test]
    fn the_checked_in_contract_is_current() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(PATH);
        let current = arm_driver_text();
        if std::env::var_os(WRITE_ENV).is_some() {
            std::fs::write(&path, &current).unwrap();
        }
        let checked_in = std::fs::read_to_string(&path).unwrap_or_default();
        assert!(
            checked_in == current,
            "{PATH} is stale: run `{WRITE_ENV}=1 cargo test -p stages contract` and commit it"
        );
    }

    #[test]
    fn the_contract_names_the_drivers_ports_and_arguments() {
        let c = arm_driver();
        assert_eq!(c["subscribes"], json!(["pose_goal"]));
        assert_eq!(c["publishes"], json!(["joint_positions"]));
        assert_eq!(c["arguments"], json!(["--prefix", "--rig"]));
        assert_eq!(c["topics"]["pose_goal"]["type_name"], "mirror.PoseGoal.v1");
        assert_eq!(c["service"]["name"], "mirror/{prefix}/{topic}");
    }
}
