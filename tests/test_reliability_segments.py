"""A window's reliability from pieces (the API's per-day cache): chaining the segments of any
split of a window gives exactly the tally of the whole window at once."""

from __future__ import annotations

import random
from datetime import UTC, datetime, timedelta

import pytest

from blackbox.register import reliability as rel

T0 = datetime(2026, 1, 1, tzinfo=UTC)


def at(s: float) -> datetime:
    return T0 + timedelta(seconds=s)


def random_history(rng: random.Random, seconds: int):
    """Records at 1 Hz with gaps, runs of up and down, and FAULT events here and there."""
    records, faults, up = [], [], True
    t = 0.0
    while t < seconds:
        if rng.random() < 0.03:
            up = not up
        if rng.random() < 0.02:
            t += rng.choice([1.5, 3.0, 40.0])  # the recorder missed some seconds
        mode = "AUTOMATIC" if up or rng.random() < 0.5 else "MANUAL"
        state = "running" if up else rng.choice(["running", "restarting"])
        records.append({"time": at(t), "mode": mode, "processes": {"controller": {"state": state}}})
        if rng.random() < 0.02:
            faults.append(at(t + rng.choice([0.0, 0.4, 1.7, 2.5])))
        t += 1.0
    return records, sorted(faults)


def pieces(records, faults, cuts: list[datetime]):
    bounds = [at(-10), *cuts, at(10**9)]
    for lo, hi in zip(bounds, bounds[1:], strict=False):
        yield (
            rel.segment(
                [r for r in records if lo <= r["time"] < hi],
                [f for f in faults if lo <= f < hi],
            )
        )


@pytest.mark.parametrize("seed", range(40))
def test_chained_segments_are_the_whole_window(seed):
    rng = random.Random(seed)
    records, faults = random_history(rng, 3000)
    until = at(3000 + rng.choice([0, 5, 100]))
    whole = rel.tally_window(records, faults, until=until)
    cuts = sorted(at(rng.uniform(0, 3000)) for _ in range(rng.randint(1, 12)))
    # a cut right after a record, a moment before a fault: the entry state decides that failure
    if faults:
        cuts = sorted({*cuts, faults[len(faults) // 2] - timedelta(milliseconds=1)})
    chained, count = rel.chain(pieces(records, faults, cuts), until=until)
    assert count == len(records)
    assert (chained.failures, chained.open_failures) == (whole.failures, whole.open_failures)
    assert chained.operating_s == pytest.approx(whole.operating_s)
    assert chained.repair_s == pytest.approx(whole.repair_s)


def test_an_outage_across_a_cut_is_one_failure_repaired_in_the_next_piece():
    up = {"mode": "AUTOMATIC", "processes": {}}
    down = {"mode": "MANUAL", "processes": {}}
    records = [{"time": at(s), **up} for s in range(10)]
    records += [{"time": at(s), **down} for s in range(10, 20)]
    records += [{"time": at(s), **up} for s in range(20, 30)]
    faults = [at(9.5), at(15)]
    for cut in (at(9.7), at(10), at(16), at(20)):
        tally, _ = rel.chain(pieces(records, faults, [cut]), until=at(30))
        assert (tally.failures, tally.repair_s, tally.operating_s) == (1, 10.5, 20.0), cut
    # the fault opens the next piece, its last up record the previous one's end
    tally, _ = rel.chain(pieces(records, faults, [at(9.2)]), until=at(30))
    assert (tally.failures, tally.repair_s) == (1, 10.5)
