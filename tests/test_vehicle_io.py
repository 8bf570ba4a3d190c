"""Vehicle I/O at the level of a run: which processes each kind of run starts (plain simulation,
simulation behind the wires, the vehicle), that each kind's topic graph is whole, that `--wire`
gives the run private wires and puts the drivers in the lockstep, and that a vehicle run without
its devices is refused with one error naming every input nobody would publish."""

from __future__ import annotations

import pytest
import yaml

from ares import cli
from ares.app import contracts, processes, vehicle_io
from ares.app.stack import prepare
from ares.core.config import ConfigError

DEVICES = {
    "gnss": {"source": "serial", "device": "/dev/ttyACM0"},
    "can": {"interface": "socketcan", "channel": "can0"},
    "lidars": {
        "roof": {"model": "HDL-64E", "port": 2368},
        "front_left": {"model": "VLP-16", "port": 2369},
        "front_right": {"model": "VLP-16", "port": 2370},
    },
}
DRIVERS = {"gnss_driver", "can_driver", "lidar_driver"}


def names(specs):
    return [p.name for p in specs]


def test_each_kind_of_run_starts_its_own_processes():
    plain, wire, vehicle = (
        processes.for_run(True, True, False),
        processes.for_run(True, True, True),
        processes.for_run(False, True, False),
    )
    assert not DRIVERS & set(names(plain))
    assert {p.node for p in plain if p.name == "sim"} == {"simulator.simulator_node:Simulator"}
    assert DRIVERS <= set(names(wire))
    assert {p.node for p in wire if p.name == "sim"} == {"simulator.wire_simulator_node:WireSimulator"}
    assert DRIVERS <= set(names(vehicle)) and "sim" not in names(vehicle) and "lidar_sim" not in names(vehicle)
    assert "lidar_driver" not in names(processes.for_run(False, False, False))
    for specs in (plain, wire, vehicle):
        assert len(names(specs)) == len(set(names(specs))), "one process per name in a run"


@pytest.mark.parametrize(
    "overrides",
    [{}, {"wire": True}, {"simulate": False, "vehicle_io": DEVICES}],
    ids=["plain simulation", "behind the wires", "the vehicle"],
)
def test_each_kind_of_runs_topic_graph_is_whole(overrides):
    cfg = prepare((), overrides, 1.0)
    graph = contracts.graph(contracts.all_contracts(cfg, processes.for_config(cfg)))
    assert contracts.problems(graph) == []
    # whoever publishes the sensors, the command to the wheels still has one source
    assert graph["movement/command"]["publishers"] == ["movement_manager"]


def test_wire_gives_the_run_wires_of_its_own_and_the_lockstep_waits_for_the_drivers(tmp_path):
    first = prepare((), {"wire": True}, "max", wire_dir=tmp_path / "a")
    second = prepare((), {"wire": True}, "max", wire_dir=tmp_path / "b")
    io = first["vehicle_io"]
    assert io["gnss"]["device"] == str((tmp_path / "a" / "gnss.tty").resolve())
    assert io["can"]["interface"] == "udp_multicast"
    assert set(io["lidars"]) == {"roof", "front_left", "front_right"}
    assert io["lidars"]["roof"]["model"] == "HDL-64E" and io["lidars"]["front_left"]["model"] == "VLP-16"
    assert (io["can"]["channel"], io["can"]["port"]) != (
        second["vehicle_io"]["can"]["channel"],
        second["vehicle_io"]["can"]["port"],
    )
    participants = first["lockstep"]["participants"]
    assert DRIVERS <= set(participants)
    # and downstream of the drivers, what they feed
    assert {"gnss", "localization", "lidar_perception"} <= set(participants)


