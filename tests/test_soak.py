"""`ares soak` as a newcomer runs it: the whole stack at --speed max, without LiDARs (their faults
and the obstacles need them: the long soak of docs/reliability.md has them), 50 faults of every
other kind packed a few seconds apart. Whatever the faults, the shuttle hits nothing, the movement
gate keeps its invariants, the black box loses no second, every bad API request gets a 4xx, and
every safety-relevant fault that found the shuttle driving brought it to its safe state. How fast
is docs/reliability.md's business, not a test's."""

from __future__ import annotations

import json
import signal
import subprocess
import sys

import pytest

from ares.core.localhost import free_port
from ares.tools.soak.plan import kinds_for
from tests.helpers.stack import NO_LIDARS, REPO

pytestmark = [pytest.mark.stack, pytest.mark.whole_stack]

FAULTS = 50
SLOT_S = 4.0  # stack seconds per fault: the plan's least


@pytest.mark.timeout(600)  # ~100 s on an idle machine; a busy one starts a dozen processes slowly
def test_a_short_soak_of_50_faults_hits_nothing_breaks_no_invariant_and_loses_no_second(tmp_path):
    out = tmp_path / "soak"
    hours = FAULTS * SLOT_S / 3600.0
    command = [sys.executable, "-m", "ares.cli", "soak", "--hours", f"{hours:.6f}", "--faults", str(FAULTS)]
    command += ["--seed", "7", "--json", "--lead", "5", "--config", str(NO_LIDARS), "--out", str(out)]
    command += ["--listen", f"tcp/127.0.0.1:{free_port()}", "--api-port", str(free_port())]
    proc = subprocess.Popen(
        command, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, stdin=subprocess.DEVNULL
    )
    try:
        stdout, stderr = proc.communicate(timeout=560)
    finally:
        if proc.poll() is None:  # out of time: SIGINT lets the soak stop its stack (a SIGKILL would orphan it)
            proc.send_signal(signal.SIGINT)
            try:
                proc.communicate(timeout=60)
            except subprocess.TimeoutExpired:
                proc.kill()
    assert proc.returncode == 0, f"exit {proc.returncode}\n{stdout[-2000:]}\n{stderr[-3000:]}"
    summary = json.loads(stdout.strip().splitlines()[-1])
    assert summary["finished"] and summary["faults_injected"] >= FAULTS
    assert set(summary["per_kind"]) == set(kinds_for(False)), "every kind without LiDARs"
    assert summary["collisions"] == 0 and summary["invariant_violations"] == 0, summary["invariant_examples"]
    assert summary["blackbox_seconds_lost"] == 0, summary["blackbox_lost_examples"]
    # every bad request the running API answered got a 4xx (none unanswered while it was up)
    assert summary["api_requests"] > 0 and summary["api_not_4xx"] == 0
    # a safety-relevant fault that found the shuttle driving normally brought it to its safe state
    assert summary["all"]["safety_relevant"] > 0 and summary["all"]["safe_state_missed"] == 0
    # and every fault was got over: each killed, hung or busy process restarted, the shuttle driving again
    assert summary["all"]["not_recovered"] == 0
    assert summary["availability"] is not None and 0.0 < summary["availability"] <= 1.0
    lines = (out / "faults.jsonl").read_text().splitlines()
    assert len(lines) == FAULTS and all(json.loads(line)["injected"] for line in lines)
    assert (out / "soak.png").stat().st_size > 10_000
    # the same figures from the directory alone, as for a soak stopped early
    again = subprocess.run(
        [sys.executable, "-m", "ares.cli", "soak", "--summarise", str(out), "--json"],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=60,
    )
    partial = json.loads(again.stdout.strip().splitlines()[-1])
    assert partial["faults_injected"] == summary["faults_injected"]
    assert partial["blackbox_seconds_lost"] == 0
    print(
        f"\nshort soak: {summary['faults_injected']} faults in {summary['vehicle_hours'] * 3600:.0f} s vehicle time, "
        f"{summary['run']['wall_time_s']} s wall; max time to safe state {summary['time_to_safe_state_max_s']} s; "
        f"availability {summary['availability']}"
    )
