"""The README's test command installs the toolchain as root without sudo and as a user with sudo.

The install prefix of the command (everything before the virtual environment is created) runs
under bash with a PATH of stubs: `id` reports the user, `apt-get` and `sudo` record their calls,
no compiler is found. The command is read exactly as `.ci/run` reads it.
"""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]


def _readme_command() -> str:
    """The lines between the test-command markers, without the fences (as `.ci/run` does)."""
    lines = (ROOT / "README.md").read_text(encoding="utf-8").splitlines()
    start = lines.index("<!-- test-command -->")
    end = lines.index("<!-- /test-command -->")
    body = [ln for ln in lines[start + 1 : end] if not ln.startswith("```")]
    assert len(body) == 1, "the test command must be one line"
    return body[0]


def _install_prefix() -> str:
    cmd = _readme_command()
    cut = cmd.index("python3 -m venv")
    return cmd[:cut].rstrip().rstrip(";").rstrip("&").strip()


def _stub(dir_: Path, name: str, body: str) -> None:
    p = dir_ / name
    p.write_text("#!/bin/sh\n" + body + "\n", encoding="utf-8")
    p.chmod(0o755)


def _run_prefix(tmp_path: Path, uid: int, with_sudo: bool) -> tuple[int, str]:
    bin_ = tmp_path / "bin"
    bin_.mkdir()
    log = tmp_path / "calls.log"
    for tool in ("sh", "bash", "cat"):
        real = shutil.which(tool)
        assert real is not None
        (bin_ / tool).symlink_to(real)
    _stub(bin_, "id", f'[ "$1" = -u ] && echo {uid}')
    _stub(bin_, "apt-get", f'echo "apt-get $* uid=$STUB_UID" >> {log}')
    if with_sudo:
        _stub(bin_, "sudo", f'echo "sudo" >> {log}; STUB_UID=0 exec "$@"')
    env = {"PATH": str(bin_), "STUB_UID": str(uid)}
    proc = subprocess.run(
        [str(bin_ / "bash"), "-c", "set -eo pipefail; " + _install_prefix()],
        env=env,
        capture_output=True,
        text=True,
        timeout=30,
    )
    return proc.returncode, log.read_text(encoding="utf-8") if log.exists() else ""


def test_command_is_read_verbatim_by_ci() -> None:
    ci = (ROOT / ".ci" / "run").read_text(encoding="utf-8")
    assert "<!-- test-command -->" in ci and 'bash -c "set -eo pipefail; $cmd"' in ci
    assert "pytest" in _readme_command()


def test_as_root_without_sudo_installs_with_apt_get(tmp_path: Path) -> None:
    rc, calls = _run_prefix(tmp_path, uid=0, with_sudo=False)
    assert rc == 0
    assert "sudo" not in calls
    install = [ln for ln in calls.splitlines() if " install " in ln]
    assert len(install) == 1 and "gcc-arm-none-eabi" in install[0]
    assert install[0].endswith("uid=0")


def test_as_user_installs_through_sudo(tmp_path: Path) -> None:
    rc, calls = _run_prefix(tmp_path, uid=1000, with_sudo=True)
    assert rc == 0
    lines = calls.splitlines()
    assert lines[0] == "sudo"
    install = [ln for ln in lines if " install " in ln]
    assert len(install) == 1 and "gcc-arm-none-eabi" in install[0] and "uid=0" in install[0]
