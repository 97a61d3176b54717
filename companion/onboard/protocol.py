"""The trajectory upload protocol to the onboard PX4 module (gen_c/px4_module), sans I/O.

Companion -> module: MAVLink DEBUG_FLOAT_ARRAY named ``ecca`` (PX4 publishes it as uORB
``debug_array``), ``array_id`` an opcode, 58 float32 values. Module -> companion: COMMAND_ACK
with ``command`` ACK_CMD (``progress`` = the module's state, ``result_param2`` = opcode << 24 |
a 24-bit value) or ACK_CRC (the answer to COMMIT: ``result_param2`` = the module's CRC-32 of the
upload). `Uploader` sends BEGIN, the segments (several in flight, each acknowledged by its
index) and COMMIT, each part again when no acknowledgement came in time (a timeout adapted to
the link's measured round trip); the upload verifies only if the module echoes the companion's
CRC-32 (zlib's, over the float32 values as sent). BEGIN names the upload by its segments' CRC
(`B_UPLOAD_ID`): a late copy of it, or the same upload sent again, leaves a module that holds
it as it is. The numbers are those of gen_c/px4_module/ecca_onboard_proto.h (a test compares
them).
"""

from __future__ import annotations

import math
import struct
import zlib
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from companion.mavlink.velocity_correction import VELOCITY_CORRECTION_RAD_S
from companion.trajectory import Bezier

FloatArray = npt.NDArray[np.float64]

PROTO_VERSION = 4
PROTO_NAME = "ecca"
MAX_SEGMENTS = 256
N_FLOATS = 58  # DEBUG_FLOAT_ARRAY.data

OP_BEGIN, OP_SEGMENT, OP_COMMIT, OP_ABORT, OP_STATUS = 1, 2, 3, 4, 5
STATE_READY, STATE_RECEIVING, STATE_LOADED, STATE_FLYING = 0, 1, 2, 3
STATE_HOLDING, STATE_DONE, STATE_STOPPED, STATE_ERROR = 4, 5, 6, 7
STATE_NAMES = {STATE_READY: "ready", STATE_RECEIVING: "receiving", STATE_LOADED: "loaded",
               STATE_FLYING: "flying", STATE_HOLDING: "holding", STATE_DONE: "done",
               STATE_STOPPED: "stopped", STATE_ERROR: "error"}
ACK_CMD, ACK_CRC, ACK_START = 31010, 31011, 31012
FINAL_HOLD, FINAL_LAND, FINAL_RTL = 0, 1, 2
FINAL_ACTIONS = {"hold": FINAL_HOLD, "land": FINAL_LAND, "rtl": FINAL_RTL}

# BEGIN layout
B_VERSION, B_N_SEGMENTS, B_SYSID, B_COMPID, B_FINAL_ACTION, B_HOLD_S, B_START_TOL_M = range(7)
B_KP, B_KD, B_KI, B_IMAX = 7, 10, 13, 16
B_HOVER, B_DRAG, B_MASS, B_G, B_THRUST_MIN, B_THRUST_MAX, B_TILT_MAX, B_DRAG_EST = range(19, 27)
B_LEAD_S = 27
B_DIST_BW = 28
B_VCORR_RAD_S = 29
B_UPLOAD_ID = 30  # the segments' CRC-32, low 24 bits (float32-exact): names the content
B_COUNT = 31
# SEGMENT layout
S_INDEX, S_DURATION, S_CTRL, S_YAW, S_COUNT = 0, 1, 2, 26, 34
DEGREE = 7


def _f32(values: Sequence[float]) -> list[float]:
    """The values as the float32 the message carries (what the module stores and hashes)."""
    return list(struct.unpack(f"<{len(values)}f", struct.pack(f"<{len(values)}f", *values)))


