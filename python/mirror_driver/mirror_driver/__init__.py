"""Join a robot's arm driver to the mirror perspective-taking pipeline.

The contract (see the project's docs/real_robot.md; its data is
``contract.json``, generated from the pipeline's own tables):

- publish the arm's joint positions, stamped with CLOCK_MONOTONIC, on the
  ``joint_positions`` topic, at the driver's own rate;
- move to each pose goal received on ``pose_goal``; the pipeline decides
  from the positions when the arm has settled, and sends the next goal;
- stop when a goal says the plan is finished.

A driver in about ten lines::

    from mirror_driver import Driver

    with Driver(prefix, dof=6) as driver:
        for goal in driver.follow(rate_hz=100, read=robot.read_joints):
            robot.move_to(goal.q)

``follow`` publishes ``read()`` every tick and yields each new goal; it
returns when the plan is finished.
"""

import argparse
import ctypes
import time
from dataclasses import dataclass
from typing import Callable, Iterator, List, Optional, Sequence

import iceoryx2 as iox2

from .contract import CONTRACT, SERVICE, event_name, service_name
from .messages import MAX_JOINTS, ROLE_DIRECT, ROLE_TEST, ROLE_TRAIN, JointPositions, PoseGoal, layout

__all__ = [
    "Driver",
    "Goal",
    "JointPositions",
    "PoseGoal",
    "MAX_JOINTS",
    "ROLE_TRAIN",
    "ROLE_TEST",
    "ROLE_DIRECT",
    "layout",
    "monotonic_ns",
    "parse_args",
]

# The pipeline's service settings: a service opened with other limits is
# refused by iceoryx2.
_SMALL_BUFFER = SERVICE["subscriber_buffer"]
_MAX_PORTS = SERVICE["max_ports"]
_MAX_NODES = SERVICE["max_nodes"]
_HISTORY = SERVICE["history_size"]


def monotonic_ns() -> int:
    """The stamp clock of the pipeline: CLOCK_MONOTONIC, ns."""
    return time.clock_gettime_ns(time.CLOCK_MONOTONIC)


@dataclass(frozen=True)
class Goal:
    """A pose to move to."""

    pose: int
    role: int
    q: List[float]
    finished: bool
    stamp_ns: int


def parse_args(argv: Optional[Sequence[str]] = None, description: str = "") -> argparse.Namespace:
    """The arguments the launcher gives every arm driver: ``--prefix`` and ``--rig``."""
    if CONTRACT["arguments"] != ["--prefix", "--rig"]:
        raise ImportError(f"the pipeline gives drivers {CONTRACT['arguments']}; this SDK knows --prefix and --rig")
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--prefix", default="default", help="service prefix of the pipeline")
    parser.add_argument("--rig", required=True, help="rig file (TOML) with the arm")
    return parser.parse_args(argv)


class Driver:
    """One arm driver's connection to pipeline ``prefix``, for an arm of
    ``dof`` joints (the chain's joints from base to tip, as in the rig)."""

    def __init__(self, prefix: str, dof: int, name: str = "arm_driver"):
        if not 0 < dof <= MAX_JOINTS:
            raise ValueError(f"dof {dof}: an arm has 1 to {MAX_JOINTS} joints")
        iox2.set_log_level_from_env_or(iox2.LogLevel.Error)
        self.dof = dof
        self._seq = 0
        self._last_pose: Optional[int] = None
        self._node = iox2.NodeBuilder.new().name(iox2.NodeName.new(name)).create(iox2.ServiceType.Ipc)
        positions = self._service(prefix, JointPositions.TOPIC, JointPositions)
        self._publisher = positions.publisher_builder().create()
        self._notifier = self._event(prefix, JointPositions.TOPIC).notifier_builder().create()
        goals = self._service(prefix, PoseGoal.TOPIC, PoseGoal)
        self._subscriber = goals.subscriber_builder().buffer_size(_SMALL_BUFFER).create()

    def _service(self, prefix: str, topic: str, t):
        name = iox2.ServiceName.new(service_name(prefix, topic))
        return (
            self._node.service_builder(name)
            .publish_subscribe(t)
            .subscriber_max_buffer_size(_SMALL_BUFFER)
            .history_size(_HISTORY)
            .max_publishers(_MAX_PORTS)
            .max_subscribers(_MAX_PORTS)
            .max_nodes(_MAX_NODES)
            .open_or_create()
        )

    def _event(self, prefix: str, topic: str):
        name = iox2.ServiceName.new(event_name(prefix, topic))
        return (
            self._node.service_builder(name)
            .event()
            .max_notifiers(_MAX_PORTS)
            .max_listeners(_MAX_PORTS)
            .max_nodes(_MAX_NODES)
            .open_or_create()
        )

    def publish(self, q: Sequence[float], stamp_ns: Optional[int] = None) -> None:
        """Publishes one reading of the joints (rad, or mm for prismatic joints)."""
        if len(q) != self.dof:
            raise ValueError(f"{len(q)} joint positions for an arm of {self.dof}")
        msg = JointPositions(seq=self._seq, stamp_ns=monotonic_ns() if stamp_ns is None else stamp_ns, dof=self.dof)
        for i, v in enumerate(q):
            msg.q[i] = float(v)
        self._publisher.send_copy(msg)
        self._notifier.notify()
        self._seq += 1

    def goals(self) -> List[Goal]:
        """The goals received since the last call, oldest first (bad ones skipped)."""
        out = []
        while True:
            sample = self._subscriber.receive()
            if sample is None:
                return out
            g = sample.payload().contents
            finished = bool(g.flags & PoseGoal.FINISHED)
            if not finished and g.dof != self.dof:
                continue
            out.append(Goal(g.pose, g.role, list(g.q[: g.dof]), finished, g.stamp_ns))

    def follow(self, rate_hz: float, read: Callable[[], Sequence[float]]) -> Iterator[Goal]:
        """Publishes ``read()`` at ``rate_hz`` and yields each new goal (a goal
        sent again is yielded once); returns when the plan is finished."""
        period_ns = int(1e9 / rate_hz)
        next_ns = monotonic_ns()
        while True:
            for goal in self.goals():
                if goal.finished:
                    return
                if goal.pose != self._last_pose:
                    self._last_pose = goal.pose
                    yield goal
            self.publish(read())
            next_ns += period_ns
            time.sleep(max(0.0, (next_ns - monotonic_ns()) * 1e-9))

    def close(self) -> None:
        """Releases the ports."""
        for port in (self._subscriber, self._notifier, self._publisher):
            port.delete()

    def __enter__(self) -> "Driver":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
