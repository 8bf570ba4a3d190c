"""A small run of the black-box store bench: the figures are there and sane (no timing goals:
benchmarks measure, tests never assert a rate or a latency), and the records it stores are ones
the event register could have written."""

from __future__ import annotations

from ares.app.processes import by_name
from ares.core.messages import ProcessState, VehicleRecord
from ares.tools.bench.blackbox_store import realistic_records, run_store_bench
from blackbox.register.recorder import SENSOR_TOPICS, SensorMinimums


def test_store_bench_small_run(tmp_path):
    messages: list[str] = []
    result = run_store_bench(
        messages.append, records_present=7200, ingest_records=1500, batch=500, queries=3, directory=str(tmp_path)
    )
    assert result["records_present"] == 7200
    assert result["ingest_records_per_s"] > 0
    assert result["fill_records_per_s"] > 0
    assert 0 < result["query_hour_p50_ms"] <= result["query_hour_p95_ms"]
    assert result["query_hour_dicts_p50_ms"] > 0
    assert result["engine"].startswith("sqlite")
    assert 500 < result["record_bytes"] < 5000
    assert result["file_mb"] > 0
    assert any("ingest" in m for m in messages) and any("queries" in m for m in messages)
    assert list(tmp_path.iterdir()) == []  # the temporary store is gone


def test_the_bench_records_are_ones_the_event_register_could_write():
    records = realistic_records("shuttle01", 100, 3)
    minimums = SensorMinimums()
    for k, record in enumerate(records):
        # built without validation (model_construct): they must still pass it, unchanged
        assert VehicleRecord.model_validate(record.model_dump()) == record
        assert record.t == 100.0 + k
        # the sensors the recorder rates, each working, so at least at its minimum rate
        assert set(record.sensors) == set(SENSOR_TOPICS)
        for name, health in record.sensors.items():
            assert health.ok and health.rate_hz >= getattr(minimums, name), name
        # processes the supervisor runs (by_name raises on a name the process table lacks)
        assert all(by_name(name).name == name for name in record.processes)
        assert {"dbw_bridge", "movement_manager", "blackbox", "api"} <= set(record.processes)
        assert all(p.state == ProcessState.RUNNING for p in record.processes.values())
