"""The fleet's door (blackbox/fleet/door.py, blackbox/fleet/sync_node.py): one vehicle cannot stall or
crash the fleet's black box. A record stamped in 2100, an event at stack time 1e15, NaN, negative
times and ids that are no vehicle's are refused before the ledger and the store; the gap bookkeeping
costs the gaps and seconds a message touches, never the seconds a gap spans; and whatever payloads
arrive on the fleet's keys, the sync node's step never raises. A real fleet sync node, a real
SQLite store and the real bus encoding (the memory network) throughout."""

from __future__ import annotations

import json
import math
import threading
import time
from datetime import UTC, datetime

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from ares.app import run_config
from ares.core import config
from ares.core.bus import encoding_name
from ares.core.clock import ManualClock
from ares.core.membus import MemoryNetwork
from ares.core.messages import BlackboxRecord, Event, VehicleRecord
from blackbox.fleet.door import StampWindow
from blackbox.fleet.sync import FleetLedger, FleetSyncParams, epoch_of
from blackbox.fleet.sync_node import FleetSync
from blackbox.register.store.sqlite_store import SqliteStore
from tests.helpers.stack import NO_LIDARS

WALL = float(int(time.time()))  # the fleet's wall, fixed: every stamp is judged against it
VEHICLE = "shuttle01"
PAST, FUTURE = datetime(1, 1, 2, tzinfo=UTC), datetime(9999, 12, 30, tzinfo=UTC)
IN_2100 = datetime(2100, 1, 1, tzinfo=UTC)
RECORD_KEY, EVENTS_KEY = f"ares/{VEHICLE}/blackbox/record", f"ares/{VEHICLE}/events"


class Fleet:
    """A fleet sync node on a memory network with its own store, and a vehicle's bus to send from."""

    def __init__(self, tmp_path):
        self.store_path = tmp_path / "fleet.sqlite"
        cfg = run_config.build(
            (str(NO_LIDARS),),
            config.deep_merge({"vehicle_id": "fleet"}, {"blackbox_store": {"uri": str(self.store_path)}}),
        )
        self.clock = ManualClock(utc_epoch=WALL)
        self.network = MemoryNetwork("fleet")
        self.sync = FleetSync(cfg, clock=self.clock, bus=self.network.bus("fleet_sync", self.clock, vehicle_id="fleet"))
        self.sync.setup()
        self.sync.wall = lambda: WALL + self.clock.now()
        self.vehicle = self.network.bus("blackbox", self.clock, vehicle_id=VEHICLE)

    def step(self) -> None:
        self.clock.advance(0.2)
        self.sync.step_once(self.clock.now())

    def record(self, time: datetime, t: float, vehicle_id: str = VEHICLE) -> None:
        record = VehicleRecord(vehicle_id=vehicle_id, time=time, t=t)
        self.vehicle.publish("blackbox/record", BlackboxRecord(t=t, record=record))

    def put_raw(self, key: str, schema: type, body: dict) -> None:
        """A payload as any publisher could put it: NaN and all, past the schema's constructor."""
        self.network.put(key, encoding_name(schema), json.dumps(body).encode())

    def close(self) -> tuple[list[int], list[dict]]:
        """Stop the node (its writer flushes) and read back what the fleet's store holds: every
        vehicle's seconds, and its events with the fleet's own (two steps: the fleet's own events
        come back to it on the bus, to be stored)."""
        self.step()
        self.step()
        self.sync.teardown()
        self.sync.bus.close()
        store = SqliteStore(str(self.store_path))
        seconds, events = [], []
        try:
            for vehicle_id in sorted(store.vehicles()):
                rows = store.records(vehicle_id, PAST, FUTURE, limit=100_000)
                seconds += [int(epoch_of(r["time"])) for r in rows]
            for vehicle_id in (VEHICLE, "fleet"):
                events += store.events(vehicle_id, PAST, FUTURE, limit=100_000)
        finally:
            store.close()
        return seconds, events


def _at(epoch_s: float) -> datetime:
    return datetime.fromtimestamp(epoch_s, UTC)


def test_a_record_stamped_in_2100_is_refused_and_the_seconds_after_it_are_kept(tmp_path):
    fleet = Fleet(tmp_path)
    fleet.record(_at(WALL), 0.0)
    fleet.step()
    fleet.record(IN_2100, 1.0)
    fleet.step()
    fleet.record(_at(WALL + 3), 3.0)  # two seconds lost on the link: a gap of 2, not of 74 years
    fleet.step()
    ledger = fleet.sync.ledger.vehicle(VEHICLE)
    assert ledger.newest == int(WALL) + 3 and ledger.gaps == [[int(WALL) + 1, int(WALL) + 3]]
    seconds, events = fleet.close()
    assert seconds == [int(WALL), int(WALL) + 3]
    refused = [e for e in events if e["kind"] == "fleet_record_refused"]
    assert [(e["data"]["cause"], e["data"]["refused"]) for e in refused] == [("record time", 1)]
    assert "ahead of the fleet's clock" in refused[0]["message"]


