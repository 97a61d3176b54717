"""A core install (`pip install ecca-offboard`, no extras) flies, serves and replays.

The CLI runs in a subprocess whose optional packages are made unimportable: a `sitecustomize`
on PYTHONPATH puts None in `sys.modules` for each (children inherit it), so `import distributed`
fails there as in a venv without the extras. In it `fly`, `serve` and `status` answer `--help`,
a replay without a plot writes its tlog and report.json (and loads no CasADi: the numeric
flight path does not need it), and commands that need an extra exit 2 naming it.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

from companion.app.extras import EXTRAS, MissingExtraError, require

ROOT = Path(__file__).resolve().parents[2]
MISSION = ROOT / "examples" / "missions" / "one_minute.plan"
#: Importable only with an extra (or the test tools): none of them in a core install.
OPTIONAL = ("matplotlib", "distributed", "dask", "pyarrow", "pandas", "mavsdk")
#: What the vehicle needs: the core install's requirements, by distribution name.
CORE = {"pymavlink", "casadi", "numpy", "scipy", "rich", "pyserial"}
EXIT_BAD_INPUT = 2
TIMEOUT_S = 120.0  # only stops a hung process

# runs the CLI in-process, then reports whether CasADi got loaded
_CLI = ("import sys\n"
        "from companion.app.cli import main\n"
        "rc = main(sys.argv[1:])\n"
        "print('casadi loaded:', 'casadi' in sys.modules)\n"
        "sys.exit(rc)\n")


@pytest.fixture(scope="module")
def core_env(tmp_path_factory: pytest.TempPathFactory) -> dict[str, str]:
    """The environment of a subprocess in which OPTIONAL cannot be imported."""
    shim = tmp_path_factory.mktemp("core_install")
    (shim / "sitecustomize.py").write_text(
        "import sys\n"
        f"for _name in {OPTIONAL!r}:\n"
        "    sys.modules[_name] = None  # import raises ModuleNotFoundError\n",
        encoding="utf-8",
    )
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(
        p for p in (str(shim), str(ROOT), env.get("PYTHONPATH", "")) if p)
    return env


def _run(env: dict[str, str], *args: str, cwd: Path = ROOT) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, *args], capture_output=True, text=True, env=env,
                          cwd=cwd, timeout=TIMEOUT_S, check=False)


def _companion(env: dict[str, str], *args: str,
               cwd: Path = ROOT) -> subprocess.CompletedProcess[str]:
    return _run(env, "-c", _CLI, *args, cwd=cwd)


def _one_line(text: str) -> str:
    return " ".join(text.split())


@pytest.mark.parametrize("name", OPTIONAL)
def test_optional_packages_cannot_be_imported(core_env: dict[str, str], name: str) -> None:
    proc = _run(core_env, "-c", f"import {name}")
    assert proc.returncode != 0
    assert "ModuleNotFoundError" in proc.stderr


@pytest.mark.parametrize("command", ["fly", "serve", "status", "replay", "campaign"])
def test_help_works_without_extras(core_env: dict[str, str], command: str) -> None:
    proc = _companion(core_env, command, "--help")
    assert proc.returncode == 0, proc.stderr
    assert "usage:" in proc.stdout


def test_replay_no_plot_writes_log_and_report_without_casadi(
    core_env: dict[str, str], tmp_path: Path
) -> None:
    proc = _companion(core_env, "replay", "--no-plot", str(MISSION), "--out", str(tmp_path))
    assert proc.returncode == 0, proc.stdout + proc.stderr
    out = tmp_path / MISSION.stem
    assert (out / "flight.tlog").stat().st_size > 0
    assert (out / "report.json").stat().st_size > 0
    assert not (out / "flight.png").exists()
    assert "[plot]" not in proc.stderr  # asked for no plot: nothing to say
    assert "casadi loaded: False" in proc.stdout, "the numeric flight path imported CasADi"


def test_replay_without_matplotlib_flies_and_says_once_that_the_plot_needs_the_extra(
    core_env: dict[str, str], tmp_path: Path
) -> None:
    proc = _companion(core_env, "replay", str(MISSION), "--out", str(tmp_path))
    assert proc.returncode == 0, proc.stdout + proc.stderr
    out = tmp_path / MISSION.stem
    assert (out / "flight.tlog").exists() and (out / "report.json").exists()
    assert not (out / "flight.png").exists()
    err = _one_line(proc.stderr)
    assert err.count("pip install 'ecca-offboard[plot]'") == 1, err
    assert "Traceback" not in err


@pytest.mark.parametrize(("command", "extra"), [
    (("campaign", str(MISSION), "--runs", "1"), "campaign"),
    (("demo",), "plot"),
])
def test_command_needing_a_missing_extra_exits_2_naming_it(
    core_env: dict[str, str], tmp_path: Path, command: tuple[str, ...], extra: str
) -> None:
    proc = _companion(core_env, *command, "--out", str(tmp_path / "out"))
    err = _one_line(proc.stderr)
    assert proc.returncode == EXIT_BAD_INPUT, err
    assert f"[{extra}] extra" in err
    assert f"pip install 'ecca-offboard[{extra}]'" in err
    assert "Traceback" not in err
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())


def test_require_names_the_extra_and_the_missing_module(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(sys.modules, "pyarrow", None)
    with pytest.raises(MissingExtraError) as info:
        require("campaign", "campaign")
    assert info.value.extra == "campaign" and info.value.module == "pyarrow"
    assert "pip install 'ecca-offboard[campaign]'" in str(info.value)


def _name(requirement: str) -> str:
    """The distribution name of a requirement string ("mkdocstrings[python]>=1" -> ...)."""
    for i, ch in enumerate(requirement):
        if ch in "[<>=!~ ;":
            return requirement[:i].lower()
    return requirement.lower()


def test_pyproject_core_is_the_vehicle_and_extras_bring_their_modules() -> None:
    project = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))["project"]
    assert {_name(r) for r in project["dependencies"]} == CORE
    extras = project["optional-dependencies"]
    for extra, modules in EXTRAS.items():  # top-level module name == distribution name here
        assert set(modules) <= {_name(r) for r in extras[extra]}, extra
    test_deps = {_name(r) for r in extras["test"]}
    assert "mavsdk" in test_deps and "ecca-offboard" in test_deps
    assert next(r for r in extras["test"] if _name(r) == "ecca-offboard").startswith(
        "ecca-offboard[plot,campaign,docs]")
