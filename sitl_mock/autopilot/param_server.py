"""The parameter protocol: PARAM_REQUEST_LIST / PARAM_REQUEST_READ / PARAM_SET over the links.

Integer parameters travel with PX4's bytewise encoding (the int32's bytes as a float32).
"""

from __future__ import annotations

import struct
from collections import Counter
from collections.abc import Callable
from typing import Any

from pymavlink.dialects.v20 import common as mavlink

from sitl_mock.autopilot.links import Link, Links
from sitl_mock.autopilot.shared import Msg, addressed_to_us
from sitl_mock.params import PARAMS, ParamStore


def float_bits_of_int(v: int) -> float:
    """PX4 bytewise encoding: the int32's bytes reinterpreted as a float32."""
    return float(struct.unpack("<f", struct.pack("<i", int(v)))[0])


def int_of_float_bits(f: float) -> int:
    """The int32 whose bytes are the float32 `f` (inverse of `float_bits_of_int`)."""
    return int(struct.unpack("<i", struct.pack("<f", f))[0])


def param_name(raw: Any) -> str:
    """A param_id field as text (bytes or str, cut at the first NUL)."""
    if isinstance(raw, bytes):
        raw = raw.decode("ascii", "replace")
    return str(raw).split("\x00", 1)[0]


class ParamServer:
    """Serves `params` on the links: list, read by name or index, set (checked, echoed)."""

    def __init__(self, params: ParamStore, links: Links, stats: Counter[str]) -> None:
        self.params = params
        self.links = links
        self.stats = stats

    def handlers(self) -> dict[str, Callable[[Link, Msg], None]]:
        """Message type -> handler for the parameter protocol."""
        return {
            "PARAM_REQUEST_LIST": self._on_param_request_list,
            "PARAM_REQUEST_READ": self._on_param_request_read,
            "PARAM_SET": self._on_param_set,
        }

    def param_value(self, name: str) -> Msg:
        """PARAM_VALUE of parameter `name` (its index and the count of all parameters)."""
        spec = PARAMS[name]
        v = self.params[name]
        if spec.is_int:
            value, ptype = float_bits_of_int(int(v)), mavlink.MAV_PARAM_TYPE_INT32
        else:
            value, ptype = float(v), mavlink.MAV_PARAM_TYPE_REAL32
        return mavlink.MAVLink_param_value_message(
            name.encode("ascii"), value, ptype, len(self.params), self.params.index(name)
        )

    def _to_us(self, msg: Msg) -> bool:
        return addressed_to_us(self.stats, msg.target_system, msg.target_component)

    def _on_param_request_list(self, link: Link, msg: Msg) -> None:
        if self._to_us(msg):
            for name in self.params:
                self.links.send(link, self.param_value(name))

    def _on_param_request_read(self, link: Link, msg: Msg) -> None:
        if not self._to_us(msg):
            return
        if msg.param_index >= 0:
            names = list(self.params)
            if msg.param_index < len(names):
                self.links.send(link, self.param_value(names[msg.param_index]))
            return
        name = param_name(msg.param_id)
        if name in PARAMS:
            self.links.send(link, self.param_value(name))

    def _on_param_set(self, link: Link, msg: Msg) -> None:
        if not self._to_us(msg):
            return
        name = param_name(msg.param_id)
        spec = PARAMS.get(name)
        if spec is None:
            self.stats["param_unknown"] += 1
            return
        value = float(msg.param_value)
        real = (mavlink.MAV_PARAM_TYPE_REAL32, mavlink.MAV_PARAM_TYPE_REAL64)
        problem: str | None = None
        new = value
        if spec.is_int and msg.param_type == mavlink.MAV_PARAM_TYPE_INT32:
            new = float(int_of_float_bits(value))
        elif spec.is_int and msg.param_type in real:
            pass  # lenient (PX4 refuses): an integral float value is taken, checked below
        elif spec.is_int or msg.param_type not in real:
            problem = "param types mismatch"  # PX4's words ("[pm] param types mismatch ...")
        if problem is None:
            try:
                self.params.set(name, new)
            except ValueError as exc:
                problem = str(exc)
        if problem is not None:
            # PX4 takes any in-type value; the mock refuses what would break its simulation or
            # lies outside PX4's metadata range, says why, and echoes the unchanged value
            self.stats["param_rejected"] += 1
            self.links.statustext(mavlink.MAV_SEVERITY_ERROR, f"[pm] {name}: {problem}")
        self.links.broadcast(self.param_value(name))
