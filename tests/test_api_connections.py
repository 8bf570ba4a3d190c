"""Bounded work per caller at the connection level (issue 42): a real `ares api` over HTTPS,
held by unfinished TLS handshakes and slow-header clients from other loopback addresses,
still answers /health; the cap per address drops the excess at once and the timeouts close
the rest."""

from __future__ import annotations

import socket
import ssl
import time

import httpx
import pytest

from ares.core.localhost import free_port
from tests.helpers.api import open_test_store, seed, start_api_process, stop_api_process, wait_serving

PER_ADDRESS = 8
TIMEOUT_S = 2.0
# a TLS record header and the start of a ClientHello that never gets its remaining bytes
HALF_CLIENT_HELLO = bytes([0x16, 0x03, 0x01, 0x02, 0x00, 0x01, 0x00, 0x01, 0xFC, 0x03, 0x03])


def connect_from(source: str, port: int) -> socket.socket:
    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    sock.bind((source, 0))
    sock.settimeout(5)
    sock.connect(("127.0.0.1", port))
    return sock


def closed_by_server(sock: socket.socket) -> bool:
    """True when the server has closed or reset the connection (no wait: what is there now)."""
    sock.setblocking(False)
    try:
        return sock.recv(1) == b""
    except (BlockingIOError, ssl.SSLWantReadError):
        return False
    except OSError:  # reset, or a TLS alert / EOF in the middle of a record
        return True
    finally:
        sock.setblocking(True)


def trickle(sock: socket.socket) -> bool:
    """One more header byte; False when the server has already shut the connection."""
    try:
        sock.sendall(b"x")
        return True
    except OSError:
        return False


@pytest.mark.timeout(90)
def test_slow_and_unfinished_connections_leave_health_answering(tmp_path):
    db = tmp_path / "blackbox.sqlite"
    store = open_test_store(db)
    seed(store)
    store.close()
    port = free_port()
    limits = {
        "per_address": PER_ADDRESS,
        "tls_handshake_timeout_s": TIMEOUT_S,
        "header_timeout_s": TIMEOUT_S,
        "read_timeout_s": TIMEOUT_S,
    }
    server = start_api_process(tmp_path, db, port, api={"connections": limits})
    held: list[socket.socket] = []
    try:
        wait_serving(server, port)
        tls = ssl.create_default_context(cafile=str(tmp_path / "state" / "tls" / "api_cert.pem"))
        health = f"https://127.0.0.1:{port}/api/v1/health"
        assert httpx.get(health, verify=tls, timeout=5).status_code == 200

        unfinished = []  # 25 TLS handshakes that never finish, from 127.0.0.2
        for _ in range(25):
            sock = connect_from("127.0.0.2", port)
            sock.sendall(HALF_CLIENT_HELLO)
            unfinished.append(sock)
        slow = []  # 25 clients whose headers never end, from 127.0.0.3 (those the cap let in)
        for _ in range(25):
            raw = connect_from("127.0.0.3", port)
            try:
                conn = tls.wrap_socket(raw, server_hostname="127.0.0.1")
                conn.sendall(b"GET /api/v1/health HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: ")
                slow.append(conn)
            except OSError:
                raw.close()  # dropped at accept: over the cap
        held = unfinished + slow
        time.sleep(0.3)
        # the cap: no address holds more than PER_ADDRESS open connections
        assert sum(not closed_by_server(s) for s in unfinished) <= PER_ADDRESS
        assert 0 < len(slow) <= PER_ADDRESS

        latencies = []
        for _ in range(5):
            began = time.monotonic()
            r = httpx.get(health, verify=tls, timeout=5)
            latencies.append(time.monotonic() - began)
            assert r.status_code == 200 and r.json()["status"] == "ok"
            for conn in slow:
                trickle(conn)
            time.sleep(0.2)
        print(f"/health under the held connections: worst {max(latencies) * 1000:.1f} ms of {len(latencies)}")

        # the timeouts: every held connection is closed, though the slow ones keep sending bytes
        deadline = time.monotonic() + TIMEOUT_S + 8
        while time.monotonic() < deadline:
            alive_slow = [c for c in slow if trickle(c) and not closed_by_server(c)]
            alive_unfinished = [s for s in unfinished if not closed_by_server(s)]
            if not alive_slow and not alive_unfinished:
                break
            time.sleep(0.25)
        assert not alive_unfinished, f"{len(alive_unfinished)} unfinished TLS handshakes still open"
        assert not alive_slow, f"{len(alive_slow)} slow-header connections still open"
        assert httpx.get(health, verify=tls, timeout=5).status_code == 200
    finally:
        for sock in held:
            sock.close()
        stop_api_process(server)
