"""`ares run --fleet N` (ares/app/fleet.py): the shuttles' ids, ports, starts and shared router."""

from __future__ import annotations

import pytest

from ares.app import run_config
from ares.app.fleet import MAX_FLEET, START_S_M, fleet_configs, fleet_ids
from ares.core import config
from ares.core.route import load_route


def test_ids_count_on_from_the_first():
    assert fleet_ids("shuttle01", 3) == ["shuttle01", "shuttle02", "shuttle03"]
    assert fleet_ids("bus9", 2) == ["bus9", "bus10"]
    assert fleet_ids("alpha", 3) == ["alpha", "alpha-2", "alpha-3"]


def test_each_shuttle_has_its_id_port_and_start_and_joins_the_first_ones_router():
    cfg = run_config.build((), {"api": {"port": 9000}})
    route = load_route(config.core(cfg))
    cfgs = fleet_configs(cfg, 3, route.length)
    assert [c["vehicle_id"] for c in cfgs] == ["shuttle01", "shuttle02", "shuttle03"]
    assert [c["api"]["port"] for c in cfgs] == [9000, 9001, 9002]
    assert [c["sim"]["start_s_m"] for c in cfgs] == list(START_S_M[:3])
    assert [c["bus"]["embedded_router"] for c in cfgs] == [cfg["bus"]["embedded_router"], False, False]
    assert len({c["bus"]["router"] for c in cfgs}) == 1
    assert cfg["vehicle_id"] == "shuttle01" and cfg["api"]["port"] == 9000  # the first's own left alone
    for c in cfgs:  # clear of the RTK-loss zones and crossings: the stack starts well
        s = c["sim"]["start_s_m"]
        assert not any(z.s_start - 20 <= s <= z.s_end for z in route.zones if z.kind != "narrow"), s


def test_a_fleet_too_large_is_refused():
    cfg = run_config.build((), {})
    with pytest.raises(config.ConfigError):
        fleet_configs(cfg, MAX_FLEET + 1, 1000.0)
