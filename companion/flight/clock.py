"""The local clocks of a flight: `SampleClock` maps the vehicle's sample times (time_boot) to
the local clock, `FlightClock` makes flight time follow the autopilot's clock. Pure: every call
takes the times."""

from __future__ import annotations

import itertools
import math
import statistics
from bisect import bisect_left, insort
from collections import deque

#: SampleClock: completed blocks (of `block_s`) before its offset is slewed rather than taken.
SETTLED_BLOCKS = 8
#: SampleClock: the largest rate [s/s] its offset moves at once settled. The fitted line moves
#: in steps: a lockstep autopilot clock that stalled 46 ms (real PX4 SITL in CI, 2026-11-29)
#: raised the line that much at once when the stall's block became the newest minimum, and the
#: controller's extrapolation at 5 m/s jumped 0.23 m: a thrust step of 0.095 between setpoints
#: 10 ms apart. Slewed at 0.1 s/s that takes 0.46 s. The fitted drift itself is followed at
#: once: PX4 SITL on a slow host runs at 0.7-0.93x real time (0.08-0.43 s/s of drift), and an
#: offset held to the slew fell behind by seconds, so that every sample looked stale and the
#: controller sat in its hover fallback for the rest of the flight (real PX4, 2026-12-01).
OFFSET_SLEW = 0.1
#: SampleClock: a change of the autopilot clock's rate. Each completed block's minimum departs
#: from the fitted drift's prediction (from the block before it) by d [s]. Departures beyond
#: CHANGE_NOISE_S the same way in CHANGE_RUN blocks in a row, or beyond CHANGE_STEP_S in two,
#: mean the rate changed where the run began. PX4 SITL slowed from 0.98x to 0.65x real time
#: mid-flight when its host got busy (real PX4, 2026-12-01): the drift fitted over 20 s lagged,
#: the mapped sample age rose from 0.01 to 0.53 s in 5 s and the law flew 3.1 s in its hover
#: fallback; a 5 % slow-down left samples 0.1 s older than they were for 14 s. A stall (one
#: step of the line) or a block of delayed samples (a step up and back) departs once each way.
CHANGE_NOISE_S = 0.005
CHANGE_STEP_S = 0.015
CHANGE_RUN = 3
#: SampleClock: the rate [s/s] its offset moves at toward the line refitted after a change of
#: rate (instead of OFFSET_SLEW) until it is on it: at 0.98x -> 0.65x the offset is 0.38 s
#: behind when the change is found. Taking the new line at once moved it by 0.17-0.25 s
#: between two samples on real PX4 SITL, and the law's extrapolation with it: a thrust step of
#: 0.149 between setpoints in CI on a loaded host (2026-12-02).
CHANGE_SLEW = 0.5


