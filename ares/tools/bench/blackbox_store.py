"""Benchmark of the embedded black-box store: ingest rate and the one-hour query.

- ingest_records_per_s: realistic VehicleRecord models (built beforehand, as the event register
  holds them) written with insert_records in batches of `batch`, into a fresh store file under
  a temporary directory; the time counted is insert_records' only (JSON encoding + SQLite);
- query_hour_p50_ms: median time of records_json(vehicle, start, start + 1 h, limit=3600) at
  random starting seconds, with `records_present` 1 Hz records of that vehicle in the store
  (default 7 days = 604,800, the retention window full): the hour as the JSON the API serves
  its record pages in. The same file is filled on after the ingest measurement, still through
  insert_records;
- query_hour_dicts_p50_ms: the same hour with records() as Python dicts (what the exports and
  the reliability figures iterate over).

Run: python -m ares.tools.bench.blackbox_store [--records N] [--queries N]
"""

from __future__ import annotations

import argparse
import json
import random
import sqlite3
import tempfile
import time
from collections.abc import Callable
from datetime import UTC, datetime, timedelta
from pathlib import Path

from ares.app.processes import for_run
from ares.core.messages import DriveMode, Position, ProcessHealth, ProcessState, SensorHealth, VehicleRecord
from ares.core.topics import TOPIC_TABLE
from ares.tools.bench.common import Goal, judge, percentile
from blackbox.register.recorder import SENSOR_TOPICS
from blackbox.register.store.record_store import RETENTION
from blackbox.register.store.sqlite_store import SqliteStore
from simulator.params import SimParams

GOALS = {"ingest_records_per_s": Goal(5000.0, at_least=True), "query_hour_p50_ms": Goal(20.0)}
VEHICLE = "shuttle01"
T0 = datetime(2026, 5, 1, tzinfo=UTC)  # first record of the bench's week

# what a record of a simulated run with the LiDARs lists, from the tables the stack runs on: every
# process (ares.app.processes), the sensors the recorder rates (blackbox.register.recorder.SENSOR_TOPICS) at
# the simulator's rates, the managers' scores (the topics with a `score`, ares.core.topics)
PROCESSES = [p.name for p in for_run(simulate=True, lidars=True)]
SENSORS = {name: float(getattr(SimParams(), f"{name}_hz")) for name in SENSOR_TOPICS}
SCORES = [t.score for t in TOPIC_TABLE if t.score is not None]


def realistic_records(vehicle_id: str, first: int, count: int, seed: int = 0) -> list[VehicleRecord]:
    """`count` consecutive 1 Hz records from second `first` after T0, with varying values.
    The fixed parts (sensors, processes) are shared and the rest assembled without validation
    (model_construct): building 600k fully validated models would dominate the bench's run
    time and is not what is measured."""
    rng = random.Random(seed + first)
    sensors = {name: SensorHealth(rate_hz=hz, ok=True) for name, hz in SENSORS.items()}
    processes = {name: ProcessHealth(state=ProcessState.RUNNING, restarts=rng.randint(0, 2)) for name in PROCESSES}
    out = []
    for i in range(first, first + count):
        x, y = 150.0 * rng.random(), 80.0 * rng.random()
        position = Position.model_construct(
            x=x,
            y=y,
            z=1.5 * rng.random(),
            easting=440000.0 + x,
            northing=4474000.0 + y,
            zone=30,
            hemisphere="N",
            lat=40.41 + y * 9e-6,
            lon=-3.71 + x * 1.2e-5,
        )
        out.append(
            VehicleRecord.model_construct(
                vehicle_id=vehicle_id,
                time=T0 + timedelta(seconds=i),
                t=float(i),
                position=position,
                speed_mps=4.0 * rng.random(),
                steering_wheel_deg=rng.uniform(-400.0, 400.0),
                mode=DriveMode.AUTOMATIC,
                scores={name: rng.random() for name in SCORES},
                controller=rng.choice(["mpc", "rrc"]),
                sensors=sensors,
                processes=processes,
                awareness_level=0,
                mission_state="NEXT_POI",
                events=rng.randint(0, 1),
            )
        )
    return out


def _ingest(store: SqliteStore, records: int, batch: int, seed: int) -> float:
    """Seconds insert_records took to write `records` fresh records in batches (building them
    not counted)."""
    elapsed = 0.0
    for first in range(0, records, batch):
        chunk = realistic_records(VEHICLE, first, min(batch, records - first), seed)
        started = time.perf_counter()
        store.insert_records(chunk)
        elapsed += time.perf_counter() - started
    return elapsed


