"""The C deadline helper and the streamer's native path: never early, the exact bytes on the
wire to the right peer, producer called on the deadline grid. Real clock, loopback UDP, bounded
loops; no timing thresholds (lateness depends on the machine, see bench/bench_stream.py)."""

from __future__ import annotations

import errno
import itertools
import os
import random
import socket
import time
from collections.abc import Iterator

import pytest

from companion.aio import FixedRateStreamer
from companion.aio.deadline import NativeDeadline, load_deadline_library
from companion.aio.transports import sockaddr_bytes


@pytest.fixture(scope="module")
def lib() -> NativeDeadline:
    native = load_deadline_library()
    assert native is not None, "the C helper must build here (CI installs a C compiler)"
    return native


@pytest.fixture
def receiver() -> Iterator[socket.socket]:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        s.bind(("127.0.0.1", 0))
        s.settimeout(2.0)
        yield s
    finally:
        s.close()


@pytest.mark.parametrize("spin_s", [200e-6, None])
def test_wait_until_never_returns_early(lib: NativeDeadline, spin_s: float | None) -> None:
    rng = random.Random(3)
    for _ in range(100):
        deadline = time.monotonic() + rng.uniform(-1e-3, 1.5e-3)
        t = lib.wait_until(deadline, spin_s)
        after = time.monotonic()  # Python's own clock: the same CLOCK_MONOTONIC
        assert t >= deadline - 2e-9  # ns rounding of the float seconds
        assert after >= deadline
        assert after >= t - 2e-9


def test_clock_is_time_monotonic(lib: NativeDeadline) -> None:
    for _ in range(20):
        a = time.monotonic()
        b = lib.now()
        c = time.monotonic()
        assert a - 2e-9 <= b <= c + 2e-9


@pytest.mark.parametrize("spin_s", [200e-6, None])
def test_wait_send_puts_the_exact_datagram_on_the_wire(
        lib: NativeDeadline, receiver: socket.socket, spin_s: float | None) -> None:
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        tx.bind(("127.0.0.1", 0))
        addr = sockaddr_bytes(socket.AF_INET, receiver.getsockname())
        payloads = [os.urandom(n) for n in (1, 17, 280)]
        for data in payloads:
            deadline = time.monotonic() + 1e-3
            t, err = lib.wait_send(deadline, spin_s, tx.fileno(), data, addr)
            assert err == 0 and t >= deadline - 2e-9
            got, src = receiver.recvfrom(2048)
            assert got == data and src == tx.getsockname()
    finally:
        tx.close()


def test_wait_send_reports_errno_on_a_bad_socket(lib: NativeDeadline) -> None:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    fd = s.fileno()
    addr = sockaddr_bytes(socket.AF_INET, ("127.0.0.1", 9))
    s.close()
    _, err = lib.wait_send(time.monotonic(), 0.0, fd, b"x", addr)
    assert err == errno.EBADF


def test_sockaddr_ipv6_round_trip(lib: NativeDeadline) -> None:
    try:
        rx = socket.socket(socket.AF_INET6, socket.SOCK_DGRAM)
        rx.bind(("::1", 0))
    except OSError:
        pytest.skip("no IPv6 loopback on this machine")
    tx = socket.socket(socket.AF_INET6, socket.SOCK_DGRAM)
    try:
        rx.settimeout(2.0)
        _, err = lib.wait_send(time.monotonic(), 0.0, tx.fileno(), b"six",
                               sockaddr_bytes(socket.AF_INET6, rx.getsockname()))
        assert err == 0 and rx.recvfrom(64)[0] == b"six"
    finally:
        tx.close()
        rx.close()


def test_sockaddr_rejects_names_and_unknown_families() -> None:
    with pytest.raises(OSError):
        sockaddr_bytes(socket.AF_INET, ("localhost", 1))
    with pytest.raises(ValueError):
        sockaddr_bytes(socket.AF_UNIX, ("/tmp/x", 0))


@pytest.mark.parametrize("wait", ["sleep", "busy"])
def test_native_streamer_sends_produced_frames_on_the_grid(
        lib: NativeDeadline, receiver: socket.socket, wait: str) -> None:
    rate = 200.0
    period = 1.0 / rate
    tx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    addr = sockaddr_bytes(socket.AF_INET, receiver.getsockname())
    asked: list[float] = []

    def producer(t: float) -> bytes:
        asked.append(t)
        return b"%d" % len(asked)

    def python_send(_frame: bytes) -> bool:  # must not be used: the target is a UDP socket
        raise AssertionError("sent from Python although a datagram target was given")

    st = FixedRateStreamer(rate, python_send, producer, target=lambda: (tx.fileno(), addr),
                           wait=wait, native=True)  # type: ignore[arg-type]
    got: list[bytes] = []
    try:
        assert st.native and st.wait == wait
        st.start()
        t_start = time.monotonic()
        for _ in range(200):  # bounded: ~1 s at 200 Hz
            if len(got) >= 60:
                break
            try:
                got.append(receiver.recv(64))
            except TimeoutError:
                break
    finally:
        st.stop()
        tx.close()
    elapsed = time.monotonic() - t_start
    assert len(got) >= 60 and st.send_errors == 0 and st.producer_errors == 0
    # every datagram is a produced frame, in production order, none duplicated
    numbers = [int(b) for b in got]
    assert numbers == sorted(set(numbers)) and numbers[-1] <= len(asked)
    # the producer is asked for times on the absolute grid t0 + k / rate
    ks = [(t - asked[0]) / period for t in asked]
    assert all(abs(k - round(k)) < 1e-6 for k in ks)
    assert all(b > a for a, b in itertools.pairwise(ks))
    # each send happens at or after its deadline; never more sends than deadlines elapsed
    sent_deadlines = [asked[n - 1] for n in numbers]
    for t_send, deadline in zip(list(st.sent_times), sent_deadlines, strict=False):
        assert t_send >= deadline - 2e-9
    assert st.sent + st.missed <= elapsed * rate + 2


def test_without_target_the_native_wait_still_sends_through_python(lib: NativeDeadline) -> None:
    got: list[bytes] = []
    st = FixedRateStreamer(250.0, lambda b: got.append(b) is None, lambda t: b"p", native=True)
    try:
        st.start()
        end = time.monotonic() + 5.0
        while len(got) < 20 and time.monotonic() < end:
            time.sleep(0.005)
    finally:
        st.stop()
    assert len(got) >= 20 and set(got) == {b"p"}


def test_busy_wait_without_the_helper_falls_back_to_sleep() -> None:
    st = FixedRateStreamer(100.0, lambda b: True, native=False, wait="busy")
    assert not st.native and st.wait == "sleep" and "busy wait" in st.last_error
    with pytest.raises(ValueError):
        FixedRateStreamer(100.0, lambda b: True, wait="spin")  # type: ignore[arg-type]