def test_a_vehicle_without_devices_is_refused_naming_each_input():
    with pytest.raises(ConfigError) as err:
        prepare((), {"simulate": False}, 1.0)
    text = str(err.value)
    for topic, device in [
        ("sensors/gnss", "vehicle_io.gnss"),
        ("sensors/can", "vehicle_io.can"),
        ("sensors/imu", "vehicle_io.can"),
        ("lidar/roof/points", "vehicle_io.lidars.roof"),
        ("lidar/front_left/points", "vehicle_io.lidars.front_left"),
    ]:
        assert topic in text and device in text, (topic, text)
    assert "--vehicle-io" in text


def test_a_vehicle_missing_one_lidar_is_refused_for_that_lidar_alone():
    devices = {**DEVICES, "lidars": {k: v for k, v in DEVICES["lidars"].items() if k != "front_right"}}
    with pytest.raises(ConfigError) as err:
        prepare((), {"simulate": False, "vehicle_io": devices}, 1.0)
    text = str(err.value)
    assert "lidar/front_right/points" in text
    assert "sensors/gnss" not in text and "lidar/roof/points" not in text
    # without the LiDARs the stack drives on GNSS and odometry: nothing is missing
    assert prepare((), {"simulate": False, "lidars": False, "vehicle_io": devices}, 1.0)["simulate"] is False


def test_ares_run_on_a_vehicle_without_devices_exits_2_with_one_line(tmp_path, capsys):
    conf = tmp_path / "vehicle.yaml"
    conf.write_text("simulate: false\n")
    assert cli.main(["run", "--config", str(conf), "--run-dir", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "sensors/gnss" in err[0] and "no driver reads a device" in err[0]


def test_a_vehicle_io_file_is_validated_naming_the_file_and_the_key(tmp_path):
    good = tmp_path / "io.yaml"
    good.write_text("gnss: {source: tcp, host: 10.0.0.5, port: 5000}\ncan: {interface: socketcan, channel: can1}\n")
    loaded = vehicle_io.load(good)
    assert loaded["gnss"]["port"] == 5000 and loaded["can"]["channel"] == "can1" and loaded["lidars"] == {}
    bad = tmp_path / "bad.yaml"
    bad.write_text("gnss: {source: serial, devcie: /dev/ttyACM0}\n")
    with pytest.raises(ConfigError, match="bad.yaml") as err:
        vehicle_io.load(bad)
    assert "devcie" in str(err.value)
    (tmp_path / "serial.yaml").write_text("gnss: {source: serial}\n")
    with pytest.raises(ConfigError, match="serial GNSS receiver needs its `device`"):
        vehicle_io.load(tmp_path / "serial.yaml")


def test_wire_needs_the_simulator():
    with pytest.raises(ConfigError, match="--wire"):
        prepare((), {"wire": True, "simulate": False, "vehicle_io": DEVICES}, 1.0)


def test_the_simulator_served_alone_writes_where_a_vehicle_run_reads(tmp_path):
    from ares.app import wire_sim

    cfg = wire_sim.sim_config((), {}, tmp_path / "wires")
    assert cfg["simulate"] and cfg["wire"]
    assert cfg["vehicle_io"]["gnss"]["device"] == str(tmp_path / "wires" / "gnss.tty")
    # what `ares sim serve` writes for the vehicle's run is a valid --vehicle-io file, and with it a
    # vehicle run has every input it needs
    io_file = tmp_path / "vehicle_io.yaml"
    io_file.write_text(yaml.safe_dump(cfg["vehicle_io"]))
    vehicle = prepare((), {"simulate": False, "vehicle_io": vehicle_io.load(io_file)}, 1.0)
    assert vehicle_io.missing_inputs(vehicle) == []


def test_a_vehicle_run_shares_a_wall_clock_given_in_its_environment(monkeypatch):
    from ares.app.stack import stack_clock
    from ares.core.clock import WallClock

    theirs = WallClock()
    for key, value in theirs.env().items():
        monkeypatch.setenv(key, value)
    ours = stack_clock(prepare((), {"simulate": False, "vehicle_io": DEVICES}, 1.0), 1.0)
    assert ours.mode == "wall" and abs(ours.now() - theirs.now()) < 0.05
    assert ours.utc_epoch == theirs.utc_epoch
