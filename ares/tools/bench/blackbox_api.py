"""Throughput of the REST API's hot path: GET /api/v1/vehicles/{id}/latest over HTTPS.

    python -m ares.tools.bench.blackbox_api [--seconds S] [--connections N] [--json]

What runs where (loopback only):
- the API: `ares api` in its own process (uvicorn, one process, uvloop + httptools, TLS with the
  self-signed certificate), against an embedded store holding an hour of one vehicle's records;
- the load: a separate process with keep-alive connections, `wrk` (Debian package, see
  scripts/setup.sh) when installed, else this module's small asyncio load generator
  (`--loadgen`), which is named in the result.

The bench is one client hammering one address, which the production limits would rate-limit
and then blacklist by design; its server gets per-client limits raised out of the way (the
result says so). Everything else (TLS, token check, security headers) is the production path.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import os
import re
import secrets
import shutil
import ssl
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from datetime import UTC, datetime, timedelta
from pathlib import Path

from ares.core.localhost import free_port
from ares.tools.bench.common import percentile

VEHICLE = "bench01"
USER = "bench"


def _seed(path: Path, password: str, records: int = 3600) -> None:
    """An hour of a realistic vehicle's records, and a fleet user."""
    from ares.core.messages import Position, ProcessHealth, SensorHealth, VehicleRecord
    from blackbox.api.credentials import Argon2Settings, Passwords, add_user
    from blackbox.register.store.sqlite_store import SqliteStore

    store = SqliteStore(str(path))
    now = datetime.now(UTC).replace(microsecond=0)
    procs = {
        name: ProcessHealth(state="running")
        for name in (
            "simulator",
            "gnss",
            "localization",
            "odometry_manager",
            "path_manager",
            "controller",
            "dbw_bridge",
        )
    }
    batch = []
    for i in range(records):
        batch.append(
            VehicleRecord(
                vehicle_id=VEHICLE,
                time=now - timedelta(seconds=records - i),
                t=float(i),
                position=Position(
                    x=i * 0.5,
                    y=2.0,
                    z=0.1,
                    easting=440000.0 + i * 0.5,
                    northing=4474002.0,
                    zone=30,
                    hemisphere="N",
                    lat=40.41,
                    lon=-3.7,
                ),
                speed_mps=3.2,
                steering_wheel_deg=-12.5,
                mode="AUTOMATIC",
                scores={"odometry": 0.98},
                controller="pure_pursuit",
                sensors={
                    "gnss": SensorHealth(rate_hz=5.0, ok=True),
                    "imu": SensorHealth(rate_hz=50.0, ok=True),
                    "can": SensorHealth(rate_hz=20.0, ok=True),
                },
                processes=procs,
                events=0,
            )
        )
    store.insert_records(batch)
    add_user(store, Passwords(Argon2Settings()), USER, "fleet", password, 10)
    store.close()


def _parse_wrk(text: str) -> dict:
    def ms(value: str, unit: str) -> float:
        return float(value) * {"us": 1e-3, "ms": 1.0, "s": 1e3, "m": 6e4}[unit]

    out: dict = {}
    m = re.search(r"Requests/sec:\s+([\d.]+)", text)
    out["req_per_s"] = float(m.group(1)) if m else None
    m = re.search(r"(\d+) requests in", text)
    out["requests"] = int(m.group(1)) if m else None
    for pct, key in (("50", "latency_p50_ms"), ("99", "latency_p99_ms")):
        m = re.search(rf"^\s*{pct}(?:\.000)?%\s+([\d.]+)(us|ms|s|m)\b", text, re.M)
        out[key] = round(ms(*m.groups()), 3) if m else None
    errors = 0
    m = re.search(r"Non-2xx or 3xx responses:\s+(\d+)", text)
    if m:
        errors += int(m.group(1))
    m = re.search(r"Socket errors: connect (\d+), read (\d+), write (\d+), timeout (\d+)", text)
    if m:
        errors += sum(int(g) for g in m.groups())
    out["errors"] = errors
    return out


def _run_wrk(url: str, token: str, seconds: float, connections: int) -> dict:
    proc = subprocess.run(
        [
            "wrk",
            "-t1",
            f"-c{connections}",
            f"-d{max(1, round(seconds))}s",
            "--latency",
            "-H",
            f"Authorization: Bearer {token}",
            url,
        ],
        capture_output=True,
        text=True,
        timeout=seconds + 30,
    )
    if proc.returncode != 0:
        raise RuntimeError(f"wrk failed: {proc.stderr.strip() or proc.stdout.strip()}")
    return {"load_generator": "wrk 1 thread", **_parse_wrk(proc.stdout)}


