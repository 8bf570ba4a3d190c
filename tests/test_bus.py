"""ares.core.bus over a real router subprocess (`python -m ares.app.embedded_router`), with Bus instances in the
test process (each its own Zenoh session) and, for liveliness, a node subprocess."""

from __future__ import annotations

import json
import math
import os
import signal
import threading
import time

import numpy as np
import pydantic
import pytest
import zenoh

from ares.core.bus import Bus, ServiceError, encoding_name
from ares.core.messages import (
    Ack,
    DriverCommand,
    Event,
    GnssSentences,
    Heartbeat,
    PointCloud,
    ServiceErrorReply,
    SupervisorState,
)

pytestmark = pytest.mark.timeout(60)


def wait_until(cond, timeout_s: float = 5.0, what: str = "") -> float:
    started = time.monotonic()
    while not cond():
        if time.monotonic() - started > timeout_s:
            raise AssertionError(f"timed out after {timeout_s} s waiting for {what or cond}")
        time.sleep(0.01)
    return time.monotonic() - started


@pytest.fixture
def buses(router):
    """make(name) -> a Bus connected to the test router; all closed at teardown."""
    made: list[Bus] = []

    def make(name: str, **kw) -> Bus:
        bus = Bus(router, name, **kw)
        made.append(bus)
        return bus

    yield make
    for bus in made:
        bus.close()


def connected(pub: Bus, sub, topic: str, make_msg) -> None:
    """Publish until the subscriber has seen one message: declarations take a moment to
    propagate through the router, and tests must not depend on a sleep being long enough."""

    def probe() -> bool:
        pub.publish(topic, make_msg())
        time.sleep(0.02)
        return sub.count > 0

    wait_until(probe, what=f"{topic} to connect")


def hb(process: str = "p", seq: int = 0) -> Heartbeat:
    return Heartbeat(t=1.0, process=process, seq=seq, pid=123, wall=time.time())


def test_pub_sub_round_trip_with_schema(buses):
    alice, bob = buses("alice"), buses("bob")
    sub = bob.subscribe("heartbeat/*", queue=50)
    connected(alice, sub, "heartbeat/alice", lambda: hb("alice"))
    sub.drain()
    received_before = sub.count
    sent = [hb("alice", seq) for seq in range(10)]
    for msg in sent:
        alice.publish("heartbeat/alice", msg)
    wait_until(lambda: sub.count >= received_before + 10, what="10 heartbeats")
    got = sub.drain()
    assert [topic for topic, _ in got] == ["heartbeat/alice"] * 10
    assert [m for _, m in got] == sent  # equal values, validated as Heartbeat
    assert all(isinstance(m, Heartbeat) for _, m in got)
    assert bob.rejects.total == 0
    # the publisher side checks the schema too
    with pytest.raises(TypeError):
        alice.publish("heartbeat/alice", Event(source="x", kind="y", message="z"))
    with pytest.raises(KeyError):
        alice.publish("no/such/topic", hb())
    with pytest.raises(pydantic.ValidationError):
        Heartbeat(process="p", seq=-1, pid=1, wall=0.0)


