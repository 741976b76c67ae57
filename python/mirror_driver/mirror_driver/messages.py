"""The pipeline's arm messages as ctypes structures.

They match the ``#[repr(C)]`` types of the Rust ``messages`` crate byte for
byte; ``type_name()`` returns the same versioned name, which iceoryx2 checks
(with size and alignment) when a service is opened, so a driver built on an
older layout is refused instead of misread.
"""

import ctypes

#: Most joints a message carries.
MAX_JOINTS = 8

#: ``Role`` wire values of a pose: training, test seen in the mirror, test seen directly.
ROLE_TRAIN, ROLE_TEST, ROLE_DIRECT = 0, 1, 2


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

    @staticmethod
    def type_name() -> str:
        return "mirror.JointPositions.v1"


class PoseGoal(ctypes.Structure):
    """A pose to move to, from the pipeline; ``flags & FINISHED`` ends the plan."""

    FINISHED = 1

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
        return "mirror.PoseGoal.v1"


#: Each message's (size, alignment) in the Rust crate: checked on import.
LAYOUTS = {JointPositions: (88, 8), PoseGoal: (104, 8)}

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
