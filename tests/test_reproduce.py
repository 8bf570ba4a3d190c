"""`ares reproduce` (ares/tools/reproduce): each experiment on its short version, its drives on the
in-process stack (deterministic, quick) where `ares reproduce` runs the process stack; the report;
the command's --list and --only."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from ares.app.stack import prepare
from ares.tools.reproduce import EXPERIMENTS
from ares.tools.reproduce.experiment import Context, Drive, Driven
from ares.tools.reproduce.report import write_report
from ares.tools.reproduce.store_reading import events_and_records
from tests.helpers.in_process_stack import InProcessStack
from tests.helpers.stack import NO_LIDARS, REPO

IN_PROCESS = REPO / "tests" / "in_process.yaml"


def in_process_drive(drive: Drive, folder: Path) -> Driven:
    """A drive as the experiments ask for it, on the in-process stack."""
    folder.mkdir(parents=True, exist_ok=True)
    store = folder / "blackbox.sqlite"
    overrides: dict = {"blackbox_store": {"uri": str(store)}}
    if drive.scenario:
        overrides["scenario"] = drive.scenario
    if drive.controller:
        overrides["control_manager"] = {"pinned": drive.controller}
    if drive.start_s_m is not None:
        overrides["sim"] = {"start_s_m": drive.start_s_m}
    cfg = prepare((str(NO_LIDARS), str(IN_PROCESS)), overrides, 1.0)
    with InProcessStack(cfg, run_dir=folder / "run") as stack:
        return Driven(stack.drive(seconds=drive.seconds), store)


@pytest.fixture
def ctx(tmp_path) -> Context:
    return Context(out=tmp_path, drive=in_process_drive, quick=True)


def rows_of(result) -> dict:
    return {row.figure: row for row in result.rows}


def test_the_step_responses_beside_the_papers(ctx):
    result = EXPERIMENTS["dbw-steps"](ctx)
    rows = rows_of(result)
    assert rows["steering, 200°: rise time (90 %)"].paper == 0.65
    assert rows["steering, 200°: rise time (90 %)"].ares == pytest.approx(0.65, abs=0.1)
    assert rows["throttle 0→3 m/s, 4 people: settling time"].ares == pytest.approx(5.45, abs=0.5)
    assert result.picture.exists() and result.picture.stat().st_size > 10_000
    assert result.notes and result.seconds >= 0


def test_the_takeovers_at_the_papers_times(ctx, tmp_path):
    """DBW Fig. 28 (simulator/scenarios/takeover.yaml) in the in-process stack: the bridge goes to
    Manual in the step of the driver's hand on the wheel (12 s) and foot on the throttle (73 s),
    the shuttle parks with nobody driving, and after the button and `engage` it drives on. As an
    auditor reads it: the black box's events and its mode of each second."""
    result = EXPERIMENTS["dbw-takeover"](ctx)
    values = [(row.figure, row.paper, row.ares) for row in result.rows]
    assert values[0] == ("takeover by the steering wheel", 12.0, 12.0)
    assert values[1][2] == 0.0  # Manual in the very step of the hand on the wheel
    assert values[2] == ("Automatic again", 27.0, 27.0)
    assert values[3] == ("takeover by the throttle", 73.0, 73.0) and values[4][2] == 0.0
    assert values[5] == ("Automatic again", 88.0, 88.0)
    assert rows_of(result)["collisions"].ares == 0 and result.picture.exists()
    events, records = events_and_records(tmp_path / "takeover" / "blackbox.sqlite")
    actions = [(e["t"], e["data"]["action"]) for e in events if e["kind"] == "driver_action"]
    assert actions == [(12.0, "steer"), (26.5, "button"), (73.0, "throttle"), (87.5, "button")]
    changes = [(e["t"], e["message"].split(":")[0]) for e in events if e["kind"] == "mode_change"][
        2:
    ]  # after the start
    assert changes == [
        (12.0, "AUTOMATIC -> MANUAL"),
        (26.5, "MANUAL -> READY"),
        (27.0, "READY -> AUTOMATIC"),  # the paper's 15 s in Manual
        (73.0, "AUTOMATIC -> MANUAL"),
        (87.5, "MANUAL -> READY"),
        (88.0, "READY -> AUTOMATIC"),
    ]
    mode = {int(r["t"]): (r["mode"], r["speed_mps"]) for r in records}
    assert all(mode[k][0] == "AUTOMATIC" for k in (*range(3, 12), *range(28, 73), *range(89, 100)))
    assert all(mode[k][0] == "MANUAL" for k in (*range(13, 26), *range(74, 87)))
    assert mode[24][1] == 0.0 and mode[85][1] == 0.0  # parked, nobody driving
    assert max(mode[k][1] for k in range(73, 77)) > max(mode[k][1] for k in range(68, 73))  # the driver's throttle
    assert mode[99][1] > 2.0  # and on again


def test_the_mpc_beside_stanley_and_the_report(ctx, tmp_path):
    lateral = EXPERIMENTS["ares-fig15"](ctx)
    rows = rows_of(lateral)
    assert rows["cross-track error RMSE, mpc"].ares < rows["cross-track error RMSE, stanley"].ares
    assert rows["the MPC follows the path closer"].ares == "yes"
    report = write_report(tmp_path / "report.md", [lateral], 12.0).read_text()
    assert "## Lateral control: the MPC beside Stanley (ARES paper Fig. 15, §3.6.1)" in report
    assert "| the MPC follows the path closer | yes (pictures) | yes |  |" in report


def test_the_trapezoid_beside_the_rectangle_says_plainly_what_it_shows(ctx):
    result = EXPERIMENTS["ares-fig14"](ctx)
    rows = rows_of(result)
    assert rows["frames in the narrow lane"].ares >= 10
    verdict = rows["the trapezoid avoids the rectangle's false detections"].ares
    assert verdict == "yes" or verdict.startswith("no: no advantage shown")


def test_the_command_lists_its_experiments_and_refuses_an_unknown_one():
    listed = subprocess.run(
        [sys.executable, "-m", "ares.cli", "reproduce", "--list", "--json"], cwd=REPO, capture_output=True, text=True
    )
    assert listed.returncode == 0, listed.stderr
    assert [e["id"] for e in json.loads(listed.stdout)["experiments"]] == list(EXPERIMENTS)
    wrong = subprocess.run(
        [sys.executable, "-m", "ares.cli", "reproduce", "--only", "fig99"], cwd=REPO, capture_output=True, text=True
    )
    assert wrong.returncode == 1 and "unknown experiments ['fig99']" in wrong.stderr