def test_corrupt_messages_are_rejected_counted_and_harmless(buses):
    sender, receiver = buses("sender"), buses("receiver")
    hb_sub = receiver.subscribe("heartbeat/*", queue=50)
    sensors = receiver.subscribe("sensors/*", queue=50)  # a pattern spanning several schemas
    connected(sender, hb_sub, "heartbeat/s", lambda: hb("s"))
    connected(sender, sensors, "sensors/gnss", lambda: GnssSentences(sentences=["$GPGGA"]))
    hb_sub.drain()
    sensors.drain()
    before = dict(receiver.rejects.by_reason)
    hb_before, sensors_before = hb_sub.count, sensors.count  # counts are cumulative: drain() does not reset them

    key = sender.key("heartbeat/s")
    as_hb = zenoh.Encoding(encoding_name(Heartbeat))
    good = json.loads(hb("s", 7).model_dump_json())
    raw_put = sender.session.put
    raw_put(key, b"{not json", encoding=as_hb)  # bad JSON
    raw_put(key, json.dumps({**good, "seq": "seven"}).encode(), encoding=as_hb)  # wrong type
    raw_put(key, json.dumps({**good, "wall": math.nan}).encode(), encoding=as_hb)  # NaN
    raw_put(key, json.dumps({**good, "extra": 1}).encode(), encoding=as_hb)  # extra field
    raw_put(key, json.dumps({k: v for k, v in good.items() if k != "pid"}).encode(), encoding=as_hb)  # missing
    raw_put(key, json.dumps(good).encode(), encoding=zenoh.Encoding(encoding_name(Event)))  # wrong schema name
    raw_put(sender.key("sensors/lidar_raw"), b"{}", encoding=zenoh.Encoding.APPLICATION_JSON)  # no such topic
    # ... and good messages afterwards still arrive
    sender.publish("heartbeat/s", hb("s", 8))
    sender.publish("sensors/gnss", GnssSentences(sentences=["$GPRMC"]))
    wait_until(
        lambda: (
            hb_sub.count > hb_before
            and sensors.count > sensors_before
            and receiver.rejects.total - sum(before.values()) >= 7
        ),
        what="the good messages after the bad ones",
    )
    added = {k: v - before.get(k, 0) for k, v in receiver.rejects.by_reason.items() if v - before.get(k, 0)}
    assert added == {"malformed": 5, "unknown schema": 1, "unknown topic": 1}
    # (a connection probe still in flight may land after the drain above: probes are seq 0 / $GPGGA)
    assert [m.seq for _, m in hb_sub.drain() if m.seq != 0] == [8]
    assert [m.sentences for _, m in sensors.drain() if m.sentences != ["$GPGGA"]] == [["$GPRMC"]]
    assert hb_sub.latest.seq == 8
    # the receiver keeps going: many more bad messages, then one more good one
    for _ in range(50):
        raw_put(key, b"\xff\xfe garbage", encoding=as_hb)
    sender.publish("heartbeat/s", hb("s", 9))
    wait_until(lambda: hb_sub.latest.seq == 9, what="a good message after 50 bad ones")
    assert receiver.rejects.by_reason["malformed"] - before.get("malformed", 0) == 55


@pytest.fixture
def driver_service(buses):
    """A Bus serving sim/driver, answered by a polling thread like a node's loop would."""
    server = buses("sim")
    calls: list[DriverCommand] = []

    def handle(req: DriverCommand) -> Ack:
        calls.append(req)
        if req.action == "STEER" and req.value > 720:
            raise ValueError("steering wheel angle out of range")
        return Ack(ok=True, detail=f"{req.action} {req.value:g}")

    server.serve("sim/driver", handle)
    stop = threading.Event()

    def loop() -> None:
        while not stop.is_set():
            server.poll_services()
            time.sleep(0.005)

    thread = threading.Thread(target=loop, daemon=True)
    thread.start()
    yield calls
    stop.set()
    thread.join(2)


def call_until_served(bus: Bus, name: str, request) -> object:
    """The first call may race the queryable's declaration reaching us through the router."""
    deadline = time.monotonic() + 5
    while True:
        try:
            return bus.call(name, request)
        except ServiceError as exc:
            if "no process offers" not in exc.reason or time.monotonic() > deadline:
                raise
            time.sleep(0.05)


def test_service_call_is_answered_via_poll_services(buses, driver_service):
    client = buses("cli")
    reply = call_until_served(client, "sim/driver", DriverCommand(action="BRAKE", value=0.5))
    assert isinstance(reply, Ack) and reply.ok and reply.detail == "BRAKE 0.5"
    assert driver_service[-1] == DriverCommand(action="BRAKE", value=0.5)
    # a handler that fails gives the caller a clear error, and the service goes on
    with pytest.raises(ServiceError, match="handler failed.*out of range") as err:
        client.call("sim/driver", DriverCommand(action="STEER", value=900))
    assert err.value.service == "sim/driver"
    assert client.call("sim/driver", DriverCommand(action="RELEASE")).ok
    # the caller cannot send a request of the wrong schema either
    with pytest.raises(ServiceError, match="request must be DriverCommand"):
        client.call("sim/driver", Ack(ok=True))
    with pytest.raises(ServiceError, match="unknown service"):
        client.call("no_such_service")