def _run_python_loadgen(url: str, token: str, seconds: float, connections: int, cafile: str) -> dict:
    proc = subprocess.run(
        [
            sys.executable,
            "-m",
            "ares.tools.bench.blackbox_api",
            "--loadgen",
            url,
            "--token",
            token,
            "--seconds",
            str(seconds),
            "--connections",
            str(connections),
            "--cafile",
            cafile,
        ],
        capture_output=True,
        text=True,
        timeout=seconds + 60,
    )
    if proc.returncode != 0:
        raise RuntimeError(f"load generator failed: {proc.stderr.strip()[-500:]}")
    return {
        "load_generator": f"python asyncio, {connections} connections",
        **json.loads(proc.stdout.strip().splitlines()[-1]),
    }


def _start_api(tmp: Path, db: Path, say: Callable[[str], None]) -> tuple[subprocess.Popen, str, str]:
    """(the `ares api` process, its certificate file, its API's base URL), once it answers: on a
    free port, per-client limits raised out of the bench's way."""
    from ares.core import config
    from blackbox.api import ApiSettings

    port = free_port()
    cfg = config.core_defaults()
    cfg["api"] = ApiSettings.model_validate(
        {
            "state_dir": str(tmp),
            "host": "127.0.0.1",
            "port": port,
            "log_level": "warning",
            "rate_limit": {"client_per_s": 1e9, "client_burst": 1e9},
            "blacklist": {"abuse_requests_per_s": 1e10},
        }
    ).model_dump(mode="json")
    run_cfg = config.write_run_config(cfg, tmp / "run_config.json")
    env = {**os.environ, config.RUN_CONFIG_ENV: str(run_cfg)}
    env.pop("ARES_API_SECRET", None)
    say(f"starting `ares api` on https://127.0.0.1:{port}")
    # the server's output goes to a file: an unread pipe would fill up and stall it
    with open(tmp / "api.log", "w") as log_file:
        server = subprocess.Popen(
            [sys.executable, "-m", "ares.cli", "api", "--store", str(db)],
            env=env,
            stdout=log_file,
            stderr=subprocess.STDOUT,
        )
    cafile = str(tmp / "tls" / "api_cert.pem")
    base = f"https://127.0.0.1:{port}/api/v1"
    try:
        _wait_until_healthy(server, base, cafile, tmp / "api.log")
    except BaseException:
        _stop_server(server)
        raise
    return server, cafile, base


def _wait_until_healthy(server: subprocess.Popen, base: str, cafile: str, log: Path) -> None:
    import httpx

    deadline = time.monotonic() + 30
    while True:
        if server.poll() is not None:
            raise RuntimeError(f"the API exited: {log.read_text()[-800:]}")
        try:
            if os.path.exists(cafile) and httpx.get(f"{base}/health", verify=cafile, timeout=1).status_code == 200:
                return
        except httpx.HTTPError:
            pass
        if time.monotonic() > deadline:
            raise RuntimeError("the API did not answer within 30 s")
        time.sleep(0.1)


def _token(base: str, cafile: str, password: str) -> str:
    """The bench user's access token, once `latest` has answered with it as it should."""
    import httpx

    with httpx.Client(verify=cafile, timeout=5) as client:
        token = client.post(f"{base}/auth/token", data={"username": USER, "password": password}).json()["access_token"]
        check = client.get(f"{base}/vehicles/{VEHICLE}/latest", headers={"Authorization": f"Bearer {token}"})
        if check.status_code != 200 or check.json().get("vehicle_id") != VEHICLE:
            raise RuntimeError(f"latest answered {check.status_code}: {check.text[:200]}")
    return token


def _stop_server(server: subprocess.Popen) -> None:
    if server.poll() is None:
        server.terminate()
        try:
            server.wait(timeout=5)
        except subprocess.TimeoutExpired:
            server.kill()
            server.wait()


