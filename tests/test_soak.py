"""`ares soak` as a newcomer runs it: the whole stack at --speed max, without LiDARs (their faults
and the obstacles need them: the long soak of docs/reliability.md has them), 27 faults of every
other kind packed a few seconds apart (three rounds, each a shuffle of every kind). Whatever the
faults, the shuttle hits nothing, the movement gate keeps its invariants, the black box loses no
second, every bad API request gets a 4xx, and every safety-relevant fault that found the shuttle
driving brought it to its safe state. How fast is docs/reliability.md's business, not a test's."""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time

import pytest

from ares.core.localhost import free_port
from ares.tools.soak.plan import kinds_for
from tests.helpers.stack import NO_LIDARS, REPO

pytestmark = [pytest.mark.stack, pytest.mark.whole_stack]

FAULTS = 27  # three rounds of the nine kinds a stack without LiDARs takes
SLOT_S = 4.0  # stack seconds per fault: the plan's least


STOP_AFTER = 12  # faults written down when the first segment is stopped (Ctrl-C), to be resumed


def soak(args: list[str], *, stop_after: int | None = None, out=None) -> subprocess.CompletedProcess:
    """`ares soak ARGS --json` with its own router and API ports; with stop_after, sent SIGINT (as
    Ctrl-C) once that many faults are written down in `out`."""
    command = [sys.executable, "-m", "ares.cli", "soak", *args, "--json"]
    command += ["--listen", f"tcp/127.0.0.1:{free_port()}", "--api-port", str(free_port())]
    proc = subprocess.Popen(
        command, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, stdin=subprocess.DEVNULL
    )
    try:
        if stop_after is not None:
            deadline = time.monotonic() + 400
            faults = out / "faults.jsonl"
            while proc.poll() is None and time.monotonic() < deadline:
                if faults.exists() and len(faults.read_text().splitlines()) >= stop_after:
                    proc.send_signal(signal.SIGINT)
                    break
                time.sleep(0.5)
        stdout, stderr = proc.communicate(timeout=460)
    finally:
        if proc.poll() is None:  # out of time: SIGINT lets the soak stop its stack (a SIGKILL would orphan it)
            proc.send_signal(signal.SIGINT)
            try:
                proc.communicate(timeout=60)
            except subprocess.TimeoutExpired:
                proc.kill()
    return subprocess.CompletedProcess(command, proc.returncode, stdout, stderr)


@pytest.mark.timeout(900)  # ~60 s on an idle machine; a busy one starts a dozen processes slowly
def test_a_short_soak_of_27_faults_stopped_and_resumed_hits_nothing_breaks_no_invariant_and_loses_no_second(
    tmp_path,
):
    out = tmp_path / "soak"
    hours = FAULTS * SLOT_S / 3600.0
    first = soak(
        ["--hours", f"{hours:.6f}", "--faults", str(FAULTS), "--seed", "7", "--lead", "5"]
        + ["--config", str(NO_LIDARS), "--out", str(out)],
        stop_after=STOP_AFTER,
        out=out,
    )
    # Ctrl-C: the stack stopped, the figures so far written down, not finished
    assert first.returncode == 1, f"exit {first.returncode}\n{first.stdout[-2000:]}\n{first.stderr[-3000:]}"
    stopped = json.loads(first.stdout.strip().splitlines()[-1])
    assert not stopped["finished"] and stopped["error"] == "interrupted"
    assert STOP_AFTER <= stopped["faults_injected"] < FAULTS
    # the rest, from where the shuttle stood: a segment of its own, then the figures of both
    second = soak(["--resume", str(out)])
    assert second.returncode == 0, f"exit {second.returncode}\n{second.stdout[-2000:]}\n{second.stderr[-3000:]}"
    summary = json.loads(second.stdout.strip().splitlines()[-1])
    assert summary["segments"] == 2 and summary["finished"]
    assert summary["faults_injected"] == FAULTS  # each fault once, a fault cut short by the stop injected again
    assert set(summary["per_kind"]) == set(kinds_for(False)), "every kind without LiDARs"
    assert summary["collisions"] == 0 and summary["invariant_violations"] == 0, summary["invariant_examples"]
    assert summary["blackbox_seconds_lost"] == 0, summary
    # every bad request the running API answered got a 4xx (none unanswered while it was up)
    assert summary["api_requests"] > 0 and summary["api_not_4xx"] == 0
    # a safety-relevant fault that found the shuttle driving normally brought it to its safe state
    assert summary["all"]["safety_relevant"] > 0 and summary["all"]["safe_state_missed"] == 0
    # and every fault was got over: each killed, hung or busy process restarted, the shuttle driving again
    assert summary["all"]["not_recovered"] == 0
    assert summary["availability"] is not None and 0.0 < summary["availability"] <= 1.0
    resumed = out / "segments" / "1"
    lines = [json.loads(line) for line in (resumed / "faults.jsonl").read_text().splitlines()]
    assert all(line["injected"] for line in lines) and len(lines) == FAULTS - summary["per_segment"][0]["faults_kept"]
    assert (resumed / "soak.png").stat().st_size > 10_000 and (out / "soak-all.png").stat().st_size > 10_000
    # the same figures from the directory alone
    again = subprocess.run(
        [sys.executable, "-m", "ares.cli", "soak", "--summarise", str(out), "--json"],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=60,
    )
    partial = json.loads(again.stdout.strip().splitlines()[-1])
    assert partial["faults_injected"] == summary["faults_injected"] and partial["blackbox_seconds_lost"] == 0
    # a soak run to its end is not resumed
    refused = subprocess.run(
        [sys.executable, "-m", "ares.cli", "soak", "--resume", str(out)], cwd=REPO, capture_output=True, text=True
    )
    assert refused.returncode == 1 and "nothing to resume" in refused.stderr
    print(
        f"\nshort soak in two segments: {summary['faults_injected']} faults in "
        f"{summary['vehicle_hours'] * 3600:.0f} s vehicle time, {summary['wall_hours'] * 3600:.0f} s wall; "
        f"max time to safe state {summary['time_to_safe_state_max_s']} s; availability {summary['availability']}"
    )
