"""`ares bench bus`: publish -> subscribe latency and sustained throughput of the real bus, for
small JSON messages and for bulk point clouds.

Three OS processes besides the caller: the embedded router (`python -m ares.app.embedded_router` on a free
loopback port) and two children spawned with subprocess (never fork), a publisher and a
subscriber, each with its own ares.core.bus.Bus, exactly the path the stack uses: Bus.publish (schema
check, encoding) and Bus.subscribe (decoding, validation).

- small: ares.core.messages.CarState (~190 B of JSON) on `dbw/car_state`;
- clouds: a 131,072-point ares.core.messages.PointCloud (x, y, z, intensity as float32, ring as
  uint8: 2.2 MB) on `lidar/roof/points`, a header plus the raw arrays, decoded as views of the
  received payload.

For each kind, driven by the caller over the children's stdin/stdout (one JSON object per line):

1. warm-up (discarded);
2. latency: messages spaced by an interval, so each one meets an idle receiver. One-way
   latency = receive time - send time, both time.monotonic() (CLOCK_MONOTONIC, one clock for
   every process on the machine): the sender stamps it into the message's `t`, the subscriber's
   callback subtracts it after decoding and validation;
3. throughput: back to back for a while through a blocking (reliable) publisher; the
   subscriber counts. rate = received / (last receive - first send); lost = sent - received
   once the stragglers have arrived.
"""

from __future__ import annotations

import argparse
import json
import os
import queue
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TextIO

from ares.core.localhost import free_port, stop_process, wait_for_port
from ares.tools.bench.common import BenchError, Goal, judge, percentile, versions

KINDS = {"small": "dbw/car_state", "cloud": "lidar/roof/points"}
CLOUD_POINTS = 131_072
GOALS = {
    "latency_p50_ms": Goal(0.3),
    "latency_p99_ms": Goal(2.0),
    "rate_msgs_per_s": Goal(20000.0, at_least=True),
    "lost": Goal(0),  # of the messages sent back to back
    "cloud_latency_p50_ms": Goal(5.0),
    "cloud_rate_per_s": Goal(50.0, at_least=True),
    "cloud_lost": Goal(0),
}
LATENCY_METHOD = (
    "one-way: the sender stamps time.monotonic() (CLOCK_MONOTONIC, shared by all "
    "processes of the machine) into the message; the subscriber's Bus callback "
    "subtracts it after decoding + schema validation"
)


def sample_message(kind: str, seq: int = 0, cloud=None):
    from ares.core.messages import CarState, DriveMode

    if kind == "cloud":
        return cloud.model_copy(update={"t": time.monotonic()})
    return CarState(
        t=time.monotonic(),
        mode=DriveMode.AUTOMATIC,
        engaged=True,
        watchdog_tripped=False,
        setpoint_age_s=0.05,
        v_command=3.5,
        kappa_command=0.012,
        speed_mps=3.47,
        steering_wheel_deg=float(seq % 360),
    )


def sample_cloud(points: int = CLOUD_POINTS):
    """A roof sweep's worth of points (the values do not matter to the bus, their size does)."""
    import numpy as np

    from ares.core.messages import PointCloud

    rng = np.random.default_rng(0)
    return PointCloud(
        t=0.0,
        sensor="roof",
        frame="lidar_roof",
        x=rng.uniform(-80, 80, points).astype("<f4"),
        y=rng.uniform(-80, 80, points).astype("<f4"),
        z=rng.uniform(-3, 5, points).astype("<f4"),
        intensity=rng.random(points, dtype=np.float32),
        ring=(np.arange(points) % 64).astype("u1"),
    )


# ---- the children ----------------------------------------------------------------------------


def _reply(obj: dict) -> None:
    sys.stdout.write(json.dumps(obj) + "\n")
    sys.stdout.flush()


