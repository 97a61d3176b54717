"""The onboard module's logic (gen_c/px4_module/ecca_onboard_core.c) on the host, via ctypes.

The same C the PX4 module runs, without PX4: the upload protocol's receiving end, the flight's
state machine and the tracking law. The tests drive it against the companion's uploader; the
mock autopilot can fly it behind the same MAVLink protocol. Imports nothing from ``companion``.

    lib = OnboardLibrary(build_onboard_library())   # NativeBuildError without a C compiler
    m = OnboardModule(lib)
    ack = m.message(op, data58)           # OnboardAck or None
    out = m.step(now_s, offboard, pos_ok, pos_ned, vel_ned, q_wxyz)
"""

from __future__ import annotations

import ctypes
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from gen_c.native import LIB_DIR, build_library

_CORE = "../px4_module/ecca_onboard_core.c"
SOURCES = ("ecca_setpoint.c", "ecca_gen_d.c", _CORE)
HEADERS = ("ecca_setpoint.h", "ecca_setpoint_gen.h", "ecca_setpoint_impl.inc", "ecca_gen_d.h",
           "../px4_module/ecca_onboard_core.h", "../px4_module/ecca_onboard_proto.h")
N_FLOATS = 58
MAX_SEGMENTS = 256  # ECCA_MAX_SEGMENTS
B_COUNT = 31  # ECCA_B_COUNT


class _Ack(ctypes.Structure):
    _fields_ = [("command", ctypes.c_uint32), ("result", ctypes.c_uint8),
                ("state", ctypes.c_uint8), ("value", ctypes.c_int32)]


class _Output(ctypes.Structure):
    _fields_ = [("publish_mode", ctypes.c_int), ("publish_setpoint", ctypes.c_int),
                ("q_d", ctypes.c_float * 4), ("thrust", ctypes.c_float),
                ("yaw_rate", ctypes.c_float), ("final_action", ctypes.c_int),
                ("event", ctypes.c_int), ("start_error_m", ctypes.c_double),
                ("dist_ne", ctypes.c_float * 2)]


@dataclass(frozen=True)
class _Segment(ctypes.Structure):
    _fields_ = [("duration", ctypes.c_float), ("ctrl", ctypes.c_float * 3 * 8),
                ("yaw", ctypes.c_float * 8)]


class _Core(ctypes.Structure):
    """The head of `ecca_onboard` (ecca_onboard_core.h; its size is checked at load)."""

    _fields_ = [("state", ctypes.c_int), ("n_expected", ctypes.c_int),
                ("n_received", ctypes.c_int), ("have", ctypes.c_uint8 * MAX_SEGMENTS),
                ("begin", ctypes.c_float * B_COUNT), ("seg", _Segment * MAX_SEGMENTS),
                ("t_start_seg", ctypes.c_double * (MAX_SEGMENTS + 1)),
                ("crc", ctypes.c_uint32), ("peer_sys", ctypes.c_uint8),
                ("peer_comp", ctypes.c_uint8), ("t0", ctypes.c_double),
                ("t_hold", ctypes.c_double), ("t_last", ctypes.c_double),
                ("integ", ctypes.c_double * 3), ("progress", ctypes.c_double),
                ("t_final", ctypes.c_double), ("v_hat", ctypes.c_double * 2),
                ("d_hat", ctypes.c_double * 2), ("t_sample", ctypes.c_double),
                ("have_sample", ctypes.c_int), ("u_last", ctypes.c_double),
                ("vc_w", ctypes.c_double), ("vc_p", ctypes.c_double * 2),
                ("vc_v", ctypes.c_double * 2), ("vc_c", ctypes.c_double * 2),
                ("vc_t", ctypes.c_double), ("vc_have", ctypes.c_int)]


@dataclass(frozen=True)
class OnboardAck:
    """An acknowledgement the module sends as COMMAND_ACK: command, result (MAV_RESULT),
    state (its progress field), value (result_param2, signed 32 bit)."""

    command: int
    result: int
    state: int
    value: int


@dataclass(frozen=True)
class OnboardOutput:
    """One step's requests (see ecca_onboard_core.h): publish offboard_control_mode, publish
    the attitude setpoint q_d (w, x, y, z) / thrust [normalised] / yaw_rate [rad/s], command
    final_action (-1: none), the event (ECCA_EV_*), the start error [m] and the disturbance
    estimate in use (north, east [m/s^2])."""

    publish_mode: bool
    publish_setpoint: bool
    q_d: tuple[float, float, float, float]
    thrust: float
    yaw_rate: float
    final_action: int
    event: int
    start_error_m: float
    dist_ne: tuple[float, float] = (0.0, 0.0)