@dataclass(frozen=True)
class LawParams:
    """What the module's law needs besides the trajectory (the companion's values at upload):
    gains per axis (x, y, z), hover thrust [normalised], drag [N/(m/s)], mass [kg], g [m/s^2],
    thrust bounds [normalised], tilt limit [rad], drag of the estimated velocity or not, the
    feed-forward's lead [s] (`TrackingConfig.attitude_lead_s`), the disturbance observer's
    bandwidth [rad/s] (0: the module estimates no disturbance), the horizontal velocity
    correction's frequency [rad/s] (the streamed law's `VelocityCorrection`, generated from the
    same step; 0: the module's law gets the reported velocity)."""

    kp: tuple[float, float, float]
    kd: tuple[float, float, float]
    ki: tuple[float, float, float]
    i_max: tuple[float, float, float]
    hover: float
    drag: float
    mass: float
    g: float
    thrust_min: float
    thrust_max: float
    max_tilt_rad: float
    drag_estimate: bool = True
    lead_s: float = 0.15
    dist_bandwidth_rad_s: float = 0.0
    vel_correction_rad_s: float = VELOCITY_CORRECTION_RAD_S


@dataclass(frozen=True)
class Upload:
    """The messages of one upload: (opcode, 58 float32 values) each, and the CRC-32."""

    begin: tuple[float, ...]
    segments: tuple[tuple[float, ...], ...]
    crc: int
    duration_s: float

    def commit(self) -> tuple[float, ...]:
        return _pad([float(self.crc & 0xFFFF), float(self.crc >> 16)])


def _pad(values: Sequence[float]) -> tuple[float, ...]:
    return tuple(values) + (0.0,) * (N_FLOATS - len(values))


def request(sysid: int, compid: int) -> tuple[float, ...]:
    """The data of a companion's request without a body (OP_STATUS, OP_ABORT): its system and
    component ids, to which the module then reports."""
    return _pad([float(sysid), float(compid)])


def _elevate(points: FloatArray, count: int) -> FloatArray:
    """Bezier control points (n+1, d) degree-elevated to `count` points (the same curve)."""
    seg = Bezier(points.reshape(points.shape[0], -1), 1.0)  # (the duration plays no part)
    if seg.degree >= count:
        raise ValueError(f"segment degree {seg.degree} exceeds the module's {count - 1}")
    while seg.degree < count - 1:
        seg = seg.elevate()
    return seg.control_points


def encode_upload(breaks: Sequence[float], control_points: Sequence[FloatArray],
                  yaw_control_points: Sequence[FloatArray] | None, law: LawParams, *,
                  sysid: int, compid: int, final_action: str = "hold", hold_s: float = 2.0,
                  start_tolerance_m: float = 1.5) -> Upload:
    """The messages of a piecewise Bezier trajectory (`breaks` [s], per segment the NED
    control points (n+1, 3) [m] and the yaw's (n+1,) [rad], degree <= 7) for the module."""
    n = len(breaks) - 1
    if not 1 <= n <= MAX_SEGMENTS:
        raise ValueError(f"{n} segments: the module holds 1 to {MAX_SEGMENTS}")
    if final_action not in FINAL_ACTIONS:
        raise ValueError(f"final action {final_action!r}: one of {sorted(FINAL_ACTIONS)}")
    segs: list[list[float]] = []
    seg_crc = 0
    for i in range(n):
        dur = float(breaks[i + 1]) - float(breaks[i])
        if not dur > 0.0:
            raise ValueError(f"segment {i} has duration {dur} s")
        cp = _elevate(np.asarray(control_points[i], dtype=np.float64), DEGREE + 1)
        if cp.shape != (DEGREE + 1, 3):
            raise ValueError(f"segment {i}: control points {cp.shape}, want (n+1, 3)")
        ycp = (np.zeros(DEGREE + 1) if yaw_control_points is None else
               _elevate(np.asarray(yaw_control_points[i], dtype=np.float64), DEGREE + 1)[:, 0])
        vals = _f32([float(i), dur, *cp.ravel().tolist(), *ycp.tolist()])
        assert len(vals) == S_COUNT
        seg_crc = zlib.crc32(struct.pack(f"<{S_COUNT}f", *vals), seg_crc)
        segs.append(vals)
    # the upload's id in BEGIN: a late copy of this BEGIN, or this upload sent again, leaves a
    # module holding it as it is; another trajectory (even with the same law) starts afresh
    head = [float(PROTO_VERSION), float(n), float(sysid), float(compid),
            float(FINAL_ACTIONS[final_action]), hold_s, start_tolerance_m, *law.kp, *law.kd,
            *law.ki, *law.i_max, law.hover, law.drag, law.mass, law.g, law.thrust_min,
            law.thrust_max, law.max_tilt_rad, 1.0 if law.drag_estimate else 0.0, law.lead_s,
            law.dist_bandwidth_rad_s, law.vel_correction_rad_s, float(seg_crc & 0xFFFFFF)]
    assert len(head) == B_COUNT
    begin = _f32(head)
    crc = zlib.crc32(struct.pack(f"<{B_COUNT}f", *begin))
    for vals in segs:
        crc = zlib.crc32(struct.pack(f"<{S_COUNT}f", *vals), crc)
    return Upload(_pad(begin), tuple(_pad(v) for v in segs), crc & 0xFFFFFFFF,
                  float(breaks[-1]) - float(breaks[0]))