def test_an_event_at_stack_time_1e15_or_minus_1e15_is_refused_and_the_step_does_not_raise(tmp_path):
    fleet = Fleet(tmp_path)
    fleet.record(_at(WALL), 0.0)  # the vehicle's clock: its stack time 0 is the wall's now
    fleet.step()
    for t in (1e15, -1e15, 5.0):
        fleet.vehicle.publish("events", Event(t=t, source="mpc", kind="probe", message=f"at {t}"))
    fleet.step()
    _, events = fleet.close()
    assert [e["message"] for e in events if e["kind"] == "probe"] == ["at 5.0"]
    refused = [e for e in events if e["kind"] == "fleet_record_refused"]
    assert [(e["data"]["cause"], e["data"]["refused"]) for e in refused] == [("event time", 2)]


def test_nan_negative_and_out_of_range_stamps_never_reach_the_store(tmp_path):
    fleet = Fleet(tmp_path)
    good = {"vehicle_id": VEHICLE, "time": _at(WALL).isoformat(), "t": 0.0}
    for record in (
        {**good, "t": math.nan},  # the schema refuses NaN
        {**good, "time": "1969-12-31T23:59:59+00:00"},  # the door: older than the store keeps
        {**good, "time": "0001-01-01T00:00:00+14:00"},  # a time with no epoch second
        {**good, "time": "9999-12-31T23:59:59-14:00"},
    ):
        fleet.put_raw(RECORD_KEY, BlackboxRecord, {"t": 0.0, "record": record})
        fleet.step()
    fleet.put_raw(EVENTS_KEY, Event, {"t": math.nan, "source": "x", "kind": "probe", "message": "nan"})
    fleet.put_raw(EVENTS_KEY, Event, {"t": math.inf, "source": "x", "kind": "probe", "message": "inf"})
    fleet.step()
    assert fleet.sync.ledger.vehicle(VEHICLE).newest is None
    seconds, events = fleet.close()
    assert seconds == [] and [e for e in events if e["kind"] == "probe"] == []
    assert fleet.sync.refusals.totals == {(VEHICLE, "record time"): 3}
    assert [e["data"]["cause"] for e in events if e["kind"] == "fleet_record_refused"] == [
        "record time"
    ]  # reported once
    assert fleet.sync.bus.rejects.by_reason  # the others never passed the bus's schema check


def test_ids_that_are_no_vehicles_are_refused(tmp_path):
    fleet = Fleet(tmp_path)
    good = {"vehicle_id": VEHICLE, "time": _at(WALL).isoformat(), "t": 0.0}
    for vehicle_id in ("../../etc", "", "x" * 65, "shuttle 01"):  # not one key segment: the schema refuses
        fleet.put_raw(RECORD_KEY, BlackboxRecord, {"t": 0.0, "record": {**good, "vehicle_id": vehicle_id}})
    fleet.put_raw("ares/bad id!/blackbox/record", BlackboxRecord, {"t": 0.0, "record": good})  # the bus refuses
    fleet.record(_at(WALL), 0.0, vehicle_id="shuttle02")  # a valid id, not the key's: the door refuses
    fleet.step()
    assert fleet.sync.ledger.vehicles.keys() == {VEHICLE}  # heard (its key), nothing taken
    assert fleet.sync.ledger.vehicle(VEHICLE).newest is None
    seconds, events = fleet.close()
    assert seconds == []
    refused = {e["data"]["cause"]: e["data"]["refused"] for e in events if e["kind"] == "fleet_record_refused"}
    assert refused == {"record of another vehicle": 1}


