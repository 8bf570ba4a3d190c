"""The vehicle router's per-process access control, made from the contracts (ares/deploy/local_acl.py):
every key a contract declares is allowed to its process, and a key no contract declares to no one."""

from __future__ import annotations

from ares.app import contracts
from ares.core import config
from ares.deploy import local_acl


def _allowed(rules: list[dict], process: str, kind: str) -> set[str]:
    return {k for r in rules if r["id"] == f"{process}_{kind}" for k in r["key_exprs"]}


def test_every_declared_output_and_service_is_allowed_to_its_process():
    cfg = config.core_defaults()
    rules = local_acl.rules(cfg)
    for c in contracts.all_contracts(cfg):
        puts = _allowed(rules, c["process"], "put")
        assert {f"ares/*/{o['topic']}" for o in c["outputs"]} <= puts
        assert f"ares/*/heartbeat/{c['process']}" in puts and "ares/*/events" in puts
        assert {f"ares/*/srv/{s['name']}" for s in c["services"]} <= _allowed(rules, c["process"], "serve")
        assert {f"ares/*/srv/{name}" for name in c["calls"]} <= _allowed(rules, c["process"], "call")
        assert _allowed(rules, c["process"], "alive") == {f"ares/*/alive/{c['process']}"}


def test_the_api_may_neither_command_the_car_nor_serve_a_mission():
    rules = local_acl.rules(config.core_defaults())
    assert "ares/*/control/setpoint" not in _allowed(rules, "api", "put")
    assert not any(k.startswith("ares/*/dbw/") for k in _allowed(rules, "api", "put"))
    assert "ares/*/srv/mission/goal" not in _allowed(rules, "api", "serve")
    assert "ares/*/srv/mission/goal" in _allowed(rules, "api", "call")


def test_a_key_no_contract_declares_is_allowed_to_no_one():
    rules = local_acl.rules(config.core_defaults())
    # the taps read everything; every process is told of every subscriber (declarations only)
    every_key = {
        k
        for r in rules
        if not r["id"].endswith(("_tap", "_tap_back")) and r["id"] != local_acl.SUBSCRIBERS_DECLARED
        for k in r["key_exprs"]
    }
    assert "ares/*/probe/acl" not in every_key and "**" not in every_key
    assert all(k.startswith("ares/*/") and "**" not in k for k in every_key)


def test_each_process_of_the_table_has_its_own_password_on_its_router(tmp_path):
    from ares.app.processes import PROCESSES
    from ares.deploy import pki

    issued = pki.issue_vehicle(tmp_path / "ca", "shuttle01", ["localhost"])
    users = pki.read_users(issued.vehicle_dir / "zenoh_local_users")
    assert {p.name for p in PROCESSES} | {"supervisor", "observer"} <= set(users)
    assert len(set(users.values())) == len(users)  # no two processes share a password
    assert set(users) <= set(local_acl.rule_ids(config.core_defaults())) | {"vehicle"}


def test_the_supervisor_reads_every_key_but_puts_and_calls_only_its_own():
    rules = local_acl.rules(config.core_defaults())
    assert _allowed(rules, "supervisor", "tap") == {"ares/*/**"}  # ares run --record / --foxglove
    assert _allowed(rules, "supervisor", "put") == {
        f"ares/*/{t}" for t in ("supervisor/state", "events", "heartbeat/supervisor")
    }
    assert _allowed(rules, "supervisor", "call") == {"ares/*/srv/sim/driver", "ares/*/srv/set_automatic_mode"}
    assert {m for r in rules if r["id"].startswith("supervisor_tap") for m in r["messages"]} == {
        "declare_subscriber",
        "put",
        "delete",
    }
    assert [r["flows"] for r in rules if r["id"] == "supervisor_tap_back"] == [["egress"]]
