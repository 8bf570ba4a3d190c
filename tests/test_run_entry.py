"""`ares run` as a function: ares.app.stack.run takes RunOptions and returns a RunResult. Here what
needs no process: the command line's arguments become the options, a refused configuration is a
typed result, the clock a run gets without --speed, the JSON line a result makes. A whole run
through the function: tests/test_stack.py."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml
from pydantic import ValidationError

from ares import cli
from ares.app import stack
from ares.app.run_options import RunOptions, RunResult
from ares.cli.run import run_options
from ares.core.config import ConfigError
from ares.core.localhost import free_port

DEVICES = {
    "gnss": {"source": "serial", "device": "/dev/ttyACM0"},
    "can": {"interface": "socketcan", "channel": "can0"},
}


def test_every_argument_of_ares_run_becomes_an_option(tmp_path):
    args = cli.build_parser().parse_args(
        ["run", "--headless", "--laps", "2", "--speed", "max", "--config", "a.yaml", "--config", "b.yaml"]
        + ["--route", "campus", "--scenario", "pedestrian_crossing", "--mission", "drive", "--controller", "mpc"]
        + ["--wire", "--vehicle", "techs4agecar", "--passengers", "3", "--vehicle-id", "shuttle07"]
        + ["--listen", "tcp/127.0.0.1:7450", "--vehicle-cpus", "0", "--run-dir", str(tmp_path)]
        + ["--api-port", "8500", "--store", "bb.sqlite", "--record", "--foxglove", "9000"]
    )
    assert run_options(args) == RunOptions(
        config_files=("a.yaml", "b.yaml"),
        headless=True,
        laps=2,
        speed="max",
        route="campus",
        scenario="pedestrian_crossing",
        mission="drive",
        controller="mpc",
        wire=True,
        vehicle="techs4agecar",
        passengers=3,
        vehicle_id="shuttle07",
        listen="tcp/127.0.0.1:7450",
        vehicle_cpus=(0,),
        run_dir=tmp_path,
        api_port=8500,
        store="bb.sqlite",
        record="",  # bus.mcap in the run folder
        foxglove="9000",
    )
    plain = run_options(cli.build_parser().parse_args(["run"]))
    assert plain == RunOptions() and plain.speed is None and plain.fleet == 1


@pytest.mark.parametrize(
    "bad, field",
    [({"speed": "fast"}, "speed"), ({"laps": 0}, "laps"), ({"mission": "fly"}, "mission"), ({"lap": 2}, "lap")],
)
def test_options_out_of_their_range_are_refused_when_made(bad, field):
    with pytest.raises(ValidationError, match=field):
        RunOptions(**bad)


def test_the_options_settings_are_the_base_their_choices_override():
    options = RunOptions(settings={"sim": {"start_s_m": 12.0, "passengers": 1}, "api": {"port": 1}}, passengers=4)
    over = options.overrides()
    assert over["sim"] == {"start_s_m": 12.0, "passengers": 4}
    assert over["api"] == {"port": 1}  # no --api-port: the settings' stands


def test_a_misspelt_key_is_a_refused_result_naming_the_file_and_the_key(tmp_path):
    bad = tmp_path / "run.yaml"
    bad.write_text(yaml.safe_dump({"pure_pursuit": {"lookahead_gian_s": 1.0}}))
    run_dir = tmp_path / "run"
    options = RunOptions(
        config_files=(str(bad),), headless=True, run_dir=run_dir, listen=f"tcp/127.0.0.1:{free_port()}"
    )
    result = stack.run(options)
    assert (result.ok, result.refused, result.interrupted, result.exit_code) == (False, True, False, 2)
    assert str(bad) in result.error and "pure_pursuit.lookahead_gian_s: unknown key" in result.error
    assert result.figures == {} and result.blackbox_records is None and result.logs is None
    assert not run_dir.exists(), "nothing was started, nothing was written"


def test_a_fleet_at_the_lockstep_is_refused(tmp_path):
    result = stack.run(RunOptions(fleet=2, speed="paced", run_dir=tmp_path / "run"))
    assert result.refused and result.exit_code == 2 and "--fleet runs interactively" in result.error


def test_ares_run_prints_the_refusal_and_no_result_line(tmp_path, capsys):
    bad = tmp_path / "run.yaml"
    bad.write_text(yaml.safe_dump({"sim": {"pasengers": 5}}))
    assert cli.main(["run", "--headless", "--config", str(bad), "--run-dir", str(tmp_path / "run")]) == 2
    out = capsys.readouterr()
    assert out.out == "" and out.err.startswith("ares run: ") and "sim.pasengers: unknown key" in out.err


def test_a_simulated_run_without_speed_is_paced_and_the_vehicle_keeps_its_wall_clock():
    # the simulator drives the clock, never faster than real time, waiting for every process it feeds
    assert stack.resolved_speed(None, simulate=True) == "paced"
    simulated = stack.prepare((), {"lidars": False}, None)
    assert simulated["lockstep"]["pace"] == 1.0 and "localization" in simulated["lockstep"]["participants"]
    assert type(stack.stack_clock(simulated, stack.resolved_speed(None, True))).__name__ == "DrivenClock"
    # `--speed 1` stays what it was: the simulation's clock at real time, each process on its own timers
    scaled = stack.prepare((), {"lidars": False}, 1.0)
    assert scaled["lockstep"]["participants"] == [] and stack.stack_clock(scaled, 1.0).mode == "scaled"
    # a fleet's shuttles share one clock, which no one simulator can drive
    assert stack.resolved_speed(None, simulate=True, fleet=3) == 1.0
    # on the vehicle the wall clock, which nothing hurries
    assert stack.resolved_speed(None, simulate=False) == 1.0
    vehicle = stack.prepare((), {"simulate": False, "lidars": False, "vehicle_io": DEVICES}, None)
    assert vehicle["lockstep"]["participants"] == [] and stack.stack_clock(vehicle, 1.0).mode == "wall"
    with pytest.raises(ConfigError, match="--speed paced needs the simulator"):
        stack.prepare((), {"simulate": False, "lidars": False, "vehicle_io": DEVICES}, "paced")


def test_the_result_line_of_a_finished_and_of_a_failed_run():
    figures = {"laps": 1, "distance_m": 801.2, "xte_rmse_m": 0.02}
    done = RunResult(ok=True, run_dir=Path("runs/1"), figures=figures, blackbox_records=498, recording={"file": "b"})
    assert json.loads(json.dumps(done.summary())) == {
        "ok": True,
        "run_dir": "runs/1",
        **figures,
        "blackbox_records": 498,
        "recording": {"file": "b"},
    }
    assert done.exit_code == 0
    failed = RunResult(ok=False, run_dir=Path("runs/2"), error="the shuttle has not moved for 60 s", figures=figures)
    assert failed.summary() == {
        "ok": False,
        "error": "the shuttle has not moved for 60 s",
        "run_dir": "runs/2",
        **figures,
    }
    assert failed.exit_code == 1
