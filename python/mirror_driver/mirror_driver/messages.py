"""The pipeline's arm messages as ctypes structures.

They match the ``#[repr(C)]`` types of the Rust ``messages`` crate byte for
byte; ``type_name()`` returns the same versioned name, which iceoryx2 checks
(with size and alignment) when a service is opened, so a driver built on an
older layout is refused instead of misread. Names, sizes and wire values
come from the contract (``contract.json``); the fields are checked against
it on import.
"""

import ctypes

from .contract import CONTRACT, GOALS_TOPIC, POSITIONS_TOPIC, TOPICS

#: Most joints a message carries.
MAX_JOINTS = CONTRACT["max_joints"]

#: ``Role`` wire values of a pose: training, test seen in the mirror, test seen directly.
ROLE_TRAIN, ROLE_TEST, ROLE_DIRECT = (CONTRACT["roles"][r] for r in ("train", "test", "direct"))


class JointPositions(ctypes.Structure):
    """The driver's raw joint positions (its encoders), base to tip:
    rad for revolute joints, mm for prismatic ones."""

    _fields_ = [
        ("seq", ctypes.c_uint64),
        ("stamp_ns", ctypes.c_int64),
        ("dof", ctypes.c_uint32),
        ("reserved", ctypes.c_uint32),
        ("q", ctypes.c_double * MAX_JOINTS),
    ]

    TOPIC = POSITIONS_TOPIC

    @staticmethod
    def type_name() -> str:
        return TOPICS[POSITIONS_TOPIC]["type_name"]


class PoseGoal(ctypes.Structure):
    """A pose to move to, from the pipeline; ``flags & FINISHED`` ends the plan."""

    FINISHED = CONTRACT["pose_goal_flags"]["finished"]
    TOPIC = GOALS_TOPIC

    _fields_ = [
        ("seq", ctypes.c_uint64),
        ("stamp_ns", ctypes.c_int64),
        ("pose", ctypes.c_uint64),
        ("role", ctypes.c_uint32),
        ("dof", ctypes.c_uint32),
        ("flags", ctypes.c_uint32),
        ("reserved", ctypes.c_uint32),
        ("q", ctypes.c_double * MAX_JOINTS),
    ]

    @staticmethod
    def type_name() -> str:
        return TOPICS[GOALS_TOPIC]["type_name"]


#: Each message's (size, alignment) in the Rust crate: checked on import.
LAYOUTS = {t: (TOPICS[t.TOPIC]["size"], TOPICS[t.TOPIC]["align"]) for t in (JointPositions, PoseGoal)}

for _t, (_size, _align) in LAYOUTS.items():
    if (ctypes.sizeof(_t), ctypes.alignment(_t)) != (_size, _align):
        raise ImportError(
            f"{_t.type_name()}: ctypes layout is {ctypes.sizeof(_t)} bytes aligned to "
            f"{ctypes.alignment(_t)}, the pipeline's is {_size} aligned to {_align}"
        )


def layout(t) -> dict:
    """Name, size, alignment and field offsets of a message type."""
    return {
        "type_name": t.type_name(),
        "size": ctypes.sizeof(t),
        "align": ctypes.alignment(t),
        "fields": {name: getattr(t, name).offset for name, _ in t._fields_},
    }