def _child_sub(bus) -> None:
    latencies: dict[str, list[float]] = {kind: [] for kind in KINDS}
    received: dict[str, list[float]] = {kind: [] for kind in KINDS}
    mono = time.monotonic

    def counter(kind: str):
        def on_message(_topic, msg) -> None:  # Zenoh thread: two appends, never blocks
            now = mono()
            received[kind].append(now)
            latencies[kind].append(now - msg.t)

        return on_message

    for kind, topic in KINDS.items():
        bus.subscribe(topic, on_message=counter(kind))
    _reply({"ready": True})
    for line in sys.stdin:
        cmd = line.split()
        if not cmd:
            continue
        if cmd[0] == "reset":
            for kind in KINDS:
                latencies[kind].clear()
                received[kind].clear()
            _reply({"ok": True})
        elif cmd[0] == "wait":
            kind, expected, quiet_s = cmd[1], int(cmd[2]), float(cmd[3])
            lat, recv = latencies[kind], received[kind]
            last_n, last_change = -1, mono()
            while len(lat) < expected and mono() - last_change < quiet_s:
                n = len(lat)
                if n != last_n:
                    last_n, last_change = n, mono()
                time.sleep(0.005)
            n = len(lat)
            values = sorted(lat[:n])
            _reply(
                {
                    "received": n,
                    "first_recv": recv[0] if n else None,
                    "last_recv": recv[n - 1] if n else None,
                    "p50": percentile(values, 50),
                    "p90": percentile(values, 90),
                    "p99": percentile(values, 99),
                    "max": values[-1] if n else None,
                    "mean": statistics.fmean(values) if n else None,
                    "min": values[0] if n else None,
                    "rejects": bus.rejects.total,
                }
            )
        elif cmd[0] == "quit":
            break


def _child_pub(bus) -> None:
    from ares.core import schema

    cloud = sample_cloud()
    publishers = {kind: bus.publisher(topic, reliable=True) for kind, topic in KINDS.items()}
    deadline = time.monotonic() + 15.0
    while not all(bus.matched(topic) for topic in KINDS.values()):
        if time.monotonic() > deadline:
            _reply({"ready": False, "error": "no subscriber matched within 15 s"})
            return
        time.sleep(0.01)
    info = bus.session.info
    _reply(
        {
            "ready": True,
            "peers": len(info.peers_zid()),
            "routers": len(info.routers_zid()),
            "payload_bytes": {kind: len(schema.encode(sample_message(kind, cloud=cloud))) for kind in KINDS},
        }
    )
    mono = time.monotonic
    for line in sys.stdin:
        cmd = line.split()
        if not cmd:
            continue
        if cmd[0] == "spaced":
            kind, count, interval_s = cmd[1], int(cmd[2]), float(cmd[3]) / 1e3
            put = publishers[kind].put
            first = mono()
            next_t = first
            for seq in range(count):
                put(sample_message(kind, seq, cloud))
                next_t += interval_s
                pause = next_t - mono()
                if pause > 0:
                    time.sleep(pause)
            _reply({"sent": count, "first_send": first, "last_send": mono()})
        elif cmd[0] == "burst":
            kind, seconds = cmd[1], float(cmd[2])
            put = publishers[kind].put
            first = mono()
            end = first + seconds
            sent = 0
            check_every = 1 if kind == "cloud" else 256
            while True:
                put(sample_message(kind, sent, cloud))
                sent += 1
                if sent % check_every == 0 and mono() >= end:
                    break
            _reply({"sent": sent, "first_send": first, "last_send": mono()})
        elif cmd[0] == "quit":
            break


def child_main(argv: list[str] | None = None) -> int:
    from ares.core import config
    from ares.core.bus import Bus

    parser = argparse.ArgumentParser(prog="python -m ares.tools.bench.bus")
    parser.add_argument("role", choices=["pub", "sub"])
    args = parser.parse_args(argv)
    bus = Bus(config.current(), f"bench_{args.role}")
    try:
        (_child_pub if args.role == "pub" else _child_sub)(bus)
    finally:
        bus.close()
    return 0


# ---- the caller ------------------------------------------------------------------------------


