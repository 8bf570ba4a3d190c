"""The CAN wire's bench (part of `ares bench drivers`): how fast the codec of ares/core/wire/ares.dbc
encodes and decodes, and how fast frames go through a real python-can udp_multicast group into the
CAN driver node and out on the bus.

- codec: a batch of the vehicle's traffic (CanFrame and Imu samples, three frames each, a body
  state per ten) encoded once, then decoded again and again by a fresh decoder (its counters start
  afresh, so every batch decodes in full); frames/s of each batch, median over the batches. The
  encoder's rate is measured the same way (the simulator's side).
- end to end: the simulator's port (simulator.can_wire) sends bursts of samples on a multicast group
  of its own; the CanDriver node (in-memory bus, manual clock) reads, decodes and publishes them.
  Throughput of the whole (send + receive in one process) and of the driver's steps alone; the
  latency from each closing frame's kernel receive time to its put on the bus, measured one
  sample at a time (no burst queued ahead of it); and the command path: an ActuatorCommand
  published on the bus, the driver's step, the simulator's poll() that returns it.
"""

from __future__ import annotations

import itertools
import math
import os
import socket
import time
from typing import Any

from ares.core import config
from ares.core.clock import ManualClock
from ares.core.config import CanDevice
from ares.core.membus import MemoryNetwork
from ares.core.messages import ActuatorCommand, BodyState, CanFrame, Imu
from ares.core.wire.can_frames import CanCodec, CanDecoder, CanEncoder
from ares.tools.bench.common import BenchError, percentile, versions
from drivers.can_node import CanDriver
from simulator.can_wire import SimCanPort

BATCH_SAMPLES = 200  # CanFrame + Imu samples per codec batch (about 600 frames)
BURST_SAMPLES = 30  # samples per end-to-end burst: 90 datagrams, well within a socket's receive buffer
WAIT_S = 2.0


def _samples(n: int) -> list[Any]:
    """n samples of a shuttle driving a curve, alternately CanFrame and Imu, a body state per ten."""
    out: list[Any] = []
    for i in range(n):
        phase = i / max(n, 1) * math.tau
        if i % 2 == 0:
            out.append(
                CanFrame(
                    t=0.0,
                    wheel_speed_rad_s=10.0 + math.sin(phase),
                    speed_mps=2.8 + 0.3 * math.sin(phase),
                    steering_wheel_deg=300.0 * math.sin(phase),
                    throttle_pedal=0.0,
                    brake_pedal=0.0,
                    steering_torque=False,
                )
            )
        else:
            out.append(
                Imu(
                    t=0.0,
                    yaw=math.remainder(phase, math.tau),
                    roll=0.01 * math.sin(phase),
                    pitch=-0.02,
                    gyro_x=0.001,
                    gyro_y=0.002,
                    gyro_z=0.3 * math.cos(phase),
                    accel_x=0.2,
                    accel_y=0.8 * math.sin(phase),
                    accel_z=9.81,
                )
            )
        if i % 10 == 9:
            out.append(BodyState(t=0.0, doors="closed", ramp="stowed", entrance_clear=True, passengers=i % 12))
    return out


def codec_bench(seconds: float) -> dict[str, Any]:
    codec = CanCodec.load()
    samples = _samples(BATCH_SAMPLES)
    encoder = CanEncoder(codec)
    frames = [frame for msg in samples for frame in encoder.encode(msg)]
    encode_rates: list[float] = []
    decode_rates: list[float] = []
    deadline = time.perf_counter() + seconds
    while time.perf_counter() < deadline or len(decode_rates) < 3:
        started = time.perf_counter()
        fresh = CanEncoder(codec)
        for msg in samples:
            fresh.encode(msg)
        encode_rates.append(len(frames) / (time.perf_counter() - started))
        decoder = CanDecoder(codec, "computer")
        started = time.perf_counter()
        published = sum(decoder.decode(frame, 0.0).message is not None for frame in frames)
        decode_rates.append(len(frames) / (time.perf_counter() - started))
        if published != len(samples):
            raise BenchError(f"the codec decoded {published} of {len(samples)} messages")
    return {
        "frames_per_batch": len(frames),
        "batches": len(decode_rates),
        "decode_frames_per_s_p50": round(percentile(decode_rates, 50) or 0.0),
        "encode_frames_per_s_p50": round(percentile(encode_rates, 50) or 0.0),
        "decode_us_per_frame_p50": round(1e6 / (percentile(decode_rates, 50) or math.inf), 2),
    }


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("", 0))
        port: int = s.getsockname()[1]
        return port


