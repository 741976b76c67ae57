"""The simulated arm as a Python driver: what the built-in `sim_arm` does,
through the mirror_driver SDK. Run by the launcher:

    pipeline --arm-driver "target/pyenv/bin/python python/examples/sim_arm.py"

A real robot's driver replaces `SimulatedArm` with calls to the robot.
"""

import tomllib

from mirror_driver import Driver, monotonic_ns, parse_args

MOVE_NS = 300_000_000


class SimulatedArm:
    """Moves to each goal by a smooth step of MOVE_NS; reads exactly."""

    def __init__(self, home):
        self.start, self.goal, self.t0 = list(home), list(home), 0

    def read_joints(self):
        s = min(max((monotonic_ns() - self.t0) / MOVE_NS, 0.0), 1.0)
        s = s * s * (3.0 - 2.0 * s)
        return [a + (b - a) * s for a, b in zip(self.start, self.goal)]

    def move_to(self, q):
        self.start, self.goal, self.t0 = self.read_joints(), list(q), monotonic_ns()


def main():
    args = parse_args(description=__doc__)
    with open(args.rig, "rb") as f:
        joints = tomllib.load(f)["arm"]["joints"]  # a DH rig: one row per joint
    arm = SimulatedArm([0.5 * (j.get("min", -3.14159) + j.get("max", 3.14159)) for j in joints])
    with Driver(args.prefix, dof=len(joints)) as driver:
        for goal in driver.follow(rate_hz=100, read=arm.read_joints):
            arm.move_to(goal.q)


if __name__ == "__main__":
    main()
