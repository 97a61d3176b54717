"""Seed inputs of the fuzz targets: the bundled missions, and datagram scripts that reach deep
states (valid frames of every handled type, PARAM_SET of every parameter)."""

from __future__ import annotations

import struct
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def mission_seeds() -> list[bytes]:
    """Every bundled mission file (examples and test data, good and bad)."""
    dirs = [ROOT / "examples" / "missions", ROOT / "tests" / "data" / "missions",
            ROOT / "tests" / "data" / "missions" / "bad"]
    return [p.read_bytes() for d in dirs for p in sorted(d.iterdir())
            if p.suffix in (".plan", ".waypoints")]


def chunk(kind: int, data: bytes) -> bytes:
    """One chunk of the datagram input format (see targets.py)."""
    return bytes((kind, len(data))) + data[:255]


def datagram_seeds(n_kinds: int, n_params: int) -> list[bytes]:
    """Per message kind a zero and a 0xFF payload; per parameter a PARAM_SET of its default
    type with 1.0 and with -1e30; a stray 2-byte datagram between two frames."""
    seeds = [chunk(k, bytes(60)) + chunk(0xFF, b"\x05" * 5) for k in range(1, n_kinds + 1)]
    seeds += [chunk(k, b"\xff" * 60) for k in range(1, n_kinds + 1)]
    for i in range(n_params):
        for v in (1.0, -1e30):
            seeds.append(chunk(0xF0, bytes((i,)) + struct.pack("<f", v) + b"\x01"))
    seeds.append(chunk(1, bytes(9)) + chunk(0, b"\xfd\x05") + chunk(1, bytes(9)))
    return seeds