def test_invalid_request_gets_an_error_reply(buses, driver_service):
    client = buses("cli")
    call_until_served(client, "sim/driver", DriverCommand(action="RELEASE"))
    served = len(driver_service)
    for payload in (b'{"action": "FLY"}', b"{oops", b'{"action": "BRAKE", "value": NaN}'):
        replies = list(client.session.get(client.key("srv/sim/driver"), payload=payload, timeout=2.0))
        assert len(replies) == 1 and replies[0].ok is None
        err = ServiceErrorReply.model_validate_json(replies[0].err.payload.to_bytes())
        assert err.error == "invalid request" and err.detail
    assert len(driver_service) == served  # the handler never saw them
    assert client.call("sim/driver", DriverCommand(action="BUTTON")).ok


def test_call_to_a_missing_process_fails_at_once(buses):
    client = buses("cli")
    started = time.monotonic()
    with pytest.raises(ServiceError, match="no process offers this service") as err:
        client.call("supervisor/status", timeout_s=3.0)
    took = time.monotonic() - started
    assert took < 0.9 * 3.0, f"took {took:.2f} s: it waited for the timeout instead of failing at once"
    assert err.value.service == "supervisor/status"


def test_call_to_a_hung_process_times_out(buses):
    hung, client = buses("hung"), buses("cli")
    hung.serve("supervisor/status", lambda req: SupervisorState(processes=[]))  # never polled
    timeout_s = 1.0
    deadline = time.monotonic() + 5
    while True:  # until the queryable is known here, a call fails at once instead
        started = time.monotonic()
        try:
            client.call("supervisor/status", timeout_s=timeout_s)
        except ServiceError as exc:
            took = time.monotonic() - started
            if "no process offers" in exc.reason and time.monotonic() < deadline:
                time.sleep(0.05)
                continue
            assert exc.reason == "no reply within 1.0 s (process dead or hung?)"
            break
        raise AssertionError("a process that never polls answered")
    assert took >= timeout_s * 0.9, f"took {took:.2f} s: it did not wait for the reply"

    # once it polls again it answers (requests its callers gave up on are dropped)
    stop = threading.Event()

    def loop() -> None:
        while not stop.is_set():
            hung.poll_services()
            time.sleep(0.005)

    poller = threading.Thread(target=loop)
    poller.start()
    try:
        assert isinstance(client.call("supervisor/status"), SupervisorState)
    finally:
        stop.set()
        poller.join()


def test_liveliness_tokens_appear_and_disappear(buses, spawn_node):
    watcher = buses("watcher")
    changes: list[tuple[float, str, bool]] = []
    watch = watcher.watch_alive(lambda name, alive: changes.append((time.monotonic(), name, alive)))
    # a Bus in this process
    other = buses("other")
    other.declare_alive()
    wait_until(lambda: ("other", True) in [(n, a) for _, n, a in changes], what="token of other")
    # a liveliness query from a peer now and then comes back empty at once (zenoh 1.10, seen
    # with back-to-back queries): ask until it answers, within a bound
    wait_until(lambda: "other" in watcher.alive_processes(), timeout_s=3, what="other in alive_processes()")
    other.close()
    wait_until(lambda: ("other", False) in [(n, a) for _, n, a in changes], what="other's token gone")
    assert "other" not in watcher.alive_processes()
    # a node subprocess killed with SIGKILL: its token disappears at once
    node = spawn_node("ares.tools.bench.ticker:Ticker", "tick")
    wait_until(lambda: ("tick", True) in [(n, a) for _, n, a in changes], timeout_s=10, what="token of tick")
    killed_at = time.monotonic()
    os.kill(node.pid, signal.SIGKILL)
    wait_until(lambda: ("tick", False) in [(n, a) for _, n, a in changes], timeout_s=3, what="tick's token gone")
    gone_at = next(t for t, n, a in changes if n == "tick" and not a)
    # at once: with the process's session, not after the lease ran out (that would be >= 1.5 s)
    assert gone_at - killed_at < 1.4
    assert "tick" not in watcher.alive_processes()
    del watch


