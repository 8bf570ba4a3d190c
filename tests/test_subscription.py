"""What a subscriber knows about a topic: the latest message, its age and the rate, all from the
messages' own stamps against the receiver's clock (deterministic: in-memory bus, manual clock)."""

from __future__ import annotations

import math

import pytest

from ares.core.clock import ManualClock
from ares.core.membus import MemoryNetwork
from ares.core.messages import GnssSentences


@pytest.fixture
def setup():
    clock = ManualClock(0.0)
    network = MemoryNetwork()
    return clock, network.bus("pub", clock), network.bus("sub", clock)


def test_age_and_rate_come_from_the_stamps(setup):
    clock, pub, sub_bus = setup
    sub = sub_bus.subscribe("sensors/gnss", max_age=0.5)
    assert sub.age() == math.inf and sub.fresh() is None and sub.rate_hz() == 0.0 and not sub.rate_ok(1.0)
    for k in range(21):  # 20 Hz for a second
        clock.set(k * 0.05)
        pub.publish("sensors/gnss", GnssSentences(t=clock.now(), sentences=["$GPGGA"]))
    assert sub.age() == pytest.approx(0.0) and sub.fresh() is not None
    assert sub.rate_hz(window_s=1.0) == pytest.approx(20.0)
    assert sub.rate_ok(10.0, window_s=1.0) and not sub.rate_ok(40.0, window_s=1.0)
    clock.set(1.6)  # then silence
    assert sub.age() == pytest.approx(0.6) and sub.fresh() is None and sub.fresh(max_age=1.0) is not None
    assert sub.rate_hz(window_s=0.5) == 0.0


def test_a_message_delivered_late_is_as_old_as_its_stamp_says(setup):
    clock, pub, sub_bus = setup
    sub = sub_bus.subscribe("sensors/gnss", max_age=1.0)
    clock.set(10.0)
    pub.publish("sensors/gnss", GnssSentences(t=8.5, sentences=[]))  # produced 1.5 s ago
    assert sub.latest is not None and sub.age() == pytest.approx(1.5) and sub.fresh() is None


def test_a_latched_subscription_changes_only_when_latched(setup):
    """A node's inputs: what arrives during a step waits for the next one."""
    clock, pub, sub_bus = setup
    sub = sub_bus.subscribe("sensors/gnss", queue=10, latched=True)
    pub.publish("sensors/gnss", GnssSentences(t=0.0, sentences=["a"]))
    pub.publish("sensors/gnss", GnssSentences(t=0.0, sentences=["b"]))
    assert sub.latest is None and sub.drain() == []
    assert sub.latch() == 2
    assert [m.sentences for _, m in sub.drain()] == [["a"], ["b"]] and sub.latest.sentences == ["b"]


def test_a_node_that_stalls_holds_only_what_its_next_step_can_use(setup):
    """Between latches a latest-value input keeps one message, a queue as many as it holds (the
    rest counted as overflowed); every message still counts for the rate."""
    clock, pub, sub_bus = setup
    latest = sub_bus.subscribe("sensors/gnss", latched=True)
    queued = sub_bus.subscribe("sensors/gnss", queue=3, latched=True)
    for k in range(1000):
        clock.set(k * 0.01)
        pub.publish("sensors/gnss", GnssSentences(t=clock.now(), sentences=[str(k)]))
    assert latest.waiting == 1 and queued.waiting == 3 and queued.overflowed == 997
    assert latest.latch() == 1000 and queued.latch() == 1000
    assert latest.latest.sentences == ["999"] and latest.count == 1000
    assert latest.rate_hz(window_s=2.0) == pytest.approx(100.0)
    assert [m.sentences[0] for _, m in queued.drain()] == ["997", "998", "999"]


def test_a_subscription_put_back_holds_again_what_it_held(setup):
    """Process replay tries a step latching different inputs and puts the node's subscriptions
    back between tries: latest value, counts, rate, queue and what waits for the next latch."""
    clock, pub, sub_bus = setup
    sub = sub_bus.subscribe("sensors/gnss", queue=5, latched=True)
    for k in range(3):
        clock.set(k * 0.1)
        pub.publish("sensors/gnss", GnssSentences(t=clock.now(), sentences=[str(k)]))
    sub.latch()
    pub.publish("sensors/gnss", GnssSentences(t=0.3, sentences=["3"]))
    held = sub.copy_state()
    for _ in range(2):  # a state is put back as often as the tries need
        pub.publish("sensors/gnss", GnssSentences(t=0.4, sentences=["4"]))
        assert sub.latch() == 2 and sub.latest.sentences == ["4"] and sub.count == 5
        assert [m.sentences[0] for _, m in sub.drain()] == ["0", "1", "2", "3", "4"]
        sub.restore_state(held)
        assert sub.latest.sentences == ["2"] and sub.count == 3 and sub.waiting == 1
    clock.set(0.3)
    assert sub.latch() == 1 and [m.sentences[0] for _, m in sub.drain()] == ["0", "1", "2", "3"]
    assert sub.rate_hz(window_s=1.0) == pytest.approx(10.0)


def test_unknown_topics_and_wrong_schemas_are_refused_at_once(setup):
    _, pub, sub_bus = setup
    with pytest.raises(KeyError, match="not in the topic table"):
        sub_bus.subscribe("sensors/gnsss")
    with pytest.raises(KeyError, match="not in the topic table"):
        pub.publish("no/such/topic", GnssSentences(sentences=[]))
    with pytest.raises(TypeError, match="carries Imu"):
        pub.publish("sensors/imu", GnssSentences(sentences=[]))
