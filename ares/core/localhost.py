"""Processes and ports on this machine, for whoever starts them (benches, tests, tools)."""

from __future__ import annotations

import os
import random
import signal
import socket
import subprocess
import time
from typing import Any

_PICK = random.SystemRandom()  # not the global generator, which a test may have seeded


def free_port() -> int:
    """A TCP port on 127.0.0.1 that nothing uses now, below the kernel's ephemeral range: a port
    from that range (what binding port 0 gives) may meanwhile become the local end of one of the
    many outgoing connections a starting stack opens, and a server meant to listen on it then
    never can (seen: a stack's API waiting for its port while a Zenoh link held it)."""
    low, _ = _ephemeral_range()
    if low > 12_000:
        for _ in range(100):
            port = _PICK.randint(10_000, low - 1)
            with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
                try:
                    s.bind(("127.0.0.1", port))
                except OSError:
                    continue
                return port
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _ephemeral_range() -> tuple[int, int]:
    try:
        low, high = open("/proc/sys/net/ipv4/ip_local_port_range").read().split()
        return int(low), int(high)
    except (OSError, ValueError):
        return 49152, 65535  # the IANA range (macOS, Windows)


def wait_for_port(port: int, timeout_s: float = 10.0, proc: subprocess.Popen[Any] | None = None) -> None:
    """Until something listens on 127.0.0.1:port; TimeoutError after timeout_s, RuntimeError if
    `proc` (the process meant to listen) exits first."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if proc is not None and proc.poll() is not None:
            raise RuntimeError(f"process {proc.pid} exited with code {proc.returncode} before listening")
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=0.2):
                return
        except OSError:
            time.sleep(0.05)
    raise TimeoutError(f"nothing listens on 127.0.0.1:{port} after {timeout_s:g} s")


def stop_process(proc: subprocess.Popen[Any], timeout_s: float = 3.0, group: bool = False) -> None:
    """SIGTERM (its process group if `group`), then SIGKILL if it does not go within timeout_s."""
    for sig, wait_s in ((signal.SIGTERM, timeout_s), (signal.SIGKILL, 5.0)):
        if proc.poll() is not None:
            return
        try:
            if group:
                os.killpg(proc.pid, sig)
            else:
                proc.send_signal(sig)
        except ProcessLookupError:
            return
        try:
            proc.wait(timeout=wait_s)
            return
        except subprocess.TimeoutExpired:
            continue
