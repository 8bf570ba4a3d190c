"""`ares bench bus`: publish -> subscribe latency and sustained throughput of the real bus.

Three OS processes besides the caller: the embedded router (`python -m ares.router` on a free
loopback port) and two children spawned with subprocess (never fork), a publisher and a
subscriber, each with its own ares.bus.Bus. Messages are ares.messages.CarState on
`dbw/car_state`, sent with Bus.publish (schema check + JSON encode) and received with
Bus.subscribe (schema check + pydantic validation), exactly the path the stack uses.

Phases, driven by the caller over the children's stdin/stdout (one JSON object per line):

1. warm-up (discarded): spaced messages, then a short burst;
2. latency: messages spaced by `interval_ms`, so each one meets an idle receiver. One-way
   latency = receive time - send time, both read with time.monotonic() (CLOCK_MONOTONIC, one
   clock for every process on the machine): the sender stamps it into the message's `t`
   field, the subscriber's on_message callback subtracts it after decode and validation;
3. throughput: the publisher sends back to back for `seconds/2` through a blocking (reliable,
   congestion control BLOCK) publisher; the subscriber counts. rate = received / (last receive
   - first send); lost = sent - received after the stragglers have arrived.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import platform
import queue
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from importlib import metadata
from pathlib import Path
from typing import Callable, TextIO

TOPIC = "dbw/car_state"
GOALS = {"latency_p50_ms": 0.3, "latency_p99_ms": 2.0, "rate_msgs_per_s": 20000.0}
LATENCY_METHOD = ("one-way: the sender stamps time.monotonic() (CLOCK_MONOTONIC, shared by all "
                  "processes of the machine) into the message; the subscriber's Bus callback "
                  "subtracts it after decode + schema validation")


class BenchError(RuntimeError):
    pass


# ---- helpers ---------------------------------------------------------------------------------

def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_for_port(port: int, timeout_s: float, proc: subprocess.Popen | None = None) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if proc is not None and proc.poll() is not None:
            raise BenchError(f"router exited with code {proc.returncode} before listening")
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=0.2):
                return
        except OSError:
            time.sleep(0.05)
    raise BenchError(f"router not listening on 127.0.0.1:{port} after {timeout_s:.0f} s")


def percentile(sorted_values: list[float], q: float) -> float:
    """Nearest-rank percentile of an already sorted list (q in 0..100)."""
    if not sorted_values:
        return float("nan")
    rank = max(1, min(len(sorted_values), math.ceil(q / 100.0 * len(sorted_values))))
    return sorted_values[rank - 1]


def sample_message(seq: int = 0):
    from ares.messages import CarState, DriveMode
    return CarState(t=time.monotonic(), mode=DriveMode.AUTOMATIC, engaged=True, watchdog_tripped=False,
                    setpoint_age_s=0.05, v_command=3.5, kappa_command=0.012, speed_mps=3.47,
                    steering_wheel_deg=float(seq % 360))


def _versions() -> dict:
    out = {"python": platform.python_version()}
    for dist in ("eclipse-zenoh", "pydantic"):
        try:
            out[dist.replace("eclipse-", "")] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            out[dist.replace("eclipse-", "")] = None
    return out


# ---- the children ----------------------------------------------------------------------------

def _reply(obj: dict) -> None:
    sys.stdout.write(json.dumps(obj) + "\n")
    sys.stdout.flush()


def _child_sub(bus) -> None:
    lat: list[float] = []
    recv: list[float] = []
    mono = time.monotonic

    def on_message(topic, msg) -> None:     # Zenoh thread: two appends, never blocks
        now = mono()
        recv.append(now)
        lat.append(now - msg.t)

    bus.subscribe(TOPIC, on_message=on_message)
    _reply({"ready": True})
    for line in sys.stdin:
        cmd = line.split()
        if not cmd:
            continue
        if cmd[0] == "reset":
            lat.clear()
            recv.clear()
            _reply({"ok": True})
        elif cmd[0] == "wait":
            expected, quiet_s = int(cmd[1]), float(cmd[2])
            last_n, last_change = -1, mono()
            while len(lat) < expected and mono() - last_change < quiet_s:
                n = len(lat)
                if n != last_n:
                    last_n, last_change = n, mono()
                time.sleep(0.005)
            n = len(lat)
            values = sorted(lat[:n])
            _reply({"received": n, "first_recv": recv[0] if n else None, "last_recv": recv[n - 1] if n else None,
                    "p50": percentile(values, 50), "p90": percentile(values, 90),
                    "p99": percentile(values, 99), "max": values[-1] if n else None,
                    "mean": statistics.fmean(values) if n else None, "min": values[0] if n else None,
                    "rejects": bus.rejects.total})
        elif cmd[0] == "quit":
            break


def _child_pub(bus) -> None:
    from ares.bus import encode
    pub = bus.publisher(TOPIC, block=True)
    deadline = time.monotonic() + 15.0
    while not pub._pub.matching_status.matching:
        if time.monotonic() > deadline:
            _reply({"ready": False, "error": "no subscriber matched within 15 s"})
            return
        time.sleep(0.01)
    info = bus.session.info
    _reply({"ready": True, "peers": len(info.peers_zid()), "routers": len(info.routers_zid()),
            "payload_bytes": len(encode(sample_message()))})
    publish, make, mono = bus.publish, sample_message, time.monotonic
    for line in sys.stdin:
        cmd = line.split()
        if not cmd:
            continue
        if cmd[0] == "spaced":
            count, interval_s = int(cmd[1]), float(cmd[2]) / 1e3
            first = mono()
            next_t = first
            for seq in range(count):
                publish(TOPIC, make(seq))
                next_t += interval_s
                pause = next_t - mono()
                if pause > 0:
                    time.sleep(pause)
            _reply({"sent": count, "first_send": first, "last_send": mono()})
        elif cmd[0] == "burst":
            seconds = float(cmd[1])
            first = mono()
            end = first + seconds
            sent = 0
            while True:
                publish(TOPIC, make(sent))
                sent += 1
                if sent % 256 == 0 and mono() >= end:
                    break
            _reply({"sent": sent, "first_send": first, "last_send": mono()})
        elif cmd[0] == "quit":
            break


def child_main(argv: list[str] | None = None) -> int:
    from ares import config
    from ares.bus import Bus
    parser = argparse.ArgumentParser(prog="python -m ares.bench")
    parser.add_argument("role", choices=["pub", "sub"])
    args = parser.parse_args(argv)
    cfg = config.current()
    bus = Bus(cfg, f"bench_{args.role}")
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
        self.proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=self._log,
                                     env=env, text=True, bufsize=1)
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
            raise BenchError(f"{self.name}: no answer to {command!r} within {timeout_s:.0f} s"
                             f"{_tail(self.log_path)}") from None
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
                self.proc.terminate()
                try:
                    self.proc.wait(timeout=3)
                except subprocess.TimeoutExpired:
                    self.proc.kill()
                    self.proc.wait()
        self._log.close()


def _tail(path: Path, chars: int = 800) -> str:
    try:
        text = path.read_text(errors="replace").strip()
    except OSError:
        return ""
    return f"; its log ends:\n{text[-chars:]}" if text else ""


def _stop_process(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def run_bus_bench(seconds: float = 6.0, mode: str | None = None, interval_ms: float = 1.0,
                  progress: Callable[[str], None] | None = None) -> dict:
    """Run the benchmark and return its result (see the module docstring)."""
    from ares import config
    if seconds <= 0:
        raise BenchError("--seconds must be positive")
    say = progress or (lambda _msg: None)
    cfg = config.build_run_config()
    mode = mode or cfg["bus"].get("mode", "peer")
    if mode not in ("peer", "client"):
        raise BenchError(f"unknown bus mode {mode!r} (peer or client)")
    port = free_port()
    cfg["vehicle_id"] = f"bench{os.getpid()}"
    cfg["bus"].update({"router": f"tcp/127.0.0.1:{port}", "mode": mode})

    latency_s = seconds / 2.0
    burst_s = seconds / 2.0
    latency_count = max(50, int(latency_s * 1e3 / interval_ms))

    with tempfile.TemporaryDirectory(prefix="ares-bench-") as tmp:
        tmpdir = Path(tmp)
        run_cfg = config.write_run_config(cfg, tmpdir / "run_config.json")
        env = dict(os.environ, **{config.RUN_CONFIG_ENV: str(run_cfg)})
        env.setdefault("ARES_LOG_LEVEL", "WARNING")
        say(f"starting router on tcp/127.0.0.1:{port} (bus mode {mode})")
        router_log = (tmpdir / "router.log").open("w")
        router = subprocess.Popen([sys.executable, "-m", "ares.router"], env=env, stdout=router_log,
                                  stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL)
        children: list[_Child] = []
        try:
            try:
                wait_for_port(port, 15.0, router)
            except BenchError as exc:
                router_log.flush()
                raise BenchError(f"{exc}{_tail(tmpdir / 'router.log')}") from None
            sub = _Child("subscriber", [sys.executable, "-m", "ares.bench", "sub"], env, tmpdir / "sub.log")
            children.append(sub)
            if not sub.ask(None, 30).get("ready"):
                raise BenchError("subscriber did not start")
            pub = _Child("publisher", [sys.executable, "-m", "ares.bench", "pub"], env, tmpdir / "pub.log")
            children.append(pub)
            hello = pub.ask(None, 30)
            if not hello.get("ready"):
                raise BenchError(f"publisher did not start: {hello.get('error')}")

            say("warm-up (discarded)")
            w1 = pub.ask(f"spaced {min(300, latency_count)} {interval_ms}", 60)
            w2 = pub.ask("burst 0.3", 60)
            sub.ask(f"wait {w1['sent'] + w2['sent']} 3", 60)
            sub.ask("reset", 10)

            say(f"latency: {latency_count} messages, one every {interval_ms:g} ms")
            lat_pub = pub.ask(f"spaced {latency_count} {interval_ms}", latency_s * 4 + 30)
            lat_sub = sub.ask(f"wait {lat_pub['sent']} 3", 60)
            sub.ask("reset", 10)

            say(f"throughput: back to back for {burst_s:g} s through a blocking publisher")
            thr_pub = pub.ask(f"burst {burst_s}", burst_s * 4 + 30)
            thr_sub = sub.ask(f"wait {thr_pub['sent']} 5", burst_s * 20 + 60)
        except BenchError as exc:
            if router.poll() is not None:   # the likely cause: say so
                router_log.flush()
                raise BenchError(f"the router exited with code {router.returncode} ({exc})"
                                 f"{_tail(tmpdir / 'router.log')}") from None
            raise
        finally:
            for child in reversed(children):
                child.stop()
            _stop_process(router)
            router_log.close()

    received = thr_sub["received"]
    elapsed = (thr_sub["last_recv"] - thr_pub["first_send"]) if received else float("nan")
    rate = received / elapsed if received and elapsed > 0 else 0.0
    ms = lambda v: round(v * 1e3, 4) if v is not None else None   # noqa: E731
    if mode == "peer":
        route = "direct peer-to-peer link" if hello.get("peers") else "through the router"
    else:
        route = "through the router (client mode)"
    result = {
        "bench": "bus",
        "latency_p50_ms": ms(lat_sub["p50"]),
        "latency_p99_ms": ms(lat_sub["p99"]),
        "rate_msgs_per_s": round(rate, 1),
        "lost": thr_pub["sent"] - received,
        "latency_p90_ms": ms(lat_sub["p90"]),
        "latency_min_ms": ms(lat_sub["min"]),
        "latency_max_ms": ms(lat_sub["max"]),
        "latency_mean_ms": ms(lat_sub["mean"]),
        "latency_method": LATENCY_METHOD,
        "latency_messages": lat_sub["received"],
        "latency_lost": lat_pub["sent"] - lat_sub["received"],
        "latency_interval_ms": interval_ms,
        "throughput_sent": thr_pub["sent"],
        "throughput_received": received,
        "throughput_seconds": round(elapsed, 4),
        "send_rate_msgs_per_s": round(thr_pub["sent"] / max(thr_pub["last_send"] - thr_pub["first_send"], 1e-9), 1),
        "messages": lat_pub["sent"] + thr_pub["sent"],
        "warmup_messages": w1["sent"] + w2["sent"],
        "rejected": thr_sub["rejects"],
        "topic": TOPIC,
        "schema": "CarState",
        "payload_bytes": hello["payload_bytes"],
        "encoding": "JSON (pydantic) with schema name",
        "mode": mode,
        "route": route,
        "publisher_links": {"peers": hello.get("peers"), "routers": hello.get("routers")},
        "congestion_control": "block",
        "processes": "router + publisher + subscriber (subprocess, no fork)",
        "cpus": os.cpu_count(),
        **_versions(),
        "goals": GOALS,
    }
    result["goals_met"] = {
        "latency_p50_ms": result["latency_p50_ms"] is not None and result["latency_p50_ms"] <= GOALS["latency_p50_ms"],
        "latency_p99_ms": result["latency_p99_ms"] is not None and result["latency_p99_ms"] <= GOALS["latency_p99_ms"],
        "rate_msgs_per_s": result["rate_msgs_per_s"] >= GOALS["rate_msgs_per_s"] and result["lost"] == 0,
    }
    return result


def format_result(result: dict, out: TextIO) -> None:
    met = result["goals_met"]
    mark = lambda k: "ok" if met[k] else "MISSED"   # noqa: E731
    out.write(f"bus bench ({result['mode']} mode, {result['route']}; {result['schema']} "
              f"{result['payload_bytes']} B, python {result['python']}, zenoh {result['zenoh']})\n")
    out.write(f"  latency p50 {result['latency_p50_ms']:.3f} ms  [goal <= {GOALS['latency_p50_ms']} ms: {mark('latency_p50_ms')}]\n")
    out.write(f"  latency p99 {result['latency_p99_ms']:.3f} ms  [goal <= {GOALS['latency_p99_ms']} ms: {mark('latency_p99_ms')}]\n")
    out.write(f"  latency p90 {result['latency_p90_ms']:.3f} ms, max {result['latency_max_ms']:.3f} ms, "
              f"{result['latency_messages']} messages\n")
    out.write(f"  throughput {result['rate_msgs_per_s']:.0f} msg/s, lost {result['lost']} of "
              f"{result['throughput_sent']}  [goal >= {GOALS['rate_msgs_per_s']:.0f} msg/s: {mark('rate_msgs_per_s')}]\n")
    out.write(f"  latency: {result['latency_method']}\n")


if __name__ == "__main__":
    sys.exit(child_main())