def test_a_point_cloud_crosses_the_bus_as_raw_arrays(buses):
    """Bulk topics: a header plus the arrays' bytes, received as views of the payload."""
    lidar, perception = buses("lidar"), buses("perception")
    clouds = perception.subscribe("lidar/roof/points", queue=4)
    n = 131_072
    rng = np.random.default_rng(0)
    sent = PointCloud(
        t=1.5,
        sensor="roof",
        frame="lidar_roof",
        x=rng.normal(size=n).astype("<f4"),
        y=rng.normal(size=n).astype("<f4"),
        z=rng.normal(size=n).astype("<f4"),
        intensity=rng.random(n, dtype=np.float32),
        ring=(np.arange(n) % 64).astype("u1"),
    )
    connected(lidar, clouds, "lidar/roof/points", lambda: sent)
    got = clouds.drain()[-1][1]
    assert got.t == 1.5 and got.sensor == "roof" and got.size == n
    for name in ("x", "y", "z", "intensity", "ring"):
        assert np.array_equal(getattr(got, name), getattr(sent, name))
        assert not getattr(got, name).flags.writeable  # a view of the received bytes, not a copy
    assert perception.rejects.total == 0


def test_a_flooded_service_refuses_at_once_and_forgets_abandoned_requests(buses):
    """The queryable's inbox is filled on Zenoh's thread, which must never block: past its
    capacity a request gets a "busy" error reply at once; requests older than the call timeout
    are dropped, because their callers have given up."""
    from ares.core.bus import SERVICE_INBOX_CAPACITY

    hung, client = buses("hung"), buses("cli")
    hung.serve("supervisor/status", lambda req: SupervisorState(processes=[]))
    inbox = hung._services[0][1]
    key = client.key("srv/supervisor/status")

    def a_probe_reaches_the_inbox() -> bool:
        # on a loaded machine the queryable's declaration takes a while to reach the client
        client.session.get(key, payload=b"{}", timeout=0.5)
        time.sleep(0.05)
        return inbox.waiting > 0

    wait_until(a_probe_reaches_the_inbox, what="the service to be reachable")
    while inbox.take() is not None:  # the probes queued requests (left unanswered): start from an empty inbox
        pass
    expired_before = inbox.expired  # a probe may have waited past the callers' timeout
    pending = [client.session.get(key, payload=b"{}", timeout=3.0) for _ in range(SERVICE_INBOX_CAPACITY + 6)]
    wait_until(lambda: inbox.refused >= 6, what="the overflow to be refused")
    busy = []
    for replies in pending[SERVICE_INBOX_CAPACITY:]:
        reply = next(iter(replies))
        busy.append(ServiceErrorReply.model_validate_json(reply.err.payload.to_bytes()).error)
    assert busy == ["busy"] * 6
    assert inbox.waiting == SERVICE_INBOX_CAPACITY

    inbox.max_wait_s = 0.0  # every queued caller has (as far as the inbox knows) given up
    time.sleep(0.01)
    assert hung.poll_services() == 0 and inbox.expired - expired_before == SERVICE_INBOX_CAPACITY


