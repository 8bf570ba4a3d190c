"""The `ares` command line: parser, `node`, and `topics` / `echo` against a real router."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import threading

import pytest

from ares import cli
from ares.core.bus import Bus
from ares.core.localhost import free_port
from ares.core.messages import CarState, DriveMode
from tests.helpers.stack import REPO

pytestmark = pytest.mark.timeout(120)


def env_without_run_config() -> dict:
    """A shell's environment: no ARES_RUN_CONFIG, so the CLI falls back to the defaults."""
    env = {k: v for k, v in os.environ.items() if k != "ARES_RUN_CONFIG"}
    env["PYTHONPATH"] = str(REPO)
    return env


def ares(*argv: str, env: dict | None = None, timeout: float = 60) -> subprocess.CompletedProcess:
    """The CLI as a user runs it: its own process, real exit code."""
    return subprocess.run(
        [sys.executable, "-m", "ares.cli", *argv],
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
        timeout=timeout,
        stdin=subprocess.DEVNULL,
    )


# ---- parser ----------------------------------------------------------------------------------


def test_run_parser_takes_every_option():
    args = cli.build_parser().parse_args(
        [
            "run",
            "--headless",
            "--laps",
            "2",
            "--speed",
            "5",
            "--route",
            "tour.yaml",
            "--vehicle",
            "techs4agecar",
            "--passengers",
            "4",
            "--vehicle-id",
            "shuttle07",
            "--router",
            "tcp/10.0.0.2:7447",
            "--run-dir",
            "/tmp/r",
        ]
    )
    assert args.command == "run"
    assert (
        args.headless,
        args.laps,
        args.speed,
        args.route,
        args.vehicle,
        args.passengers,
        args.vehicle_id,
        args.router,
        args.run_dir,
    ) == (True, 2, 5.0, "tour.yaml", "techs4agecar", 4, "shuttle07", "tcp/10.0.0.2:7447", "/tmp/r")


def test_run_parser_defaults():
    args = cli.build_parser().parse_args(["run"])
    assert args.headless is False and args.manual is False and args.speed is None  # paced in simulation
    assert args.laps is None and args.route is None and args.vehicle is None and args.passengers is None
    assert args.vehicle_id is None and args.router is None and args.run_dir is None


@pytest.mark.parametrize(
    "argv, complaint",
    [
        (["run", "--speed", "0"], "--speed"),
        (["run", "--speed", "fast"], "--speed"),
        (["run", "--laps", "-1"], "--laps"),
        (["run", "--passengers", "-2"], "--passengers"),
        (["run", "--router", "localhost"], "endpoint"),
        (["run", "--vehicle-id", "a/b"], "vehicle id"),
        (["echo"], "KEY"),
        (["topics", "--seconds", "0"], "--seconds"),
        (["bench", "bus", "--mode", "router"], "--mode"),
        (["fly"], "invalid choice"),
    ],
)
def test_bad_arguments_are_usage_errors(argv, complaint, capsys):
    assert cli.main(argv) == 2
    assert complaint in capsys.readouterr().err


def test_other_subcommands_parse():
    p = cli.build_parser()
    assert p.parse_args(["node", "sim"]).name == "sim"
    a = p.parse_args(["topics", "--seconds", "3", "--router", "tcp/127.0.0.1:7000", "--vehicle-id", "v1"])
    assert (a.seconds, a.router, a.vehicle_id) == (3.0, "tcp/127.0.0.1:7000", "v1")
    a = p.parse_args(["echo", "heartbeat/*", "--count", "5", "--seconds", "2"])
    assert (a.key, a.count, a.seconds) == ("heartbeat/*", 5, 2.0)
    a = p.parse_args(["bench", "bus", "--json", "--seconds", "1"])
    assert (a.bench, a.json, a.seconds) == ("bus", True, 1.0)


def test_no_command_prints_help(capsys):
    assert cli.main([]) == 2
    assert "COMMAND" in capsys.readouterr().err