def test_a_gap_of_74_years_costs_the_ledger_no_more_than_a_gap_of_two_seconds():
    """Before the door, and for the seconds inside its window: filling a second of a long gap
    walks the gaps, not the seconds in them."""
    ledger = FleetLedger(FleetSyncParams())
    ledger.heard("v", 0.0)
    start, far = int(WALL), int(IN_2100.timestamp())
    done = threading.Event()

    def bookkeeping() -> None:
        ledger.record("v", start, 0.0)
        ledger.record("v", far, 1.0)
        for k in range(1, 201):  # live seconds inside the long gap
            ledger.record("v", start + 2 * k, 2.0 * k)
        done.set()

    worker = threading.Thread(target=bookkeeping, daemon=True)
    began = time.perf_counter()
    worker.start()
    assert done.wait(10.0), "the ledger walks every second of a gap"
    assert time.perf_counter() - began < 1.0
    gaps = ledger.vehicle("v").gaps
    assert len(gaps) == 201 and gaps[0] == [start + 1, start + 2] and gaps[-1] == [start + 401, far]
    assert ledger.open_seconds("v") == far - start - 1 - 200


def test_the_window_refuses_what_no_clock_of_the_fleet_could_say():
    window = StampWindow(oldest_s=3600.0, future_tolerance_s=300.0)
    assert window.why_refused(WALL, WALL) is None
    assert window.why_refused(WALL + 299, WALL) is None and window.why_refused(WALL - 3599, WALL) is None
    for stamp in (math.nan, math.inf, -math.inf, WALL + 301, WALL - 3601, -1.0, 1e15):
        assert window.why_refused(stamp, WALL) is not None, stamp


# ---- whatever arrives, the step never raises ------------------------------------------------------

_ids = st.one_of(st.sampled_from([VEHICLE, "shuttle02", "fleet"]), st.text(max_size=70))
_floats = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.floats(-10.0, 10_000.0),
    st.sampled_from([0.0, 1e15, -1e15, 1e308]),
)
_times = st.one_of(
    st.integers(-20_000, 20_000).map(lambda d: _at(WALL + d).isoformat()),  # around the window's edges
    st.datetimes(timezones=st.none() | st.timezones()).map(lambda d: d.isoformat()),
    st.text(max_size=30),
)
_records = st.fixed_dictionaries({"vehicle_id": _ids, "time": _times, "t": _floats})
_events = st.fixed_dictionaries(
    {"t": _floats, "source": st.text(max_size=20), "kind": st.text(max_size=20), "message": st.text(max_size=50)}
)
_payloads = st.one_of(
    st.tuples(st.just("blackbox/record"), st.builds(lambda r, t: {"t": t, "record": r}, _records, _floats)),
    st.tuples(st.just("events"), _events),
    st.tuples(st.sampled_from(["blackbox/record", "events"]), st.binary(max_size=40)),
)
_arrivals = st.lists(st.tuples(_ids.filter(lambda v: "/" not in v and "*" not in v), _payloads), max_size=25)
_answers = st.lists(st.lists(_records, max_size=6), max_size=4)


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    arrivals=_arrivals,
    answers=_answers,
    oldest=st.none() | st.integers(-(2**62), 2**62),
    complete_to=st.none() | st.integers(-(2**62), 2**62),
)
def test_no_payload_on_the_fleets_keys_and_no_recorders_answer_makes_the_step_raise(
    tmp_path_factory, arrivals, answers, oldest, complete_to
):
    fleet = Fleet(tmp_path_factory.mktemp("fleet"))
    try:
        for vehicle_id, (topic, body) in arrivals:
            schema = BlackboxRecord if topic == "blackbox/record" else Event
            payload = body if isinstance(body, bytes) else json.dumps(body).encode()
            fleet.network.put(f"ares/{vehicle_id}/{topic}", encoding_name(schema), payload)
            fleet.step()
        ledger = fleet.sync.ledger
        for batch in answers:
            # a recorder's answer, as the bus gives it: whatever passes the schema, to the range in flight
            records = []
            for body in batch:
                try:
                    records.append(VehicleRecord.model_validate(body))
                except ValueError:
                    continue
            for vehicle_id, state in ledger.vehicles.items():
                if state.in_flight is None and state.gaps:
                    state.in_flight = (state.gaps[0][0], state.gaps[0][1])
                fleet.sync.answers.put((vehicle_id, records, oldest, complete_to, ""))
            fleet.step()
        window = fleet.sync.window
        for state in ledger.vehicles.values():
            assert all(a < b for a, b in state.gaps)  # disjoint, oldest first, none empty
            assert all(prev[1] <= nxt[0] for prev, nxt in zip(state.gaps, state.gaps[1:]))
            assert state.newest is None or window.why_refused(state.newest, fleet.sync.wall()) is None
    finally:
        seconds, events = fleet.close()
    p = fleet.sync.params
    for k in seconds:  # the store took only what the window allowed when each arrived
        assert WALL - p.oldest_accepted_s - 1 <= k <= WALL + fleet.clock.now() + p.future_tolerance_s
    assert all(isinstance(e["message"], str) for e in events)
