"""`ares route coverage` (ares/tools/coverage.py): the default tour driven by the simulated receiver
(its no_4g zone: corrections stop and the fix degrades as they age; its rtk_loss zone: the sky
blocked), and a run's black box read back: the shares of the route with RTK and with corrections."""

from __future__ import annotations

import json
from datetime import UTC, datetime, timedelta

import numpy as np
import pytest

from ares import cli
from ares.app import run_config
from ares.core.messages import CorrectionsRecord, Position, VehicleRecord
from ares.core.route import Route
from ares.tools.coverage import coverage_recorded, coverage_simulated
from tests.helpers.api import open_test_store


@pytest.fixture(scope="module")
def cfg():
    return run_config.build((), {})


def test_the_default_tour_simulated(cfg):
    result = coverage_simulated(cfg)
    route = Route.from_tour("default")
    no_4g = next(z for z in route.zones if z.kind == "no_4g")
    sky = next(z for z in route.zones if z.kind == "rtk_loss")
    assert result.driven_share == 1.0
    assert result.corrections_share == pytest.approx(1 - (no_4g.s_end - no_4g.s_start) / route.length, abs=0.005)
    blocked = (sky.s_end - sky.s_start) / route.length
    assert 0.85 < result.rtk_fixed_share < 1 - blocked  # the sky-blocked stretch and part of the no-4G one
    stretch = np.arange(len(result.stretch_fix)) + 0.5
    inside = (stretch > no_4g.s_start + 30) & (stretch < no_4g.s_end)  # its corrections long gone there
    assert set(result.stretch_fix[inside]) <= {5, 2} and (result.stretch_link[inside] == 0).all()
    assert set(result.stretch_fix[(stretch > sky.s_start + 1) & (stretch < sky.s_end - 1)]) == {1}
    assert set(result.fix_shares) == {"RTK fixed", "RTK float", "DGPS", "single"}


def test_a_runs_black_box_read_back(cfg, tmp_path):
    """Records along the route: RTK on the first half, float on the rest, corrections lost on the
    last quarter; every stretch driven once, the shares as recorded."""
    route = Route.from_tour("default")
    store = open_test_store(tmp_path / "bb.sqlite")
    start = datetime(2026, 12, 1, 10, tzinfo=UTC)
    records = []
    for k, s in enumerate(np.arange(0.0, route.length, 0.5)):
        x, y, z, _yaw = route.point_at(float(s))
        quality = 4 if s < route.length / 2 else 5
        link = "streaming" if s < 0.75 * route.length else "down"
        position = Position(x=x, y=y, z=z, easting=0.0, northing=0.0, zone=30, hemisphere="N", lat=40.0, lon=-3.0)
        records.append(
            VehicleRecord(
                vehicle_id="shuttle01",
                time=start + timedelta(seconds=k),
                t=float(k),
                position=position,
                corrections=CorrectionsRecord(link=link, age_s=0.5, fix_quality=quality),
            )
        )
    store.insert_records(records)
    store.close()
    result = coverage_recorded(cfg, str(tmp_path / "bb.sqlite"))
    assert result.samples >= len(records) and result.driven_share > 0.99
    assert result.rtk_fixed_share == pytest.approx(0.5, abs=0.01)
    assert result.corrections_share == pytest.approx(0.75, abs=0.01)
    with pytest.raises(ValueError, match="no vehicle's records"):
        coverage_recorded(cfg, str(tmp_path / "empty.sqlite"))


def test_the_command_draws_and_prints(tmp_path, capsys):
    picture = tmp_path / "coverage.png"
    assert cli.main(["route", "coverage", "--route", "campus", "--out", str(picture)]) == 0
    report = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert report["route"] == "campus" and report["rtk_fixed_share"] == 1.0  # no zone on the campus loop
    assert picture.stat().st_size > 20_000