def run_api_bench(
    progress: Callable[[str], None] | None = None, seconds: float = 10.0, connections: int = 16, tool: str = "auto"
) -> dict:
    """Start the API over HTTPS in a subprocess, load `latest` from another one; the figures.
    `tool`: "wrk", "python" or "auto" (wrk when installed)."""
    say = progress or (lambda _msg: None)
    tmp = Path(tempfile.mkdtemp(prefix="ares-api-bench-"))
    server = None
    try:
        db = tmp / "blackbox.sqlite"
        password = secrets.token_urlsafe(16)
        say("seeding an embedded store with an hour of records")
        _seed(db, password)
        server, cafile, base = _start_api(tmp, db, say)
        token = _token(base, cafile, password)
        url = f"{base}/vehicles/{VEHICLE}/latest"
        if tool == "auto":
            tool = "wrk" if shutil.which("wrk") else "python"
        say(f"loading GET {url} for {seconds:g} s with {connections} keep-alive connections ({tool})")
        if tool == "wrk":
            result = _run_wrk(url, token, seconds, connections)
        else:
            result = _run_python_loadgen(url, token, seconds, connections, cafile)
        out = {
            "api_latest_req_per_s": round(result.pop("req_per_s") or 0.0, 1),
            **result,
            "seconds": seconds,
            "connections": connections,
            "server": "ares api: uvicorn, 1 process, uvloop + httptools, HTTPS (self-signed P-256)",
            "note": "per-client rate limit and abuse blacklist raised for this single-client bench",
            "cpus": os.cpu_count(),
        }
        say(
            f"{out['api_latest_req_per_s']:.0f} req/s, p50 {out.get('latency_p50_ms')} ms, "
            f"p99 {out.get('latency_p99_ms')} ms, {out.get('errors')} errors"
        )
        return out
    finally:
        if server is not None:
            _stop_server(server)
        shutil.rmtree(tmp, ignore_errors=True)


# ---- the fallback load generator (a separate process) --------------------------------------------


async def _loadgen(url: str, token: str, seconds: float, connections: int, cafile: str) -> dict:
    from urllib.parse import urlsplit

    parts = urlsplit(url)
    ctx = ssl.create_default_context(cafile=cafile) if parts.scheme == "https" else None
    request = (
        f"GET {parts.path} HTTP/1.1\r\nHost: {parts.netloc}\r\nAuthorization: Bearer {token}\r\n"
        "Connection: keep-alive\r\n\r\n"
    ).encode()
    latencies: list[float] = []
    errors = 0
    stop = time.monotonic() + seconds

    async def worker() -> None:
        nonlocal errors
        reader, writer = await asyncio.open_connection(parts.hostname, parts.port, ssl=ctx)
        try:
            while time.monotonic() < stop:
                t0 = time.perf_counter()
                writer.write(request)
                head = await reader.readuntil(b"\r\n\r\n")
                length = int(re.search(rb"(?i)content-length:\s*(\d+)", head).group(1))
                await reader.readexactly(length)
                latencies.append(time.perf_counter() - t0)
                if not head.startswith(b"HTTP/1.1 200"):
                    errors += 1
        finally:
            writer.close()

    started = time.monotonic()
    results = await asyncio.gather(*(worker() for _ in range(connections)), return_exceptions=True)
    elapsed = time.monotonic() - started
    errors += sum(1 for r in results if isinstance(r, BaseException))
    latencies_ms = [v * 1e3 for v in latencies]
    return {
        "req_per_s": len(latencies) / elapsed,
        "requests": len(latencies),
        "latency_p50_ms": percentile(latencies_ms, 50, 3),
        "latency_p99_ms": percentile(latencies_ms, 99, 3),
        "errors": errors,
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m ares.tools.bench.blackbox_api", description=__doc__.split("\n\n")[0])
    p.add_argument("--seconds", type=float, default=10.0)
    p.add_argument("--connections", type=int, default=16)
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.add_argument(
        "--tool",
        choices=["auto", "wrk", "python"],
        default="auto",
        help="load generator (default: wrk when installed, else the Python one)",
    )
    p.add_argument("--loadgen", metavar="URL", help=argparse.SUPPRESS)  # internal: be the load generator
    p.add_argument("--token", help=argparse.SUPPRESS)
    p.add_argument("--cafile", help=argparse.SUPPRESS)
    args = p.parse_args(argv)
    if args.loadgen:
        try:
            import uvloop

            uvloop.install()
        except ImportError:
            pass
        print(json.dumps(asyncio.run(_loadgen(args.loadgen, args.token, args.seconds, args.connections, args.cafile))))
        return 0
    result = run_api_bench(
        progress=lambda m: print(f"[bench] {m}", file=sys.stderr, flush=True),
        seconds=args.seconds,
        connections=args.connections,
        tool=args.tool,
    )
    print(json.dumps(result) if args.json else "\n".join(f"{k}: {v}" for k, v in result.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
