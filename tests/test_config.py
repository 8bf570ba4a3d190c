"""Typed configuration: every section a model that refuses unknown keys, defaults in one place, a
bad file refused before anything starts, with the file, the key and what is allowed."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from pydantic import ValidationError

from ares import cli
from ares.app import run_config
from ares.core import config
from ares.core.config import ConfigError
from ares.core.localhost import free_port

REPO = Path(__file__).resolve().parents[1]


def write(tmp_path: Path, name: str, data: dict) -> Path:
    path = tmp_path / name
    path.write_text(yaml.safe_dump(data))
    return path


def test_the_defaults_build_and_validate():
    cfg = run_config.build()
    assert cfg["vehicle_id"] == "shuttle01" and cfg["vehicle_profile"]["name"] == "ares_shuttle"
    assert cfg["path_manager"]["radius_m"] == 5.0 and cfg["dbw_bridge"]["setpoint_timeout_s"] == 0.5
    # the code's defaults are the only ones: no file of defaults is shipped beside them
    assert not (REPO / "ares" / "core" / "config" / "stack.yaml").exists()
    # and they are what a section model gives when nothing is configured
    from perception.localization import LocalizationParams

    assert cfg["localization"] == LocalizationParams().model_dump(mode="json")


def test_a_misspelt_key_names_the_file_the_key_and_what_is_allowed(tmp_path):
    bad = write(tmp_path, "site.yaml", {"path_manager": {"radius_mm": 4.0}})
    with pytest.raises(ConfigError) as caught:
        run_config.build((bad,))
    message = str(caught.value)
    assert str(bad) in message and "path_manager.radius_mm: unknown key" in message
    assert "did you mean 'radius_m'" in message and "window_ahead_m" in message


def test_a_misspelt_section_and_a_bad_value(tmp_path):
    with pytest.raises(ConfigError, match="localisation: unknown key \\(did you mean 'localization'\\?\\)"):
        run_config.build((write(tmp_path, "a.yaml", {"localisation": {"rate_hz": 50}}),))
    with pytest.raises(ConfigError, match="sim.physics_hz: Input should be greater than 0"):
        run_config.build((write(tmp_path, "b.yaml", {"sim": {"physics_hz": -1}}),))
    with pytest.raises(ConfigError, match="bus.mode: Input should be 'peer' or 'client'"):
        run_config.build((write(tmp_path, "c.yaml", {"bus": {"mode": "router"}}),))


def test_files_apply_in_order_and_overrides_last(tmp_path):
    first = write(tmp_path, "1.yaml", {"sim": {"passengers": 4}, "vehicle_id": "alpha"})
    second = write(tmp_path, "2.yaml", {"sim": {"passengers": 6}})
    cfg = run_config.build((first, second), {"vehicle_id": "beta"})
    assert cfg["sim"]["passengers"] == 6 and cfg["vehicle_id"] == "beta"


def test_a_vehicle_profile_with_a_misspelt_key_names_its_file(tmp_path):
    profile = yaml.safe_load((REPO / "ares" / "core" / "config" / "vehicles" / "ares_shuttle.yaml").read_text())
    profile["wheelbase"] = profile.pop("wheelbase_m")
    path = write(tmp_path, "shuttle.yaml", profile)
    with pytest.raises(ConfigError) as caught:
        config.load_vehicle(str(path))
    assert str(path) in str(caught.value) and "wheelbase_m: required" in str(caught.value)
    assert "wheelbase: unknown key" in str(caught.value)


def test_vehicle_profile_overrides_are_named_where_they_were_made(tmp_path):
    ok = write(tmp_path, "ok.yaml", {"vehicle_profile": {"empty_mass_kg": 700.0}})
    assert run_config.build((ok,))["vehicle_profile"]["empty_mass_kg"] == 700.0
    bad = write(tmp_path, "bad.yaml", {"vehicle_profile": {"wheelbase_m": -1.0, "empty_mas_kg": 700.0}})
    with pytest.raises(ConfigError) as caught:
        run_config.build((ok, bad))
    message = str(caught.value)
    assert message.startswith(f"{bad}: ")
    assert "vehicle_profile.wheelbase_m: Input should be greater than 0" in message
    assert "vehicle_profile.empty_mas_kg: unknown key (did you mean 'empty_mass_kg'?)" in message
    with pytest.raises(ConfigError, match="the command line: vehicle_profile.empty_mass_kg: Input should be"):
        run_config.build((ok,), {"vehicle_profile": {"empty_mass_kg": "heavy"}})
    with pytest.raises(
        ConfigError,
        match=f"{write(tmp_path, 'list.yaml', {'vehicle_profile': [1]})}: vehicle_profile: expected a mapping",
    ):
        run_config.build((tmp_path / "list.yaml",))


def test_command_line_overrides_are_validated_as_the_command_line(tmp_path):
    with pytest.raises(ConfigError, match="^the command line: vehicle_id: String should match pattern"):
        run_config.build((write(tmp_path, "a.yaml", {"sim": {"passengers": 4}}),), {"vehicle_id": "a b"})


def test_an_empty_section_means_its_defaults(tmp_path):
    path = tmp_path / "empty.yaml"
    path.write_text("supervisor:\nsim:\n  passengers: 3\n")
    cfg = run_config.build((path,))
    assert cfg["supervisor"]["check_period_s"] == 0.1 and cfg["sim"]["passengers"] == 3


def test_errors_inside_lists_still_say_what_is_allowed(tmp_path):
    bad = write(tmp_path, "sup.yaml", {"supervisor": {"restart_backoff_s": [0.5, -1.0]}})
    with pytest.raises(ConfigError, match="supervisor.restart_backoff_s.1: Input should be greater than or equal to 0"):
        run_config.build((bad,))
    from ares.core.config import TourDescription

    tour = yaml.safe_load((REPO / "ares" / "core" / "config" / "tours" / "default.yaml").read_text())
    listed = next(k for k, v in tour.items() if isinstance(v, list) and v and isinstance(v[0], dict))
    tour[listed][0]["colour"] = "red"
    with pytest.raises(ConfigError) as caught:
        config.validated(TourDescription, tour, "tour.yaml")
    allowed = sorted(TourDescription.model_fields[listed].annotation.__args__[0].model_fields)
    assert f"{listed}.0.colour: unknown key" in str(caught.value) and ", ".join(allowed) in str(caught.value)


def test_an_unknown_vehicle_or_tour_lists_the_known_ones():
    with pytest.raises(ConfigError, match="unknown vehicle 'ligier'; known: ares_shuttle, techs4agecar"):
        config.load_vehicle("ligier")
    with pytest.raises(ConfigError, match="unknown tour 'nowhere'; known: campus, default"):
        config.load_tour("nowhere")


def test_sections_are_read_only():
    from managers.path import PathManagerParams

    params = PathManagerParams()
    with pytest.raises(ValidationError, match="frozen"):
        params.radius_m = 1.0  # a node's parameters do not change under it


def test_ares_run_with_a_misspelt_key_exits_2_before_any_process_starts(tmp_path):
    bad = write(tmp_path, "run.yaml", {"pure_pursuit": {"lookahead_gian_s": 1.0}})
    run_dir = tmp_path / "run"
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "ares.cli",
            "run",
            "--headless",
            "--config",
            str(bad),
            "--run-dir",
            str(run_dir),
            "--listen",
            f"tcp/127.0.0.1:{free_port()}",
        ],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=60,
        stdin=subprocess.DEVNULL,
    )
    assert result.returncode == 2
    assert str(bad) in result.stderr and "pure_pursuit.lookahead_gian_s: unknown key" in result.stderr
    assert "lookahead_gain_s" in result.stderr
    assert not run_dir.exists(), "nothing was started, nothing was written"


def test_config_check_and_show(tmp_path, capsys):
    good = write(tmp_path, "good.yaml", {"sim": {"passengers": 5}})
    bad = write(tmp_path, "bad.yaml", {"sim": {"pasengers": 5}})
    # once as the command runs, in a process of its own; the rest through the same entry point here
    ok = subprocess.run(
        [sys.executable, "-m", "ares.cli", "config", "check", str(good)],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert ok.returncode == 0 and "ok" in ok.stdout
    assert cli.main(["config", "check", str(bad)]) == 2
    assert "sim.pasengers: unknown key (did you mean 'passengers'?)" in capsys.readouterr().err
    assert cli.main(["config", "show", str(good)]) == 0
    shown = capsys.readouterr().out
    assert "# passengers on board" in shown  # every key with its meaning
    assert yaml.safe_load(shown) == run_config.build((good,))  # and it is the merged configuration
    assert cli.main(["config", "show", "--json"]) == 0
    assert json.loads(capsys.readouterr().out) == run_config.build()


def test_only_a_simulated_shuttle_can_be_hurried():
    from ares.app.stack import prepare

    for speed in (5.0, "max"):
        with pytest.raises(ConfigError, match=f"--speed {speed} needs the simulator"):
            prepare((), {"simulate": False}, speed)
    devices = {
        "gnss": {"source": "serial", "device": "/dev/ttyACM0"},
        "can": {"interface": "socketcan", "channel": "can0"},
    }
    assert prepare((), {"simulate": False, "lidars": False, "vehicle_io": devices}, 1.0)["simulate"] is False