class SampleClock:
    """Maps the vehicle's sample times (time_boot) to the local clock.

    Every sample gives `t_receive - t_boot = offset + latency`. The offset is not constant: the
    autopilot's clock drifts against ours (PX4 SITL's lockstep clock runs ~0.7-1.1 % slow on
    SIH, and more while the host is busy). So the offset is modelled as a line `a + b t_boot`:
    the smallest offset of each `block_s` of boot time (the sample that met the least latency),
    a robust slope through those of the last `blocks` completed blocks (Theil-Sen over pairs at
    least two blocks apart, refitted when a block completes; before three blocks, b = 0), and
    the intercept lowered until the line touches the minima of the newest `recent` blocks from
    below. Then `t_boot + a + b t_boot` is the local time the sample was taken (up to the
    link's minimum latency), which exposes the link latency to the controller's extrapolation
    where receive times would hide it. Short blocks and a recent intercept let a fresh clock
    settle within about a second and follow a lockstep clock that falls behind in bursts (a
    line touching 20 s of one-second minima was up to 40-47 ms off on PX4 SITL in the first
    seconds of a flight, these settings 8-9 ms). When the clock changes its rate (two blocks
    in a row whose minima depart from the fitted drift by more than CHANGE_STEP_S the same
    way), the fit starts again from the block where the change began, and the offset moves
    toward the new line at CHANGE_SLEW until it is on it. A boot time that jumps back by more than
    0.5 s (autopilot reboot) starts over.
    """

    def __init__(self, block_s: float = 0.25, blocks: int = 80, recent: int = 8) -> None:
        if not (block_s > 0.0 and math.isfinite(block_s)):
            raise ValueError(f"block_s must be a positive number of seconds, got {block_s}")
        if blocks < 1:
            raise ValueError(f"blocks must be >= 1, got {blocks}")
        if not 1 <= recent <= blocks:
            raise ValueError(f"recent must be between 1 and blocks ({blocks}), got {recent}")
        self.block_s = block_s
        self._size = blocks
        self._recent = recent
        # per block: [block index, boot time, offset] of its smallest offset
        self._blocks: deque[list[float]] = deque()
        # the Theil-Sen slopes kept up to date as blocks complete and leave the window: per
        # block (aligned with _blocks) the slopes it makes with the later completed blocks,
        # and all of them sorted (the median is then a lookup; see _fit_slope)
        self._pair_slopes: deque[list[float]] = deque()
        self._sorted: list[float] = []
        self._nan_slopes = 0  # NaN slopes in the window: sort order undefined, recompute
        self._a = 0.0  # intercept [s]
        self._b = 0.0  # drift [s/s]
        self._last_key: tuple[float, float] | None = None
        self._last_boot = -math.inf
        self._out: float | None = None  # the offset given [s] (slewed toward a + b t_boot)
        self._out_t: float | None = None  # receive time [s] it was last moved at
        self._out_boot = 0.0  # the boot time [s] it was last moved for
        self._seen = 0  # blocks begun since the start (SETTLED_BLOCKS)
        self._catch_up = False  # moving toward a line refitted after a change of rate

    @property
    def drift(self) -> float:
        """Estimated drift of the vehicle clock: d(offset)/d(t_boot) (0.0073 for 0.73 % slow)."""
        return self._b

    def local_time(self, t_boot_s: float, t_receive_s: float) -> float:
        """Local time [s] at which the sample stamped `t_boot_s` [s] was taken. Once the
        clock has settled (SETTLED_BLOCKS completed blocks), the offset it gives follows the
        fitted line's slope (the drift) and moves at most OFFSET_SLEW s per second of receive
        time toward the line besides."""
        key = (t_boot_s, t_receive_s)
        if key != self._last_key:
            self._last_key = key
            self._add(t_boot_s, t_receive_s - t_boot_s)
            target = self._a + self._b * t_boot_s
            out, t_last = self._out, self._out_t
            if out is None or t_last is None or self._seen <= SETTLED_BLOCKS:
                self._out = target
            else:
                # along the line's slope at once (a clock that runs steadily slow or fast),
                # only the rest (a step of the line) slewed, faster after a change of rate
                pred = out + self._b * (t_boot_s - self._out_boot)
                slew = CHANGE_SLEW if self._catch_up else OFFSET_SLEW
                step = slew * max(0.0, t_receive_s - t_last)
                rest = target - pred
                if abs(rest) <= step:
                    self._catch_up = False
                self._out = pred + min(step, max(-step, rest))
            self._out_t = t_receive_s
            self._out_boot = t_boot_s
        out = self._out
        assert out is not None
        # never after its arrival (the fitted slope's noise could tilt the line that far)
        return min(t_boot_s + out, t_receive_s)

    def _add(self, boot: float, off: float) -> None:
        blocks = self._blocks
        if boot < self._last_boot - 0.5:
            self._out = None
            self._seen = 0
            self._catch_up = False
            blocks.clear()
            self._pair_slopes.clear()
            self._sorted.clear()
            self._nan_slopes = 0
        self._last_boot = boot
        idx = math.floor(boot / self.block_s)
        if blocks and blocks[-1][0] == idx:
            last = blocks[-1]
            if off >= last[2]:
                return
            last[1], last[2] = boot, off
        else:
            if blocks:
                self._complete()  # the newest block so far is final now
                self._detect_rate_change()
            blocks.append([idx, boot, off])
            self._seen += 1
            self._pair_slopes.append([])
            if len(blocks) > self._size:
                blocks.popleft()
                self._forget(self._pair_slopes.popleft())
            self._fit_slope()
        b = self._b
        self._a = min(p[2] - b * p[1] for p in itertools.islice(
            blocks, max(len(blocks) - self._recent, 0), None))

    def _complete(self) -> None:
        """The newest block is final (a later one starts): its slopes with every earlier
        block (pairs at least two blocks apart in time) join the sorted slopes."""
        blocks, pairs, srt = self._blocks, self._pair_slopes, self._sorted
        q = blocks[-1]
        gap = 2.0 * self.block_s
        for k in range(len(blocks) - 1):
            p = blocks[k]
            if q[1] - p[1] >= gap:
                slope = (q[2] - p[2]) / (q[1] - p[1])
                pairs[k].append(slope)
                if slope != slope:
                    self._nan_slopes += 1
                else:
                    insort(srt, slope)

    def _detect_rate_change(self) -> None:
        """The completed blocks' minima departed from the drift in a run (CHANGE_NOISE_S,
        CHANGE_STEP_S, CHANGE_RUN): the clock's rate changed at the block before the run. The
        fit keeps only the run's blocks, and the drift is their pairwise slopes' median until
        later blocks refit it; the offset given catches up at CHANGE_SLEW."""
        blocks = self._blocks
        n = len(blocks)
        if n < 4:  # the drift is fitted from three completed blocks
            return
        b = self._b
        run, way, least = 0, 0.0, math.inf
        for k in range(n - 1, max(n - 1 - CHANGE_RUN, 0), -1):
            p, q = blocks[k - 1], blocks[k]
            d = q[2] - p[2] - b * (q[1] - p[1])
            if not abs(d) > CHANGE_NOISE_S or d * way < 0.0:
                break
            run, way, least = run + 1, d, min(least, abs(d))
            if run >= CHANGE_RUN or (run == 2 and least > CHANGE_STEP_S):
                break
        if not (run >= CHANGE_RUN or (run == 2 and least > CHANGE_STEP_S)):
            return
        keep = list(itertools.islice(blocks, n - 1 - run, None))
        blocks.clear()
        self._pair_slopes.clear()
        self._sorted.clear()
        self._nan_slopes = 0
        for blk in keep:
            blocks.append(blk)
            self._pair_slopes.append([])
            if len(blocks) > 1:
                self._complete()
        self._b = statistics.median([(q[2] - p[2]) / (q[1] - p[1])
                                     for p, q in itertools.combinations(keep, 2)])
        self._catch_up = True

    def _forget(self, slopes: list[float]) -> None:
        """The slopes of a block that left the window leave the sorted slopes."""
        srt = self._sorted
        for slope in slopes:
            if slope != slope:
                self._nan_slopes -= 1
            else:
                del srt[bisect_left(srt, slope)]

    def _fit_slope(self) -> None:
        if len(self._blocks) - 1 < 3:  # the newest may not have met its least latency yet
            return
        # Theil-Sen: the median of the pairwise slopes of the completed blocks, so a block
        # whose every sample was delayed (a link hiccup) does not tilt the line
        if self._nan_slopes:  # (not finite telemetry) the order statistics.median gives
            done = list(self._blocks)[:-1]
            gap = 2.0 * self.block_s
            slopes = [(q[2] - p[2]) / (q[1] - p[1]) for i, p in enumerate(done)
                      for q in done[i + 1:] if q[1] - p[1] >= gap]
            if slopes:
                self._b = statistics.median(slopes)
            return
        srt = self._sorted
        n = len(srt)
        if n:  # statistics.median of the same values
            i = n // 2
            self._b = srt[i] if n % 2 else (srt[i - 1] + srt[i]) / 2