@dataclass(frozen=True)
class Ack:
    """One COMMAND_ACK of the module: `state` (STATE_*), `result` (MAV_RESULT), the opcode it
    answers (0 for a CRC answer) and its value (segment index, progress; the CRC)."""

    state: int
    result: int
    op: int
    value: int
    crc: bool = False
    start: bool = False  # a start report: `value` = the start on the autopilot's clock [ms]


def decode_ack(command: int, result: int, progress: int, result_param2: int) -> Ack | None:
    """The module's acknowledgement in a COMMAND_ACK, or None for any other COMMAND_ACK."""
    if command == ACK_CRC:
        return Ack(progress, result, OP_COMMIT, result_param2 & 0xFFFFFFFF, crc=True)
    if command == ACK_START:
        return Ack(progress, result, 0, result_param2, start=True)
    if command == ACK_CMD:
        v = result_param2 & 0xFFFFFFFF
        return Ack(progress, result, v >> 24, v & 0xFFFFFF)
    return None


@dataclass
class Uploader:
    """Upload of `upload`: `poll(now)` gives the message to send now (or None), `on_ack(ack,
    now)` takes each acknowledgement, `wait_s(now)` says how long until `poll` may send [s].
    Finished when `verified` (the module echoed the CRC) or `failed` (a refusal, or a part
    unanswered after `retries` sends and `retries` x `timeout_s` seconds).

    BEGIN and COMMIT go alone (each acknowledged before anything else is sent); the segments
    in between go `window` at a time (selective repeat: each acknowledged by its index, the
    module stores them in any order), at most one message per `pace_s` [s] (PX4's uORB
    `debug_array` holds one message, which the module reads every 4 ms cycle: two in one cycle
    lose the older). A part unanswered is sent again after the retransmission timeout:
    `timeout_s` [s] until a round trip is measured, then smoothed round trip + 4 x its
    variation (RFC 6298, from parts answered at their first send only: Karn's rule), at least
    `min_timeout_s`, at most `timeout_s`, doubled at each resend of the same part up to
    `timeout_s`. Over 20 ms each way with 5 % loss a 210-segment trajectory uploads in ~1.9 s
    where one part at a time with a fixed 0.3 s timeout took ~17 s (bench/bench_upload.py);
    a longer stall costs duplicate parts (the module answers them again), never the upload
    sooner than the fixed timeout gave it up."""

    upload: Upload
    timeout_s: float = 0.3
    retries: int = 10
    min_timeout_s: float = 0.02
    window: int = 8
    pace_s: float = 0.005
    verified: bool = False
    failed: str = ""
    sent: int = 0
    resent: int = 0
    srtt_s: float | None = None  # smoothed round trip [s] (None: not measured yet)
    rttvar_s: float = 0.0  # its mean deviation [s]
    # parts: -1 BEGIN, 0..n-1 the segments, n COMMIT; in flight: part -> (last send [s],
    # sends, first send [s])
    _stage: int = -1  # -1 BEGIN, 0 the segments, 1 COMMIT
    _next: int = 0  # the next segment never sent
    _acked: int = 0  # segments acknowledged
    _flight: dict[int, tuple[float, int, float]] = field(default_factory=dict)
    _last_send: float = -math.inf

    @property
    def done(self) -> bool:
        return self.verified or bool(self.failed)

    def rto_s(self) -> float:
        """The retransmission timeout of a part's first send [s] (see the class)."""
        if self.srtt_s is None:
            return self.timeout_s
        rto = self.srtt_s + max(4.0 * self.rttvar_s, self.min_timeout_s)
        return min(max(rto, self.min_timeout_s), self.timeout_s)

    def _due(self, part: int) -> float:
        """When part `part` (in flight) is sent again [s]."""
        last, tries, _first = self._flight[part]
        return last + min(math.ldexp(self.rto_s(), max(tries - 1, 0)), self.timeout_s)

    def _n(self) -> int:
        return len(self.upload.segments)

    def _fresh(self) -> int | None:
        """The part to send for the first time now, if any."""
        n = self._n()
        if self._stage == -1:
            return None if -1 in self._flight else -1
        if self._stage == 1:
            return None if n in self._flight else n
        if self._next < n and len(self._flight) < self.window:
            return self._next
        return None

    def wait_s(self, now: float) -> float:
        """Seconds until `poll` sends (0: now; inf when done or waiting only for answers
        that cannot time out, which does not happen while a part is in flight)."""
        if self.done:
            return math.inf
        due = 0.0 if self._fresh() is not None else min(
            (self._due(p) for p in self._flight), default=math.inf)
        return max(due - now, self._last_send + self.pace_s - now, 0.0)

    def _message(self, part: int) -> tuple[int, tuple[float, ...]]:
        if part == -1:
            return OP_BEGIN, self.upload.begin
        if part < self._n():
            return OP_SEGMENT, self.upload.segments[part]
        return OP_COMMIT, self.upload.commit()

    def poll(self, now: float) -> tuple[int, tuple[float, ...]] | None:
        if self.done or now - self._last_send < self.pace_s:
            return None
        late = [p for p in self._flight if now >= self._due(p)]
        if late:
            part = min(late, key=self._due)  # the longest overdue first
            _last, tries, first = self._flight[part]
            if tries >= self.retries and now - first >= self.retries * self.timeout_s:
                self.failed = (f"no acknowledgement of part {part + 1} after {tries} sends "
                               f"in {now - first:.1f} s")
                return None
            self._flight[part] = (now, tries + 1, first)
            self.resent += 1
        else:
            fresh = self._fresh()
            if fresh is None:
                return None
            part = fresh
            self._flight[part] = (now, 1, now)
            if self._stage == 0:
                self._next += 1
        self.sent += 1
        self._last_send = now
        return self._message(part)

    def _round_trip(self, part: int, now: float) -> None:
        """Part `part` was answered at `now`: a round-trip sample if it was sent once."""
        last, tries, _first = self._flight.pop(part)
        if tries != 1:
            return  # which send was answered is unknown (Karn)
        r = now - last
        if not (math.isfinite(r) and r >= 0.0):
            return
        if self.srtt_s is None:
            self.srtt_s, self.rttvar_s = r, 0.5 * r
        else:
            self.rttvar_s = 0.75 * self.rttvar_s + 0.25 * abs(self.srtt_s - r)
            self.srtt_s = 0.875 * self.srtt_s + 0.125 * r

    def on_ack(self, ack: Ack, now: float) -> None:
        if self.done or ack.start:
            return
        n = self._n()
        if ack.crc:
            if self._stage != 1 or n not in self._flight:
                return
            if ack.result == 0 and ack.value == self.upload.crc:
                self.verified = True
            else:
                self.failed = (f"the module's CRC 0x{ack.value:08x} is not the upload's "
                               f"0x{self.upload.crc:08x} (result {ack.result})")
            return
        if self._stage == -1 and ack.op == OP_BEGIN and -1 in self._flight:
            part = -1
        elif self._stage == 0 and ack.op == OP_SEGMENT and ack.value in self._flight:
            part = ack.value
        else:
            return  # an answer to an earlier send, or a status report
        if ack.result != 0:
            self.failed = f"the module refused part {part + 1} (result {ack.result})"
            return
        self._round_trip(part, now)
        if part == -1:
            self._stage = 0
        else:
            self._acked += 1
        if self._stage == 0 and self._acked == n:
            self._stage = 1
