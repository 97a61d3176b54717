"""Start and stop a real PX4 SITL (SIH) for tests and benchmarks.

`Px4Sitl()` starts one fresh PX4 v1.16 SITL on the machine's loopback as PX4 instance N (1-9,
the first free one): PX4 binds UDP 14580+N and sends its onboard/API link to 127.0.0.1:14540+N,
its GCS link to 127.0.0.1:14550; its MAVLink system id is N+1 (PX4's multi-instance rule).

    with Px4Sitl() as px4:                      # blocks until PX4 reports "Ready for takeoff"
        Vehicle.connect(px4.url, link_config=LinkConfig(target_sysid=px4.target_system))

Where PX4 comes from: `$ECCA_PX4_SITL` (a folder with bin/px4 and etc/, e.g. a PX4 build's
`build/px4_sitl_default`), else `shared/px4_sitl` beside the repository (`../shared/px4_sitl`)
or beside any folder above it; PX4 built from main (the SIH Ackermann rover,
`find_px4_sitl("main")`): `$ECCA_PX4_MAIN_SITL`, else `shared/px4_main_sitl`. `find_px4_sitl()`
says why none was found. A copy whose `bin/px4-*` command links were flattened into plain files
(as in an archive without symlinks) is repaired in the run folder: PX4's start script runs
`px4-param` etc. from the folder of the `px4` binary it was started as.

As root, PX4 gets a private /tmp (its lock and socket files) through `unshare -m`, as the
`with-px4` wrapper does; otherwise the instance's files in /tmp are used. Each instance is
reserved with a lock file, so parallel test sessions cannot pick the same one. Everything PX4
writes (console, parameters, ULog) stays in a temporary folder that is removed at `stop()`; the
console is copied to `log` (if given) first, and PX4's ULog files (`.ulg`: its estimator,
setpoints and the simulator's ground truth) to `$ECCA_PX4_ULOG_DIR` when that is set.
"""

from __future__ import annotations

import contextlib
import ctypes
import fcntl
import os
import shutil
import signal
import socket
import subprocess
import tempfile
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import IO

REPO = Path(__file__).resolve().parents[1]
#: The lock real-PX4 measurement flights hold (`flight_lock`), so two benches on one machine
#: never fly at the same time (PX4 SITL runs in real time).
FLIGHT_LOCK = "/tmp/ecca-px4-flights.lock"
READY_MARK = "Ready for takeoff"
STARTED_MARK = "Startup script returned successfully"
_FAIL_MARKS = ("Startup script returned with return value", "PX4 server already running",
               "ERROR [px4] Startup script", "Permission denied")


class Px4SitlError(RuntimeError):
    """PX4 SITL could not be found or did not start."""


@dataclass(frozen=True)
class Px4Location:
    """A PX4 SITL installation: `bin/px4` and `etc/`."""

    root: Path

    @property
    def binary(self) -> Path:
        return self.root / "bin" / "px4"

    @property
    def etc(self) -> Path:
        return self.root / "etc"


#: The PX4 SITL builds: name -> (environment variable, folder beside the repository's parents).
#: "v1.16": PX4 v1.16.0 (SIH quadrotor, the quad's yardstick); "main": PX4 built from main
#: (SIH Ackermann rover `sihsim_rover_ackermann` and quadrotor; its uORB layouts are not v1.16's).
BUILDS = {"v1.16": ("ECCA_PX4_SITL", "px4_sitl"), "main": ("ECCA_PX4_MAIN_SITL", "px4_main_sitl")}
#: The SIH model each build's tests fly by default.
DEFAULT_MODEL = {"v1.16": "sihsim_quadx", "main": "sihsim_rover_ackermann"}


def find_px4_sitl(build: str = "v1.16") -> tuple[Px4Location | None, str]:
    """The PX4 SITL of `build` (see BUILDS) to use and, when there is none, why (for pytest's
    skip reason)."""
    var, folder = BUILDS[build]
    env = os.environ.get(var)
    # ../shared/<folder> next to the repository, or next to any folder above it (a CI clone)
    candidates = [Path(env)] if env else [d / "shared" / folder for d in REPO.parents]
    whys = []
    for root in candidates:
        loc = Px4Location(root.resolve())
        if not loc.binary.is_file():
            whys.append(f"no PX4 SITL binary at {loc.binary}")
        elif not (loc.etc / "init.d-posix" / "rcS").is_file():
            whys.append(f"no PX4 start script at {loc.etc / 'init.d-posix' / 'rcS'}")
        elif not os.access(loc.binary, os.X_OK):
            whys.append(f"{loc.binary} is not executable")
        else:
            return loc, ""
    src = var if env else f"set {var} to a PX4 build's px4_sitl_default"
    return None, f"{whys[0]} ({src})"