class _Child:
    """A spawned child with a line protocol: commands on stdin, JSON replies on stdout."""

    def __init__(self, name: str, cmd: list[str], env: dict, log_path: Path):
        self.name = name
        self._log = log_path.open("w")
        self.proc = subprocess.Popen(
            cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=self._log, env=env, text=True, bufsize=1
        )
        self._lines: queue.Queue[str | None] = queue.Queue()
        threading.Thread(target=self._read, daemon=True).start()
        self.log_path = log_path

    def _read(self) -> None:
        for line in self.proc.stdout:
            self._lines.put(line)
        self._lines.put(None)

    def ask(self, command: str | None, timeout_s: float) -> dict:
        if command is not None:
            self.proc.stdin.write(command + "\n")
            self.proc.stdin.flush()
        try:
            line = self._lines.get(timeout=timeout_s)
        except queue.Empty:
            raise BenchError(
                f"{self.name}: no answer to {command!r} within {timeout_s:.0f} s{_tail(self.log_path)}"
            ) from None
        if line is None:
            self.proc.wait(timeout=5)
            raise BenchError(f"{self.name} exited with code {self.proc.returncode}{_tail(self.log_path)}")
        return json.loads(line)

    def stop(self) -> None:
        if self.proc.poll() is None:
            try:
                self.proc.stdin.write("quit\n")
                self.proc.stdin.flush()
                self.proc.wait(timeout=5)
            except (OSError, subprocess.TimeoutExpired):
                stop_process(self.proc)
        self._log.close()


def _tail(path: Path, chars: int = 800) -> str:
    try:
        text = path.read_text(errors="replace").strip()
    except OSError:
        return ""
    return f"; its log ends:\n{text[-chars:]}" if text else ""


@dataclass(frozen=True)
class _Plan:
    """How many messages of each kind, how far apart, and how long each burst lasts."""

    half_s: float
    interval_ms: float
    count: int
    cloud_interval_ms: float
    cloud_count: int


Phase = tuple[dict, dict, dict, dict]  # a kind's (latency publisher, subscriber, throughput publisher, subscriber)


def _phase(
    pub: _Child,
    sub: _Child,
    kind: str,
    count: int,
    interval_ms: float,
    burst_s: float,
    warmup: int,
    say: Callable[[str], None],
) -> Phase:
    """The answers of one kind's phase (warm-up, latency, throughput)."""
    say(f"{kind}: warm-up (discarded)")
    w1 = pub.ask(f"spaced {kind} {warmup} {interval_ms}", 120)
    sub.ask(f"wait {kind} {w1['sent']} 3", 60)
    sub.ask("reset", 10)
    say(f"{kind}: latency, {count} messages one every {interval_ms:g} ms")
    lat_pub = pub.ask(f"spaced {kind} {count} {interval_ms}", count * interval_ms / 1e3 * 4 + 60)
    lat_sub = sub.ask(f"wait {kind} {lat_pub['sent']} 3", 60)
    sub.ask("reset", 10)
    say(f"{kind}: throughput, back to back for {burst_s:g} s through a blocking publisher")
    thr_pub = pub.ask(f"burst {kind} {burst_s}", burst_s * 4 + 60)
    thr_sub = sub.ask(f"wait {kind} {thr_pub['sent']} 5", burst_s * 20 + 60)
    sub.ask("reset", 10)
    return lat_pub, lat_sub, thr_pub, thr_sub


def _rate(thr_pub: dict, thr_sub: dict) -> tuple[float, float]:
    received = thr_sub["received"]
    elapsed = (thr_sub["last_recv"] - thr_pub["first_send"]) if received else float("nan")
    return (received / elapsed if received and elapsed > 0 else 0.0), elapsed


def _ms(seconds: float | None) -> float | None:
    return round(seconds * 1e3, 4) if seconds is not None else None


def _bench_config(mode: str | None) -> tuple[dict, str, int]:
    """(the processes' configuration, its bus mode, the router's port): the stack's bus settings,
    on a free port and a vehicle id of the bench's own."""
    from ares.core import config

    cfg = config.core_defaults()
    mode = mode or cfg["bus"]["mode"]
    if mode not in ("peer", "client"):
        raise BenchError(f"unknown bus mode {mode!r} (peer or client)")
    port = free_port()
    cfg["vehicle_id"] = f"bench{os.getpid()}"
    cfg["bus"].update({"router": f"tcp/127.0.0.1:{port}", "mode": mode})
    return cfg, mode, port


def _start_router(env: dict, port: int, log_path: Path) -> subprocess.Popen:
    with log_path.open("w") as log:  # the child holds its own descriptor
        router = subprocess.Popen(
            [sys.executable, "-m", "ares.app.embedded_router"],
            env=env,
            stdout=log,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
        )
    try:
        wait_for_port(port, 15.0, router)
    except (TimeoutError, RuntimeError) as exc:
        stop_process(router)
        raise BenchError(f"{exc}{_tail(log_path)}") from None
    return router


