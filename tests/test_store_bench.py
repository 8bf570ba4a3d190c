"""A small run of the black-box store bench: the figures are there and sane (no timing goals)."""

from __future__ import annotations

from ares.tools.bench.blackbox_store import GOALS, run_store_bench


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
    assert result["goals"] == GOALS
    assert any("ingest" in m for m in messages) and any("queries" in m for m in messages)
    assert list(tmp_path.iterdir()) == []  # the temporary store is gone
