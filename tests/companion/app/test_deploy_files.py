"""The shipped deployment files stay valid: the example vehicle file loads, and the systemd
unit's and the mavlink-router example's command lines are ones `serve` accepts."""

from __future__ import annotations

import configparser
import shlex
from pathlib import Path

from companion.aio.transports import parse_url
from companion.app.cli import build_parser
from companion.planning.config import load_vehicle_file

DEPLOY = Path(__file__).resolve().parents[3] / "deploy"


def test_example_vehicle_file_loads_with_its_values() -> None:
    vf = load_vehicle_file(DEPLOY / "vehicle.example.toml")
    assert vf.params.mass == 1.6 and vf.params.hover_thrust == 0.42
    assert abs(vf.limits.max_tilt_rad - 0.5236) < 1e-3


def test_systemd_unit_runs_serve_with_options_the_cli_accepts() -> None:
    unit = configparser.ConfigParser(strict=False, interpolation=None)
    unit.read_string((DEPLOY / "ecca-serve.service").read_text().replace("\\\n", " "))
    argv = shlex.split(unit["Service"]["ExecStart"])
    assert argv[1:3] == ["-m", "companion"]
    args = build_parser().parse_args(argv[3:])
    assert args.command == "serve"
    assert parse_url(args.connect).kind == "serial"
    assert unit["Service"]["KillSignal"] == "SIGTERM"


def test_mavlink_router_example_feeds_the_documented_udp_port() -> None:
    conf = configparser.ConfigParser()
    conf.read_string((DEPLOY / "mavlink-router.conf").read_text())
    ep = conf["UdpEndpoint ecca"]
    url = f"udpin://{ep['Address']}:{ep['Port']}"
    assert parse_url(url).port == 14540
    assert conf["UartEndpoint pixhawk"]["Baud"] == "921600"