class FlightClock:
    """Flight time that follows the autopilot's clock, for the reference a flight streams.

    PX4 SITL's lockstep clock runs slower than the wall clock while its host is busy (on a
    2-core host, 2-30 %, plus stalls of 0.1-0.3 s in which its simulation does not advance). A
    reference timed by the wall clock then runs ahead of a vehicle that cannot follow it in
    its own time: on real PX4 SITL a 6 m/s figure-8 in rates mode was 1.3-1.7 m off (5.6 m at
    worst) with the thrust at its bounds while PX4 ran at ~70 % speed. On a real autopilot the
    two clocks agree and this changes nothing.

    `now(local)` [s] advances with the local clock, slowed smoothly when it gets more than
    `lead_s` ahead of the newest telemetry sample's own time (its time_boot), at a rate
    ``1 - gain_per_s * excess`` (clamped to [0, 1]): a clock that runs slow by a fraction r
    settles `r / gain_per_s` beyond the lead, and a stall freezes flight time within about
    ``lead_s + 1 / gain_per_s`` of the last sample. It never runs backwards and never faster
    than the local clock. `lead_s` covers the link's latency and the sample interval, so at
    full speed it only shifts the origin. Before the first sample it is the local clock, and
    it is again while samples keep arriving with a time_boot that has not advanced for
    `frozen_s` [s] (a broken vehicle clock must not hold a flight at its start). Not
    thread-safe: one caller at a time.
    """

    def __init__(self, lead_s: float = 0.08, gain_per_s: float = 20.0,
                 frozen_s: float = 1.0) -> None:
        if not (lead_s >= 0.0 and math.isfinite(lead_s)):
            raise ValueError(f"lead_s must be >= 0, got {lead_s}")
        if not (gain_per_s > 0.0 and math.isfinite(gain_per_s)):
            raise ValueError(f"gain_per_s must be > 0, got {gain_per_s}")
        if not (frozen_s > 0.0 and math.isfinite(frozen_s)):
            raise ValueError(f"frozen_s must be > 0, got {frozen_s}")
        self.lead_s = lead_s
        self.gain_per_s = gain_per_s
        self.frozen_s = frozen_s
        self._boot: float | None = None  # newest sample's time_boot [s]
        self._boot_rx = 0.0  # receive time of the sample that last advanced time_boot [s]
        self._last_rx = 0.0  # receive time of the newest sample [s]
        self._offset = 0.0  # flight time - time_boot origin: flight time is local-clock-like
        self._t_local: float | None = None
        self._t_flight = 0.0
        self._lag = 0.0  # local - flight time [s]: flight time is kept as the local clock less
        # this, so that at full speed it is the local clock to the bit

    def observe(self, time_boot_s: float, t_receive_s: float) -> None:
        """A telemetry sample stamped `time_boot_s` [s] by the vehicle, received at local time
        `t_receive_s` [s]."""
        if not (math.isfinite(time_boot_s) and math.isfinite(t_receive_s)):
            return
        if self._boot is None or time_boot_s < self._boot - 0.5:  # first, or a reboot
            # flight time origin: the sample's time on the local clock (received then)
            self._offset = (t_receive_s if self._t_local is None else self._t_flight) - time_boot_s
            self._boot, self._boot_rx = time_boot_s, t_receive_s
        elif time_boot_s > self._boot:
            if t_receive_s - self._boot_rx > self.frozen_s:  # thawed: re-anchor, no jump
                self._offset = self._t_flight - time_boot_s
            self._boot, self._boot_rx = time_boot_s, t_receive_s
        self._last_rx = max(self._last_rx, t_receive_s)

    def now(self, local_s: float) -> float:
        """Flight time at local time `local_s` [s] (calls in time order)."""
        if self._t_local is None:
            self._t_local, self._t_flight = local_s, local_s
            return local_s
        dt = local_s - self._t_local
        if dt <= 0.0:
            return self._t_flight
        rate = 1.0
        if self._boot is not None and self._last_rx - self._boot_rx <= self.frozen_s:
            excess = self._t_flight - (self._boot + self._offset) - self.lead_s
            rate = min(max(1.0 - self.gain_per_s * excess, 0.0), 1.0)
        self._t_local = local_s
        if rate < 1.0:
            self._lag += (1.0 - rate) * dt
        self._t_flight = local_s - self._lag
        return self._t_flight

    @property
    def lag_s(self) -> float:
        """How far [s] flight time has fallen behind the local clock (0 at full speed)."""
        return self._lag