def _start_children(env: dict, tmpdir: Path, children: list[_Child]) -> tuple[_Child, _Child, dict]:
    """(subscriber, publisher, the publisher's hello), appended to `children` as they start."""
    sub = _Child("subscriber", [sys.executable, "-m", "ares.tools.bench.bus", "sub"], env, tmpdir / "sub.log")
    children.append(sub)
    if not sub.ask(None, 30).get("ready"):
        raise BenchError("subscriber did not start")
    pub = _Child("publisher", [sys.executable, "-m", "ares.tools.bench.bus", "pub"], env, tmpdir / "pub.log")
    children.append(pub)
    hello = pub.ask(None, 30)
    if not hello.get("ready"):
        raise BenchError(f"publisher did not start: {hello.get('error')}")
    return sub, pub, hello


def _measure(cfg: dict, port: int, plan: _Plan, say: Callable[[str], None]) -> tuple[dict, Phase, Phase]:
    """(the publisher's hello, the small messages' phase, the clouds'): the router and the two
    children started, both kinds measured, everything stopped again."""
    from ares.core import config

    with tempfile.TemporaryDirectory(prefix="ares-bench-") as tmp:
        tmpdir = Path(tmp)
        run_cfg = config.write_run_config(cfg, tmpdir / "run_config.json")
        env = dict(os.environ, **{config.RUN_CONFIG_ENV: str(run_cfg)})
        env.setdefault("ARES_LOG_LEVEL", "WARNING")
        say(f"starting router on tcp/127.0.0.1:{port} (bus mode {cfg['bus']['mode']})")
        router = _start_router(env, port, tmpdir / "router.log")
        children: list[_Child] = []
        try:
            sub, pub, hello = _start_children(env, tmpdir, children)
            small = _phase(pub, sub, "small", plan.count, plan.interval_ms, plan.half_s, min(300, plan.count), say)
            clouds = _phase(pub, sub, "cloud", plan.cloud_count, plan.cloud_interval_ms, plan.half_s, 10, say)
        except BenchError as exc:
            if router.poll() is not None:  # the likely cause: say so
                raise BenchError(
                    f"the router exited with code {router.returncode} ({exc}){_tail(tmpdir / 'router.log')}"
                ) from None
            raise
        finally:
            for child in reversed(children):
                child.stop()
            stop_process(router)
    return hello, small, clouds


def _small_figures(small: Phase, interval_ms: float, hello: dict) -> dict:
    lat_pub, lat_sub, thr_pub, thr_sub = small
    rate, elapsed = _rate(thr_pub, thr_sub)
    return {
        "latency_p50_ms": _ms(lat_sub["p50"]),
        "latency_p99_ms": _ms(lat_sub["p99"]),
        "rate_msgs_per_s": round(rate, 1),
        "lost": thr_pub["sent"] - thr_sub["received"],
        "latency_p90_ms": _ms(lat_sub["p90"]),
        "latency_min_ms": _ms(lat_sub["min"]),
        "latency_max_ms": _ms(lat_sub["max"]),
        "latency_mean_ms": _ms(lat_sub["mean"]),
        "latency_method": LATENCY_METHOD,
        "latency_messages": lat_sub["received"],
        "latency_lost": lat_pub["sent"] - lat_sub["received"],
        "latency_interval_ms": interval_ms,
        "throughput_sent": thr_pub["sent"],
        "throughput_received": thr_sub["received"],
        "throughput_seconds": round(elapsed, 4),
        "send_rate_msgs_per_s": round(thr_pub["sent"] / max(thr_pub["last_send"] - thr_pub["first_send"], 1e-9), 1),
        "messages": lat_pub["sent"] + thr_pub["sent"],
        "rejected": thr_sub["rejects"],
        "topic": KINDS["small"],
        "schema": "CarState",
        "payload_bytes": hello["payload_bytes"]["small"],
        "encoding": "JSON (pydantic) with schema name",
    }