def test_a_router_that_asks_for_credentials(run_config, tmp_path):
    """A deployment's router (docs/deploy.md) asks every link for a user and a password: the bus
    gives them from bus.user and the file bus.password_file; without them it is refused."""
    from ares.core.bus import BusError
    from ares.core.localhost import free_port

    port = free_port()
    (tmp_path / "users").write_text("vehicle:s3cret-enough\n")
    (tmp_path / "password").write_text("s3cret-enough\n")
    router_cfg = {
        "mode": "router",
        "listen": {"endpoints": [f"tcp/127.0.0.1:{port}"]},
        "scouting": {"multicast": {"enabled": False}},
        "transport": {"auth": {"usrpwd": {"dictionary_file": str(tmp_path / "users")}}},
    }
    router = zenoh.open(zenoh.Config.from_json5(json.dumps(router_cfg)))
    made: list[Bus] = []
    try:
        cfg = {**run_config, "bus": {**run_config["bus"], "router": f"tcp/127.0.0.1:{port}"}}
        with pytest.raises(zenoh.ZError):
            Bus(cfg, "anonymous", mode="client")
        logged_in = {
            **cfg,
            "bus": {**cfg["bus"], "mode": "client", "user": "vehicle", "password_file": str(tmp_path / "password")},
        }
        made += [Bus(logged_in, "pub", mode="client"), Bus(logged_in, "sub", mode="client")]
        sub = made[1].subscribe("heartbeat/*", queue=50)
        connected(made[0], sub, "heartbeat/pub", lambda: hb("pub"))
        missing = {**cfg, "bus": {**logged_in["bus"], "password_file": str(tmp_path / "no-such-file")}}
        with pytest.raises(BusError, match="no-such-file"):
            Bus(missing, "lost", mode="client")
    finally:
        for bus in made:
            bus.close()
        router.close()


def test_user_and_password_file_come_together():
    from ares.core.config.run import BusSettings

    with pytest.raises(pydantic.ValidationError, match="both user and password_file"):
        BusSettings(user="vehicle")
    with pytest.raises(pydantic.ValidationError, match="both user and password_file"):
        BusSettings(password_file="/run/secrets/x")
    # peers would link to each other past the router that checks the credentials (and be refused)
    with pytest.raises(pydantic.ValidationError, match="set mode: client"):
        BusSettings(user="vehicle", password_file="/run/secrets/x")
    assert BusSettings(user="vehicle", password_file="/run/secrets/x", mode="client").mode == "client"


def test_each_process_logs_in_with_its_own_line_of_the_credentials_file(run_config, tmp_path):
    """bus.credentials_file (one compose secret for a stack's container): each process logs in as its
    own name with its line; a process without a line is told so, naming the file; a wrong password
    on a line is refused by the router."""
    from ares.core.bus import BusError
    from ares.core.localhost import free_port

    port = free_port()
    (tmp_path / "users").write_text("pub:pub-password\nsub:sub-password\n")
    (tmp_path / "credentials").write_text("pub:pub-password\nsub:sub-password\nintruder:sub-password\n")
    router_cfg = {
        "mode": "router",
        "listen": {"endpoints": [f"tcp/127.0.0.1:{port}"]},
        "scouting": {"multicast": {"enabled": False}},
        "transport": {"auth": {"usrpwd": {"dictionary_file": str(tmp_path / "users")}}},
    }
    router = zenoh.open(zenoh.Config.from_json5(json.dumps(router_cfg)))
    made: list[Bus] = []
    try:
        bus_section = {**run_config["bus"], "router": f"tcp/127.0.0.1:{port}", "mode": "client"}
        cfg = {**run_config, "bus": {**bus_section, "credentials_file": str(tmp_path / "credentials")}}
        made += [Bus(cfg, "pub", mode="client"), Bus(cfg, "sub", mode="client")]
        sub = made[1].subscribe("heartbeat/*", queue=50)
        connected(made[0], sub, "heartbeat/pub", lambda: hb("pub"))
        with pytest.raises(BusError, match=r"credentials.*no line `lost:<password>`"):
            Bus(cfg, "lost", mode="client")
        with pytest.raises(zenoh.ZError):  # a line the router's dictionary does not hold: refused
            Bus(cfg, "intruder", mode="client")
    finally:
        for bus in made:
            bus.close()
        router.close()


def test_credentials_file_is_instead_of_user_and_password_file():
    from ares.core.config.run import BusSettings

    with pytest.raises(pydantic.ValidationError, match="not both"):
        BusSettings(user="vehicle", password_file="/run/secrets/x", credentials_file="/run/secrets/y", mode="client")
    with pytest.raises(pydantic.ValidationError, match="set mode: client"):
        BusSettings(credentials_file="/run/secrets/y")
    assert BusSettings(credentials_file="/run/secrets/y", mode="client").credentials_file == "/run/secrets/y"