@contextlib.contextmanager
def flight_lock(path: str = FLIGHT_LOCK) -> Iterator[float]:
    """Hold the shared real-PX4 flight lock (flock(2), as `flock FILE cmd`); yields the wait
    [s]."""
    t0 = time.monotonic()
    with open(path, "a") as f:
        fcntl.flock(f, fcntl.LOCK_EX)
        try:
            yield time.monotonic() - t0
        finally:
            fcntl.flock(f, fcntl.LOCK_UN)


def _udp_port_free(port: int) -> bool:
    for host in ("127.0.0.1", "0.0.0.0"):
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            try:
                s.bind((host, port))
            except OSError:
                return False
    return True


def _die_with_parent() -> None:
    """In the child before exec: SIGKILL it when the process that started it dies (a killed
    test or bench must not leave PX4 running; the setting survives unshare's and sh's exec)."""
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG


def _can_unshare() -> bool:
    return os.geteuid() == 0 and shutil.which("unshare") is not None


class Px4Sitl:
    """One running PX4 SITL instance (context manager; see the module doc).

    model: SIH airframe (`sihsim_quadx`, `sihsim_airplane`, ...). speed_factor: PX4's
    PX4_SIM_SPEED_FACTOR (>1 runs the simulation faster than real time; the companion keeps wall
    time, so use it only where timing and tracking are not judged). params: PX4 parameters set
    at boot (PX4_PARAM_<NAME> in PX4's environment; MAV_SYS_ID stays instance + 1).
    startup_timeout_s: how long to wait for `ready_mark` in PX4's console ("Ready for takeoff",
    which the rover of PX4 main prints only once armable; STARTED_MARK there, and the caller
    retries arming). log: where to copy PX4's console at stop.
    """

    def __init__(self, *, model: str = "sihsim_quadx", speed_factor: float = 1.0,
                 params: dict[str, float] | None = None, startup_timeout_s: float = 40.0,
                 log: str | Path | None = None, location: Px4Location | None = None,
                 ready_mark: str = READY_MARK) -> None:
        if location is None:
            location, why = find_px4_sitl()
            if location is None:
                raise Px4SitlError(why)
        self.location = location
        self.model = model
        self.speed_factor = speed_factor
        self.params = dict(params or {})
        self.startup_timeout_s = startup_timeout_s
        self.log = Path(log) if log is not None else None
        self.ready_mark = ready_mark
        self.instance = 0
        self._lock: IO[str] | None = None
        self._run: Path | None = None
        self._proc: subprocess.Popen[bytes] | None = None
        self._console: IO[bytes] | None = None
        self._bin: Path | None = None

    # -- addresses ------------------------------------------------------------------------
    @property
    def port(self) -> int:
        """Local UDP port PX4's onboard/API link sends to (the companion listens here)."""
        return 14540 + self.instance

    @property
    def url(self) -> str:
        """The companion's connect URL for this PX4."""
        return f"udpin://127.0.0.1:{self.port}"

    @property
    def target_system(self) -> int:
        """PX4's MAVLink system id (MAV_SYS_ID = instance + 1 in PX4 SITL)."""
        return self.instance + 1

    @property
    def px4_port(self) -> int:
        """UDP port PX4 binds for the onboard/API link."""
        return 14580 + self.instance

    gcs_port = 14550  # PX4's GCS link sends here (every instance)

    @property
    def console_path(self) -> Path:
        assert self._run is not None
        return self._run / "console.log"

    def console_text(self) -> str:
        """PX4's console output so far."""
        try:
            return self.console_path.read_text(errors="replace")
        except (OSError, AssertionError):
            return ""

    # -- lifecycle --------------------------------------------------------------------------
    def _reserve_instance(self) -> None:
        for n in range(1, 10):
            lock = open(Path(tempfile.gettempdir()) / f"ecca-px4-instance-{n}.lock", "w")  # noqa: SIM115
            try:
                fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:
                lock.close()
                continue
            ports = (14540 + n, 14580 + n, 18570 + n, 14280 + n, 13030 + n, 19450 + n)
            if all(_udp_port_free(p) for p in ports):
                self.instance, self._lock = n, lock
                return
            lock.close()
        raise Px4SitlError("no free PX4 instance 1-9 (UDP ports 14541-14549 in use?)")

    def _bin_dir(self) -> Path:
        """A folder with `px4` and working `px4-*` command links."""
        src = self.location.binary.parent
        probe = src / "px4-param"
        if probe.is_symlink() or (probe.is_file() and os.access(probe, os.X_OK)
                                  and probe.stat().st_size > 64):
            return src
        assert self._run is not None
        out = self._run / "bin"
        out.mkdir()
        os.symlink(self.location.binary, out / "px4")
        for f in src.iterdir():
            if f.name == "px4":
                continue
            if f.name.startswith("px4-") and not f.name.endswith(".sh"):
                os.symlink("px4", out / f.name)
            else:
                os.symlink(f, out / f.name)
        return out

    def start(self) -> Px4Sitl:
        """Start PX4 and wait until it is ready for takeoff (raises Px4SitlError)."""
        self._reserve_instance()
        self._run = Path(tempfile.mkdtemp(prefix="ecca-px4-", dir="/var/tmp"))
        rootfs = self._run / "rootfs"
        rootfs.mkdir()
        self._bin = self._bin_dir()
        binary = self._bin / "px4"
        env = dict(os.environ, PX4_SIM_MODEL=self.model, PX4_SIMULATOR="sihsim", HEADLESS="1")
        # PX4's rcS sets PX4_PARAM_<NAME> before the airframe's defaults (which it overrides)
        env.update({f"PX4_PARAM_{k}": f"{v:g}" for k, v in self.params.items()})
        if self.speed_factor != 1.0:
            env["PX4_SIM_SPEED_FACTOR"] = f"{self.speed_factor:g}"
        argv = [str(binary), "-i", str(self.instance), "-d", "-w", str(rootfs),
                str(self.location.etc)]
        if _can_unshare():
            argv = ["unshare", "-m", "--propagation", "private", "sh", "-c",
                    'mount -t tmpfs tmpfs /tmp && exec "$@"', "sh", *argv]
        self._console = open(self.console_path, "wb")  # noqa: SIM115
        self._proc = subprocess.Popen(argv, cwd=rootfs, env=env, stdin=subprocess.DEVNULL,
                                      stdout=self._console, stderr=subprocess.STDOUT,
                                      start_new_session=True, preexec_fn=_die_with_parent)
        deadline = time.monotonic() + self.startup_timeout_s
        try:
            while True:
                text = self.console_text()
                if self.ready_mark in text:
                    break
                bad = next((m for m in _FAIL_MARKS if m in text), None)
                if bad is not None or self._proc.poll() is not None:
                    raise Px4SitlError(f"PX4 did not start ({bad or 'process exited'}); "
                                       f"console:\n{_tail(text)}")
                if time.monotonic() > deadline:
                    raise Px4SitlError(f"PX4 not ready after {self.startup_timeout_s:g} s; "
                                       f"console:\n{_tail(text)}")
                time.sleep(0.1)  # polling PX4's console file (bounded by the deadline)
        except BaseException:
            self.stop()
            raise
        return self

    def command(self, name: str, *args: str,
                timeout_s: float = 30.0) -> subprocess.CompletedProcess[str]:
        """Run PX4 shell command `name` with `args` in this PX4 (what `pxh> name args` does:
        `px4-<name> --instance N args`; inside PX4's mount namespace when PX4 has its own /tmp,
        as `px4-cmd` does). Returns the finished process (its output: stdout; PX4's exit
        status: returncode)."""
        if self._proc is None or self._bin is None or self._proc.poll() is not None:
            raise Px4SitlError("PX4 is not running")
        argv = [str(self._bin / f"px4-{name}"), "--instance", str(self.instance), *args]
        if _can_unshare():
            argv = ["nsenter", "-t", str(self._proc.pid), "-m", *argv]
        return subprocess.run(argv, capture_output=True, text=True, timeout=timeout_s,
                              check=False, stdin=subprocess.DEVNULL)

    def stop(self) -> None:
        """Stop PX4 (SIGTERM, then SIGKILL after 5 s), keep its console in `log`, clean up."""
        proc, self._proc = self._proc, None
        if proc is not None and proc.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, signal.SIGTERM)
            try:
                proc.wait(timeout=5.0)
            except subprocess.TimeoutExpired:
                with contextlib.suppress(ProcessLookupError):
                    os.killpg(proc.pid, signal.SIGKILL)
                proc.wait(timeout=5.0)
        if self._console is not None:
            self._console.close()
            self._console = None
        if self._run is not None:
            if self.log is not None:
                with contextlib.suppress(OSError):
                    shutil.copyfile(self.console_path, self.log)
            keep = os.environ.get("ECCA_PX4_ULOG_DIR")
            if keep:  # PX4's own flight logs (.ulg), for a look at its internals afterwards
                with contextlib.suppress(OSError):
                    Path(keep).mkdir(parents=True, exist_ok=True)
                    for f in sorted((self._run / "rootfs" / "log").rglob("*.ulg")):
                        shutil.copyfile(f, Path(keep) / f"{self._run.name}-{f.name}")
            shutil.rmtree(self._run, ignore_errors=True)
            self._run = None
        if self._lock is not None:
            self._lock.close()
            self._lock = None

    def __enter__(self) -> Px4Sitl:
        return self.start()

    def __exit__(self, et: type[BaseException] | None, ev: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.stop()


def _tail(text: str, lines: int = 30) -> str:
    return "\n".join(text.splitlines()[-lines:])