def _cloud_figures(clouds: Phase, interval_ms: float, hello: dict) -> dict:
    lat_pub, lat_sub, thr_pub, thr_sub = clouds
    rate, elapsed = _rate(thr_pub, thr_sub)
    return {
        "cloud_latency_p50_ms": _ms(lat_sub["p50"]),
        "cloud_latency_p99_ms": _ms(lat_sub["p99"]),
        "cloud_rate_per_s": round(rate, 1),
        "cloud_lost": thr_pub["sent"] - thr_sub["received"] + lat_pub["sent"] - lat_sub["received"],
        "cloud_points": CLOUD_POINTS,
        "cloud_topic": KINDS["cloud"],
        "cloud_payload_bytes": hello["payload_bytes"]["cloud"],
        "cloud_encoding": "header + raw little-endian arrays (x, y, z, intensity float32; ring uint8), "
        "decoded as views of the received payload",
        "cloud_latency_messages": lat_sub["received"],
        "cloud_latency_interval_ms": interval_ms,
        "cloud_latency_max_ms": _ms(lat_sub["max"]),
        "cloud_throughput_sent": thr_pub["sent"],
        "cloud_throughput_received": thr_sub["received"],
        "cloud_throughput_seconds": round(elapsed, 4),
    }


def _setting_figures(mode: str, hello: dict) -> dict:
    if mode == "peer":
        route = "direct peer-to-peer link" if hello.get("peers") else "through the router"
    else:
        route = "through the router (client mode)"
    return {
        "mode": mode,
        "route": route,
        "publisher_links": {"peers": hello.get("peers"), "routers": hello.get("routers")},
        "congestion_control": "block",
        "processes": "router + publisher + subscriber (subprocess, no fork)",
        "cpus": os.cpu_count(),
        **versions("eclipse-zenoh", "pydantic", "numpy"),
    }


def run_bus_bench(
    seconds: float = 6.0,
    mode: str | None = None,
    interval_ms: float = 1.0,
    cloud_interval_ms: float = 50.0,
    progress: Callable[[str], None] | None = None,
) -> dict:
    """Run the benchmark and return its result (see the module docstring). `seconds` is split
    between the small messages' latency and throughput; the clouds take about as long again."""
    if seconds <= 0:
        raise BenchError("--seconds must be positive")
    say = progress or (lambda _msg: None)
    cfg, mode, port = _bench_config(mode)
    half = seconds / 2.0
    plan = _Plan(
        half_s=half,
        interval_ms=interval_ms,
        count=max(50, int(half * 1e3 / interval_ms)),
        cloud_interval_ms=cloud_interval_ms,
        cloud_count=max(20, int(half * 1e3 / cloud_interval_ms)),
    )
    hello, small, clouds = _measure(cfg, port, plan, say)
    result = {
        "bench": "bus",
        **_small_figures(small, interval_ms, hello),
        **_cloud_figures(clouds, cloud_interval_ms, hello),
        **_setting_figures(mode, hello),
    }
    return judge(result, GOALS)


def format_result(result: dict, out: TextIO) -> None:
    met = result["goals_met"]

    def line(label: str, key: str, unit: str, fmt: str) -> None:
        goal = GOALS[key]
        mark = "ok" if met[key] else "MISSED"
        compare = ">=" if goal.at_least else "<="
        out.write(f"  {label} {result[key]:{fmt}} {unit}  [goal {compare} {goal.limit:g} {unit}: {mark}]\n")

    out.write(
        f"bus bench ({result['mode']} mode, {result['route']}; python {result['python']}, zenoh {result['zenoh']})\n"
    )
    out.write(f" {result['schema']} {result['payload_bytes']} B:\n")
    line("latency p50", "latency_p50_ms", "ms", ".3f")
    line("latency p99", "latency_p99_ms", "ms", ".3f")
    line("throughput", "rate_msgs_per_s", "msg/s", ".0f")
    line("lost", "lost", f"of {result['throughput_sent']}", "d")
    out.write(f" PointCloud of {result['cloud_points']} points, {result['cloud_payload_bytes'] / 1e6:.2f} MB:\n")
    line("latency p50", "cloud_latency_p50_ms", "ms", ".2f")
    line("throughput", "cloud_rate_per_s", "clouds/s", ".1f")
    line("lost", "cloud_lost", "clouds", "d")
    out.write(f"  p99 latency {result['cloud_latency_p99_ms']:.2f} ms\n")
    out.write(f"  latency: {result['latency_method']}\n")


if __name__ == "__main__":
    sys.exit(child_main())