def _fill(store: SqliteStore, first_record: int, records_present: int, batch: int, seed: int, say) -> float:
    """Seconds insert_records took to fill the store on up to `records_present` records."""
    started_fill = time.perf_counter()
    elapsed = 0.0
    step = max(records_present // 10, batch)
    next_report = first_record + step
    for first in range(first_record, records_present, batch):
        chunk = realistic_records(VEHICLE, first, min(batch, records_present - first), seed)
        started = time.perf_counter()
        store.insert_records(chunk)
        elapsed += time.perf_counter() - started
        if first + batch >= next_report:
            say(f"filling: {first + batch}/{records_present} records ({time.perf_counter() - started_fill:.0f} s)")
            next_report += step
    return elapsed


def _hour_queries(store: SqliteStore, records_present: int, queries: int, rng: random.Random) -> tuple[list, list]:
    """(ms of each hour as dicts, ms of each hour as JSON), at random starting seconds."""
    hour = min(3600, records_present)
    times_ms, json_times_ms = [], []
    for _ in range(queries):
        start = T0 + timedelta(seconds=rng.randrange(0, records_present - hour + 1))
        started = time.perf_counter()
        docs = store.records(VEHICLE, start, start + timedelta(hours=1), limit=3600)
        times_ms.append((time.perf_counter() - started) * 1000.0)
        if len(docs) != hour:
            raise RuntimeError(f"hour query returned {len(docs)} records, expected {hour}")
        del docs
        # the same hour as JSON bytes, for a handler that sends it on (no dicts built)
        start = T0 + timedelta(seconds=rng.randrange(0, records_present - hour + 1))
        started = time.perf_counter()
        raw = store.records_json(VEHICLE, start, start + timedelta(hours=1), limit=3600)
        json_times_ms.append((time.perf_counter() - started) * 1000.0)
        if raw.count(b'"vehicle_id"') != hour:
            raise RuntimeError(f"hour query (JSON) did not return {hour} records")
    return times_ms, json_times_ms


def run_store_bench(
    progress: Callable[[str], None] | None = None,
    *,
    records_present: int = 7 * 86400,
    ingest_records: int = 50_000,
    batch: int = 500,
    queries: int = 50,
    seed: int = 1,
    directory: str | None = None,
) -> dict:
    say = progress or (lambda _msg: None)
    ingest_records = min(ingest_records, records_present)
    rng = random.Random(seed)
    with tempfile.TemporaryDirectory(prefix="ares-store-bench-", dir=directory) as tmp:
        path = Path(tmp) / "blackbox.sqlite"
        # the clock puts the oldest record exactly at the retention edge: the purge run by the
        # inserts keeps all of them
        store = SqliteStore(str(path), now=lambda: T0 + RETENTION)
        try:
            say(f"ingest: {ingest_records} records in batches of {batch} into a fresh file")
            ingest_rate = ingest_records / _ingest(store, ingest_records, batch, seed)
            fill_elapsed = _fill(store, ingest_records, records_present, batch, seed, say)
            present = store.count_records(VEHICLE, T0, T0 + timedelta(seconds=records_present))
            say(f"queries: {queries} x one hour among {present} records")
            times_ms, json_times_ms = _hour_queries(store, records_present, queries, rng)
            record_bytes = len(realistic_records(VEHICLE, 0, 1, seed)[0].model_dump_json())
            file_mb = sum(p.stat().st_size for p in Path(tmp).iterdir()) / 2**20
        finally:
            store.close()
    result = {
        "ingest_records_per_s": round(ingest_rate, 1),
        "query_hour_p50_ms": percentile(json_times_ms, 50, 3),
        "query_hour_p95_ms": percentile(json_times_ms, 95, 3),
        "query_hour_dicts_p50_ms": percentile(times_ms, 50, 3),
        "fill_records_per_s": round((records_present - ingest_records) / fill_elapsed, 1) if fill_elapsed else None,
        "engine": f"sqlite {sqlite3.sqlite_version}",
        "records_present": present,
        "record_bytes": record_bytes,
        "file_mb": round(file_mb, 1),
        "batch": batch,
        "ingest_records": ingest_records,
        "queries": queries,
    }
    return judge(result, GOALS)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--records", type=int, default=7 * 86400, help="1 Hz records present for the queries")
    parser.add_argument("--ingest", type=int, default=50_000, help="records timed for the ingest rate")
    parser.add_argument("--queries", type=int, default=50)
    parser.add_argument("--dir", default=None, help="where the temporary store file goes")
    args = parser.parse_args()
    result = run_store_bench(
        lambda msg: print(msg, flush=True),
        records_present=args.records,
        ingest_records=args.ingest,
        queries=args.queries,
        directory=args.dir,
    )
    print(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