class OnboardLibrary:
    """The compiled onboard core (shared by every `OnboardModule`)."""

    def __init__(self, path: Path) -> None:
        self.path = path
        lib = ctypes.CDLL(str(path))
        lib.ecca_onboard_size.restype = ctypes.c_ulong
        lib.ecca_onboard_size.argtypes = []
        lib.ecca_onboard_init.restype = None
        lib.ecca_onboard_init.argtypes = [ctypes.c_void_p]
        lib.ecca_onboard_message.restype = ctypes.c_int
        lib.ecca_onboard_message.argtypes = [ctypes.c_void_p, ctypes.c_int,
                                             ctypes.POINTER(ctypes.c_float),
                                             ctypes.POINTER(_Ack)]
        lib.ecca_onboard_status.restype = None
        lib.ecca_onboard_status.argtypes = [ctypes.c_void_p, ctypes.POINTER(_Ack)]
        lib.ecca_onboard_start_report.restype = ctypes.c_int
        lib.ecca_onboard_start_report.argtypes = [ctypes.c_void_p, ctypes.POINTER(_Ack)]
        lib.ecca_onboard_step.restype = None
        lib.ecca_onboard_step.argtypes = [ctypes.c_void_p, ctypes.c_double, ctypes.c_int,
                                          ctypes.c_int, ctypes.POINTER(ctypes.c_double),
                                          ctypes.POINTER(ctypes.c_double), ctypes.c_double,
                                          ctypes.POINTER(ctypes.c_double),
                                          ctypes.POINTER(_Output)]
        self.lib = lib
        self.size = int(lib.ecca_onboard_size())
        if self.size != ctypes.sizeof(_Core):
            raise RuntimeError(f"{path}: ecca_onboard is {self.size} bytes, the ctypes mirror "
                               f"{ctypes.sizeof(_Core)}: ecca_onboard_core.h changed")


class OnboardModule:
    """One module instance (its whole state in a buffer this object owns)."""

    def __init__(self, library: OnboardLibrary) -> None:
        self._lib = library.lib
        self._buf = ctypes.create_string_buffer(library.size)
        self._lib.ecca_onboard_init(self._buf)

    @property
    def state(self) -> int:
        """The module's state (ECCA_STATE_*)."""
        return int(_Core.from_buffer(self._buf).state)

    @property
    def peer(self) -> tuple[int, int]:
        """The module's peer: the system and component id its acknowledgements go to (0, 0
        before a STATUS or BEGIN named one)."""
        c = _Core.from_buffer(self._buf)
        return int(c.peer_sys), int(c.peer_comp)

    def message(self, op: int, data: Sequence[float]) -> OnboardAck | None:
        """Take one protocol message (opcode, up to 58 values); the acknowledgement or None."""
        if len(data) > N_FLOATS:
            raise ValueError(f"at most {N_FLOATS} values, got {len(data)}")
        arr = (ctypes.c_float * N_FLOATS)(*[float(x) for x in data])
        ack = _Ack()
        if not self._lib.ecca_onboard_message(self._buf, int(op), arr, ctypes.byref(ack)):
            return None
        return OnboardAck(ack.command, ack.result, ack.state, ack.value)

    def status(self) -> OnboardAck:
        """The periodic status report."""
        ack = _Ack()
        self._lib.ecca_onboard_status(self._buf, ctypes.byref(ack))
        return OnboardAck(ack.command, ack.result, ack.state, ack.value)

    def start_report(self) -> OnboardAck | None:
        """The start report sent with each status while flown (None before)."""
        ack = _Ack()
        if not self._lib.ecca_onboard_start_report(self._buf, ctypes.byref(ack)):
            return None
        return OnboardAck(ack.command, ack.result, ack.state, ack.value)

    def step(self, now_s: float, offboard: bool, pos_ok: bool, pos_ned: Sequence[float],
             vel_ned: Sequence[float], q_wxyz: Sequence[float] | None = None,
             sample_s: float | None = None) -> OnboardOutput:
        """One control step at `now_s` [s]: armed in OFFBOARD or not, the estimate valid or
        not, position [m] and velocity [m/s] NED sampled at `sample_s` [s] (default: now),
        the estimated attitude `q_wxyz` (body FRD -> NED; None: unknown, the disturbance
        observer does not learn). Each new valid sample updates the velocity correction (in
        every state); the observer and the law get the corrected velocity."""
        p = (ctypes.c_double * 3)(*[float(x) for x in pos_ned])
        v = (ctypes.c_double * 3)(*[float(x) for x in vel_ned])
        q = None if q_wxyz is None else (ctypes.c_double * 4)(*[float(x) for x in q_wxyz])
        o = _Output()
        self._lib.ecca_onboard_step(self._buf, float(now_s), int(bool(offboard)),
                                    int(bool(pos_ok)), p, v,
                                    float(now_s if sample_s is None else sample_s), q,
                                    ctypes.byref(o))
        return OnboardOutput(bool(o.publish_mode), bool(o.publish_setpoint),
                             (o.q_d[0], o.q_d[1], o.q_d[2], o.q_d[3]), o.thrust, o.yaw_rate,
                             o.final_action, o.event, o.start_error_m,
                             (o.dist_ne[0], o.dist_ne[1]))

    @property
    def disturbance(self) -> tuple[float, float]:
        """The disturbance observer's estimate (north, east [m/s^2])."""
        c = _Core.from_buffer(self._buf)
        return (float(c.d_hat[0]), float(c.d_hat[1]))

    @property
    def velocity_correction(self) -> tuple[float, float]:
        """The velocity correction (north, east [m/s]): what the module adds to the reported
        horizontal velocity before its observer and law (0, 0 while off)."""
        c = _Core.from_buffer(self._buf)
        return (float(c.vc_c[0]), float(c.vc_c[1]))

    @property
    def velocity_correction_rad_s(self) -> float:
        """The velocity correction's frequency in use [rad/s] (the default until an upload's
        BEGIN is accepted, then that upload's; 0: off)."""
        return float(_Core.from_buffer(self._buf).vc_w)


def build_onboard_library(*, cache: Path | None = None) -> Path:
    """Compile the onboard core with the setpoint library (double) into the cache."""
    return build_library(LIB_DIR, cache=cache, sources=SOURCES, headers=HEADERS,
                         extra_flags=("-DECCA_SETPOINT_NO_FLOAT",), name="ecca_onboard")