def test_help_imports_no_heavy_package():
    # `ares --help` and `ares topics` start fast: each command imports what it needs when it runs
    probe = (
        "import sys\nfrom ares import cli\ncli.build_parser().format_help()\n"
        "print(' '.join(sorted({m.split('.')[0] for m in sys.modules})))"
    )
    result = subprocess.run(
        [sys.executable, "-c", probe],
        cwd=REPO,
        env=env_without_run_config(),
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert result.returncode == 0, result.stderr
    loaded = set(result.stdout.split())
    assert not loaded & {"zenoh", "fastapi", "numpy", "pydantic", "blackbox"}


# ---- node ------------------------------------------------------------------------------------


def test_node_unknown_name_fails_clearly(capsys):
    assert cli.main(["node", "nosuch"]) == 1
    err = capsys.readouterr().err
    assert "unknown process 'nosuch'" in err
    assert "dbw_bridge" in err  # the known names are listed


def test_node_unknown_name_exit_code_from_the_shell():
    result = ares("node", "nosuch")
    assert result.returncode == 1
    assert "unknown process" in result.stderr


# ---- topics / echo against a real router -----------------------------------------------------


def car_state(i: int) -> CarState:
    return CarState(
        t=float(i),
        mode=DriveMode.AUTOMATIC,
        engaged=True,
        watchdog_tripped=False,
        setpoint_age_s=0.1,
        v_command=2.5,
        kappa_command=0.02,
        speed_mps=2.4,
        steering_wheel_deg=12.5,
        reason=f"test {i}",
    )


@pytest.fixture
def publishing(router):
    """A process-like publisher on the router: liveliness token `testpub`, CarState at 20 Hz,
    plus a malformed message and a topic outside the schema table."""
    bus = Bus(router, "testpub")
    bus.declare_alive()
    stop = threading.Event()

    def loop() -> None:
        i = 0
        while not stop.is_set():
            bus.publish("dbw/car_state", car_state(i))
            bus.session.put(bus.key("dbw/measure"), b'{"t": 1.0, "v": "fast"}', encoding="application/json;DbwMeasure")
            bus.session.put(bus.key("lab/notes"), b"plain text")
            i += 1
            stop.wait(0.05)

    thread = threading.Thread(target=loop, daemon=True)
    thread.start()
    yield router
    stop.set()
    thread.join(timeout=5)
    bus.close()


def test_topics_lists_keys_rates_schemas_and_live_processes(publishing, child_env):
    result = ares("topics", "--seconds", "1.5", "--json", env=child_env)
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout.strip().splitlines()[-1])
    assert report["prefix"] == f"ares/{publishing['vehicle_id']}"
    by_topic = {row["topic"]: row for row in report["topics"]}
    car = by_topic["dbw/car_state"]
    assert car["schema"] == "CarState" and car["count"] > 5 and car["rate_hz"] > 0
    assert by_topic["lab/notes"]["schema"] == "?"
    assert "testpub" in report["alive"]

    table = ares("topics", "--seconds", "1", env=child_env)
    assert table.returncode == 0, table.stderr
    assert "dbw/car_state" in table.stdout and "CarState" in table.stdout
    assert "live processes" in table.stdout and "testpub" in table.stdout


def test_topics_with_explicit_router_and_vehicle_id(publishing, port):
    # no ARES_RUN_CONFIG: the endpoint and the vehicle id come from the command line
    env = env_without_run_config()
    result = ares(
        "topics",
        "--seconds",
        "1",
        "--router",
        f"tcp/127.0.0.1:{port}",
        "--vehicle-id",
        publishing["vehicle_id"],
        env=env,
    )
    assert result.returncode == 0, result.stderr
    assert "dbw/car_state" in result.stdout

    other = ares("topics", "--seconds", "0.5", "--router", f"tcp/127.0.0.1:{port}", "--vehicle-id", "nobody", env=env)
    assert other.returncode == 1
    assert "nothing seen under ares/nobody/**" in other.stderr


def test_echo_prints_decoded_messages(publishing, child_env):
    result = ares("echo", "dbw/car_state", "--count", "3", "--seconds", "20", env=child_env)
    assert result.returncode == 0, result.stderr
    lines = [json.loads(line) for line in result.stdout.splitlines()]
    assert len(lines) == 3
    for line in lines:
        assert line["key"] == f"ares/{publishing['vehicle_id']}/dbw/car_state"
        assert line["schema"] == "CarState"
        msg = line["msg"]
        assert msg["mode"] == "AUTOMATIC" and msg["steering_wheel_deg"] == 12.5
        assert msg["reason"] == f"test {int(msg['t'])}"
    assert [m["msg"]["t"] for m in lines] == sorted(m["msg"]["t"] for m in lines)


def test_echo_reports_invalid_and_raw_messages(publishing, child_env):
    bad = ares("echo", "dbw/measure", "--count", "1", "--seconds", "20", env=child_env)
    assert bad.returncode == 0, bad.stderr
    line = json.loads(bad.stdout.splitlines()[0])
    assert line["schema"] == "DbwMeasure" and line["error"].startswith("invalid")
    assert line["raw"] == {"t": 1.0, "v": "fast"}

    raw = ares("echo", "ares/*/lab/notes", "--count", "1", "--seconds", "20", env=child_env)
    assert raw.returncode == 0, raw.stderr
    assert json.loads(raw.stdout.splitlines()[0])["raw"] == "plain text"


def test_echo_bad_key_and_silence(router, child_env):
    bad = ares("echo", "dbw//car_state", "--seconds", "1", env=child_env)
    assert bad.returncode == 1
    assert "invalid key expression" in bad.stderr
    quiet = ares("echo", "dbw/car_state", "--count", "1", "--seconds", "0.5", env=child_env)
    assert quiet.returncode == 1
    assert "0 of 1 messages" in quiet.stderr


@pytest.mark.parametrize("command", [["topics", "--seconds", "1"], ["echo", "dbw/car_state", "--count", "1"]])
def test_no_router_is_a_clear_error(command):
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    result = ares(*command, "--router", endpoint, env=env_without_run_config(), timeout=30)
    assert result.returncode == 1
    assert f"no Zenoh router reachable at {endpoint}" in result.stderr
    assert "Traceback" not in result.stderr


def test_run_route_takes_a_built_in_tour_a_tour_file_or_a_route_csv(tmp_path):
    from ares.app.run_options import RunOptions

    tour = tmp_path / "mine.yaml"
    tour.write_text("name: mine\n")
    csv = tmp_path / "drive.csv"
    csv.write_text("0,0\n10,0\n")
    picked = {
        r: {k: v for k, v in RunOptions(route=r).overrides().items() if k in ("tour", "route_file")}
        for r in ("campus", str(tour), str(csv))
    }
    assert picked == {
        "campus": {"tour": "campus"},
        str(tour): {"tour": str(tour.resolve())},
        str(csv): {"route_file": str(csv.resolve())},
    }
