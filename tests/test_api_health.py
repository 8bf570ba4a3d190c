"""GET /health answers anyone who reaches the port: the status only. A MongoDB store whose server
is gone (a real pymongo client at a loopback port nothing listens on) makes pymongo's error name
the servers it tried and their state; the answer carries none of it, the API's log does."""

from __future__ import annotations

import logging

from fastapi.testclient import TestClient

from ares.core.localhost import free_port
from blackbox.api import create_app
from blackbox.register.store.mongo_store import MongoStore
from blackbox.register.store.record_store import StoreSettings
from tests.helpers.api import VEHICLE_ID, api_settings


def test_an_unreachable_mongodb_is_reported_without_its_topology(caplog):
    port = free_port()
    timeouts = {"mongo_server_selection_timeout_ms": 300, "mongo_connect_timeout_ms": 300, "mongo_timeout_ms": 300}
    store = MongoStore(f"mongodb://127.0.0.1:{port}/", settings=StoreSettings(**timeouts))
    try:
        client = TestClient(create_app(store, api_settings(), VEHICLE_ID))
        with caplog.at_level(logging.WARNING, logger="blackbox.api.health"):
            r = client.get("/api/v1/health")
    finally:
        store.close()
    assert r.status_code == 503 and r.headers["retry-after"] == "5"
    assert r.json() == {"status": "degraded", "store": "unavailable", "detail": None}
    assert str(port) not in r.text and "127.0.0.1" not in r.text
    # the operator still learns why: pymongo's own account of the servers it tried, in the log
    assert f"127.0.0.1:{port}" in caplog.text