class _Wire:
    """The driver node and the simulator's port on a multicast group of their own."""

    def __init__(self) -> None:
        self.device = CanDevice(
            interface="udp_multicast", channel=f"239.84.{os.getpid() % 250}.1", port=_free_udp_port()
        )
        cfg = config.core_defaults()
        cfg["vehicle_io"] = {"can": self.device.model_dump()}
        self.clock = ManualClock()
        network = MemoryNetwork()
        self.node = CanDriver(cfg, clock=self.clock, bus=network.bus("can_driver", self.clock))
        self.node.setup()
        self.sim = SimCanPort(self.device)
        self.bus = network.bus("bench", self.clock)
        self.out = {t: self.bus.subscribe(t, queue=100_000) for t in ("sensors/can", "sensors/imu", "body/state")}
        self.ticks = itertools.count(1)
        self.step_s = 0.0  # wall time spent in the driver's steps

    def step(self) -> None:
        t = next(self.ticks) * 0.02
        self.clock.set(t)
        started = time.perf_counter()
        self.node.step_once(t)
        self.step_s += time.perf_counter() - started

    def published(self) -> int:
        return sum(len(sub.drain()) for sub in self.out.values())

    def close(self) -> None:
        self.node.teardown()
        self.sim.close()


def _send(sim: SimCanPort, msg: CanFrame | Imu | BodyState) -> None:
    if isinstance(msg, CanFrame):
        sim.send_can(msg)
    elif isinstance(msg, Imu):
        sim.send_imu(msg)
    else:
        sim.send_body(msg)


def wire_bench(seconds: float) -> dict[str, Any]:
    wire = _Wire()
    try:
        burst = _samples(BURST_SAMPLES)
        frames_per_burst = sum(3 if isinstance(m, (CanFrame, Imu)) else 1 for m in burst)
        # throughput: bursts sent, then the driver steps until it has published them all
        sent = published = 0
        started = time.perf_counter()
        deadline = started + seconds / 2
        while time.perf_counter() < deadline:
            for msg in burst:
                _send(wire.sim, msg)
            sent += frames_per_burst
            want = published + len(burst)
            wait_until = time.perf_counter() + WAIT_S
            while published < want:
                wire.step()
                published += wire.published()
                if time.perf_counter() > wait_until:
                    raise BenchError(f"the driver published {published} of {want} messages")
        elapsed = time.perf_counter() - started
        status = wire.node.counters
        if status.lost or status.malformed:
            raise BenchError(f"frames lost ({status.lost}) or refused ({dict(status.malformed)}) on loopback")
        throughput = {
            "frames": sent,
            "end_to_end_frames_per_s": round(sent / elapsed),
            "driver_frames_per_s": round(sent / wire.step_s),
        }

        # latency: one sample at a time, the driver stepping right after its closing frame went out
        wire.node.counters.latencies_s.clear()
        wire.sim.poll(0.0)  # its own frames, looped back and queued meanwhile: the next poll must be quick
        sample = burst[0]
        round_trips: list[float] = []
        deadline = time.perf_counter() + seconds / 2
        while time.perf_counter() < deadline or len(round_trips) < 10:
            _send(wire.sim, sample)
            wait_until = time.perf_counter() + WAIT_S
            while not wire.published():
                wire.step()
                if time.perf_counter() > wait_until:
                    raise BenchError("a sample did not come through")
            # and the command path: the bus, the driver's step, the wire, the simulator's poll
            t = wire.clock.now()
            command = ActuatorCommand(t=t, engaged=True, steer_effort=0.1, drive_effort=0.2)
            started = time.perf_counter()
            wire.bus.publish("dbw/actuators", command)
            wire.step()
            while not wire.sim.poll(t)[0]:
                if time.perf_counter() - started > WAIT_S:
                    raise BenchError("a command did not reach the simulator")
            round_trips.append(time.perf_counter() - started)
        return {
            **throughput,
            "samples_timed": len(wire.node.counters.latencies_s),
            "wire_to_bus_latency_p50_ms": wire.node.counters.percentile_ms(50),
            "wire_to_bus_latency_p99_ms": wire.node.counters.percentile_ms(99),
            "command_to_sim_latency_p50_ms": percentile([s * 1e3 for s in round_trips], 50, 3),
            "command_to_sim_latency_p99_ms": percentile([s * 1e3 for s in round_trips], 99, 3),
        }
    finally:
        wire.close()


def can_bench(seconds: float) -> dict[str, Any]:
    """The codec's and the udp_multicast wire's figures; `seconds` is split between the two."""
    return {
        "codec": codec_bench(seconds / 2),
        "udp_multicast": wire_bench(seconds / 2),
        "versions": versions("python-can", "cantools"),
    }
