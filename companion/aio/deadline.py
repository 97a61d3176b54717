"""Native deadline wait and send for the setpoint streamer (``native/ecca_deadline.c``).

ctypes releases the GIL for each call, so the sender thread waits for its deadline and sends the
datagram without the interpreter: a busy asyncio thread cannot delay the send, and in busy-wait
mode the waiting thread keeps its core awake (on virtual machines a halted vCPU can take
milliseconds to wake). Compiled on first use with the system C compiler into the same cache as
the generated setpoint library (``gen_c.native``); :func:`load_deadline_library` returns ``None``
when no compiler is available (the streamer then waits and sends in Python).

Times are ``time.monotonic()`` seconds on the Python side and CLOCK_MONOTONIC nanoseconds in C
(the same clock on Linux).
"""

from __future__ import annotations

import ctypes
import logging
import sys
import threading
from pathlib import Path

from gen_c.native import NativeBuildError, build_library

__all__ = ["NativeDeadline", "load_deadline_library"]

log = logging.getLogger(__name__)

NATIVE_DIR = Path(__file__).resolve().parent / "native"
_lock = threading.Lock()
_loaded: list[NativeDeadline | None] = []


class NativeDeadline:
    """ctypes binding of ``ecca_deadline.c``."""

    def __init__(self, path: Path) -> None:
        lib = ctypes.CDLL(str(path))
        i64 = ctypes.c_int64
        lib.ecca_now_ns.restype = i64
        lib.ecca_now_ns.argtypes = []
        lib.ecca_set_timer_slack_ns.restype = ctypes.c_int
        lib.ecca_set_timer_slack_ns.argtypes = [ctypes.c_ulong]
        lib.ecca_wait_until.restype = i64
        lib.ecca_wait_until.argtypes = [i64, i64]
        lib.ecca_wait_send.restype = i64
        lib.ecca_wait_send.argtypes = [i64, i64, ctypes.c_int, ctypes.c_char_p, ctypes.c_size_t,
                                       ctypes.c_char_p, ctypes.c_uint32,
                                       ctypes.POINTER(ctypes.c_int)]
        self._lib = lib
        self._err = ctypes.c_int(0)
        self._err_ref = ctypes.byref(self._err)
        self.path = path

    def now(self) -> float:
        """CLOCK_MONOTONIC [s]."""
        return float(self._lib.ecca_now_ns()) * 1e-9

    def set_timer_slack(self, slack_s: float) -> bool:
        """Set the calling thread's timer slack [s]; True on success."""
        return int(self._lib.ecca_set_timer_slack_ns(max(1, round(slack_s * 1e9)))) == 0

    def wait_until(self, deadline_s: float, spin_s: float | None) -> float:
        """Return at ``deadline_s`` (never earlier): sleep until ``deadline_s - spin_s`` then
        busy-wait; ``spin_s=None`` busy-waits the whole way. Returns the clock after [s]."""
        spin = -1 if spin_s is None else round(spin_s * 1e9)
        return float(self._lib.ecca_wait_until(round(deadline_s * 1e9), spin)) * 1e-9

    def wait_send(self, deadline_s: float, spin_s: float | None, fd: int, data: bytes,
                  addr: bytes | None) -> tuple[float, int]:
        """Wait as :meth:`wait_until`, then send ``data`` on ``fd`` (``sendto`` ``addr``, a
        packed sockaddr, or ``send`` when None). Returns (time just before the send [s], errno
        or 0)."""
        spin = -1 if spin_s is None else round(spin_s * 1e9)
        t = self._lib.ecca_wait_send(round(deadline_s * 1e9), spin, fd, data, len(data),
                                     addr, 0 if addr is None else len(addr), self._err_ref)
        return float(t) * 1e-9, int(self._err.value)


def load_deadline_library() -> NativeDeadline | None:
    """The compiled helper (built on first use, cached per process), or None with one warning
    when it cannot be built on this machine (then the streamer waits in Python)."""
    with _lock:
        if not _loaded:
            lib: NativeDeadline | None = None
            if sys.platform.startswith("linux"):
                try:
                    lib = NativeDeadline(build_library(
                        NATIVE_DIR, sources=("ecca_deadline.c",), headers=(),
                        name="ecca_deadline"))
                except (NativeBuildError, OSError) as exc:
                    log.warning("native deadline sender unavailable, waiting in Python: %s", exc)
            _loaded.append(lib)
        return _loaded[0]

