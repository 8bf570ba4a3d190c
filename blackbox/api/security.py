"""Front door of the REST API: per-client rate limits, the IP blacklist, security headers.

ARES §3.8: "If the REST API service detects an abnormal flow of requests from a specific IP it
will ignore the requests received from that source, entering a blacklist of untrusted sources
and notifying those responsible."

- Rate limits (token buckets, per client IP): every request spends from the client bucket
  (`client_per_s`, `client_burst`); a login attempt also from a much smaller login bucket
  (`token_per_s`, `token_burst`) so passwords cannot be guessed quickly. An empty bucket -> 429
  with Retry-After.
- Blacklist: an IP whose flow is abnormal is refused for `duration_s`: every request -> 403.
  Abnormal is either `failed_logins` failed or refused (429) login attempts within
  `failed_logins_window_s`, or more than `abuse_requests_per_s` requests per second averaged
  over `abuse_window_s` (counted whether they were served or refused: a client that keeps
  hammering after its 429s is no dashboard). Each blacklisting is written to the black box as
  an event (source "api", kind "ip_blacklisted", level WARNING) and logged.
- Accounts: guesses spread over many addresses stay under every address's limits, so failures
  are counted per account name too: `account_failed_logins` failed logins of one name within
  `account_window_s` (from any addresses) lock that name's logins for `account_lock_s` (429
  with Retry-After, even with the right password; the account's tokens keep working).
- Headers: every response carries HSTS, nosniff, X-Frame-Options DENY, no referrer, a CSP that
  allows nothing (the API serves JSON, never pages), and Cache-Control no-store (records and
  tokens must not linger in caches).

State is in memory, per API process (the API runs as one process on the vehicle), bounded by
`max_clients`; the blacklist and the account locks are also kept in a file (`ban_file`, in the
API's state directory), so that a restart does not let a banned address or a locked name in.
The client is the TCP peer: no X-Forwarded-For is trusted, as the API faces the VPN directly
(ARES §3.8: port 443 is the vehicle's only open port).
"""

from __future__ import annotations

import logging
import os
import threading
import time
from collections import Counter, deque
from collections.abc import Awaitable, Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import datetime, timedelta
from pathlib import Path

import orjson

from ares.core.config import Params, param

log = logging.getLogger("blackbox.api.security")

BAN_FILE = "api_bans.json"  # in the API's state directory, beside its token key


class RateLimitSettings(Params):
    """Per client IP, token buckets -> 429 with Retry-After."""

    client_per_s: float = param(50.0, "any request, sustained", unit="1/s", gt=0)
    client_burst: float = param(100.0, "any request, burst", ge=1)
    token_per_s: float = param(0.05, "login attempts: one per 20 s sustained ...", unit="1/s", gt=0)
    token_burst: float = param(5.0, "... after a burst of 5", ge=1)
    max_clients: int = param(100_000, "IPs tracked at once (memory bound)", ge=100)
    reports_per_role: int = param(
        2, "reliability reports computed at once per role (each may read a week of records); more: 429", ge=1
    )


class BlacklistSettings(Params):
    """An abnormal flow -> every request from that IP gets 403 for duration_s, event ip_blacklisted."""

    failed_logins: int = param(10, "failed or refused (429) logins ...", ge=1)
    failed_logins_window_s: float = param(300.0, "... within this window", unit="s", gt=0)
    abuse_requests_per_s: float = param(100.0, "or more requests per second than this ...", unit="1/s", gt=0)
    abuse_window_s: float = param(10.0, "... averaged over this window", unit="s", gt=0)
    duration_s: float = param(900.0, "how long an IP stays blacklisted", unit="s", gt=0)
    account_failed_logins: int = param(10, "failed logins of one user name, from any addresses ...", ge=1)
    account_window_s: float = param(300.0, "... within this window ...", unit="s", gt=0)
    account_lock_s: float = param(900.0, "... lock that name's logins this long (429)", unit="s", gt=0)


class HeaderSettings(Params):
    content_security_policy: str = param("default-src 'none'; frame-ancestors 'none'", "Content-Security-Policy")
    page_content_security_policy: str = param(
        "default-src 'none'; script-src 'self'; style-src 'self'; img-src 'self' data: blob:; connect-src 'self'; "
        "font-src 'self'; base-uri 'none'; form-action 'self'; frame-ancestors 'none'",
        "Content-Security-Policy of the pages and their assets: their own scripts, styles and images only, no "
        "inline script, nothing from elsewhere",
    )
    hsts_max_age_s: int = param(31_536_000, "Strict-Transport-Security max-age", unit="s", ge=0)


def security_headers(cfg: HeaderSettings, page: bool = False) -> list[tuple[bytes, bytes]]:
    """Every response's headers; `page`: those of the web pages and their assets (a CSP that lets
    them run their own scripts and call the API, and nothing else)."""
    csp = cfg.page_content_security_policy if page else cfg.content_security_policy
    return [
        (b"strict-transport-security", f"max-age={cfg.hsts_max_age_s}; includeSubDomains".encode()),
        (b"x-content-type-options", b"nosniff"),
        (b"x-frame-options", b"DENY"),
        (b"referrer-policy", b"no-referrer"),
        (b"content-security-policy", csp.encode()),
        (b"cache-control", b"no-store"),
    ]


@dataclass
class Verdict:
    status: int  # 403 blacklisted, 429 rate-limited
    detail: str
    retry_after_s: int
    newly_blacklisted: str | None = None  # the reason, when this request got the IP blacklisted


class _Client:
    __slots__ = ("tokens", "login_tokens", "stamp", "win_start", "win_count", "prev_count", "failures", "seen")

    def __init__(self, now: float, cfg: RateLimitSettings):
        self.tokens = cfg.client_burst
        self.login_tokens = cfg.token_burst
        self.stamp = now
        self.win_start = now
        self.win_count = 0
        self.prev_count = 0
        self.failures: deque[float] = deque()
        self.seen = now


class Guard:
    """Rate limits, blacklist and account-lock decisions; no I/O but its `ban_file` (the caller
    writes the events)."""

    def __init__(
        self,
        limits: RateLimitSettings,
        blacklist: BlacklistSettings,
        now: Callable[[], float] = time.monotonic,
        ban_file: Path | None = None,
        wall: Callable[[], float] = time.time,
    ):
        self.limits = limits
        self.cfg = blacklist
        self.now = now
        self.wall = wall  # the ban file's clock: monotonic times do not survive a restart
        self.clients: dict[str, _Client] = {}
        self.blacklist: dict[str, float] = {}  # ip -> monotonic time it is let in again
        self.account_failures: dict[str, deque[float]] = {}
        self.locked_accounts: dict[str, float] = {}  # user name -> monotonic time its logins are let in again
        self.reports_in_flight: Counter[str] = Counter()  # role -> reports being computed
        # the middleware calls in from the event loop, the login handler from a worker thread
        self._lock = threading.Lock()
        self.ban_file = ban_file
        if ban_file is not None:
            self._load_bans(ban_file)

    # ---- the ban file ----------------------------------------------------------------------------

    def _load_bans(self, path: Path) -> None:
        """The bans of an earlier run that still hold; an unreadable file is logged and ignored
        (the API must start), a missing one is a first start."""
        try:
            saved = orjson.loads(path.read_bytes())
            addresses, accounts = dict(saved["addresses"]), dict(saved["accounts"])
        except FileNotFoundError:
            return
        except (OSError, ValueError, KeyError, TypeError) as exc:
            log.error("REST API: ban file %s unreadable (%s): starting with no bans", path, exc)
            return
        now, wall = self.now(), self.wall()
        self.blacklist = {ip: now + until - wall for ip, until in addresses.items() if float(until) > wall}
        self.locked_accounts = {name: now + until - wall for name, until in accounts.items() if float(until) > wall}

    def _save_bans(self) -> None:
        """Written whole at each new ban (rare: each takes a flood or many failures), replaced
        atomically so a crash mid-write leaves the previous list."""
        if self.ban_file is None:
            return
        now, wall = self.now(), self.wall()
        body = orjson.dumps(
            {
                "addresses": {ip: wall + until - now for ip, until in self.blacklist.items() if until > now},
                "accounts": {name: wall + until - now for name, until in self.locked_accounts.items() if until > now},
            }
        )
        try:
            self.ban_file.parent.mkdir(parents=True, exist_ok=True)
            partial = self.ban_file.with_suffix(".partial")
            partial.write_bytes(body)
            os.replace(partial, self.ban_file)
        except OSError as exc:
            log.error("REST API: could not keep the bans in %s (%s): they hold until a restart", self.ban_file, exc)

    def _client(self, ip: str, now: float) -> _Client:
        client = self.clients.get(ip)
        if client is None:
            if len(self.clients) >= self.limits.max_clients:
                self._prune(now)
            client = self.clients[ip] = _Client(now, self.limits)
        return client

    def _prune(self, now: float) -> None:
        idle = max(self.cfg.abuse_window_s * 2, self.cfg.failed_logins_window_s)
        self.clients = {ip: c for ip, c in self.clients.items() if now - c.seen < idle}
        self.blacklist = {ip: until for ip, until in self.blacklist.items() if until > now}
        if len(self.clients) >= self.limits.max_clients:
            self.clients.clear()  # flooded by distinct addresses: forget rather than grow

    def _prune_accounts(self, now: float) -> None:
        window = self.cfg.account_window_s
        self.account_failures = {n: f for n, f in self.account_failures.items() if f and now - f[-1] < window}
        self.locked_accounts = {n: until for n, until in self.locked_accounts.items() if until > now}
        if len(self.account_failures) >= self.limits.max_clients:
            self.account_failures.clear()  # guesses at endless distinct names: forget rather than grow

    def _ban(self, ip: str, now: float, reason: str) -> Verdict:
        self.blacklist[ip] = now + self.cfg.duration_s
        self.clients.pop(ip, None)
        self._save_bans()
        return Verdict(
            403,
            f"address blacklisted for {self.cfg.duration_s:g} s: {reason}",
            int(self.cfg.duration_s),
            newly_blacklisted=reason,
        )

    def blacklisted(self, ip: str) -> float | None:
        """Seconds the IP stays blacklisted, or None."""
        with self._lock:
            return self._blacklisted(ip)

    def _blacklisted(self, ip: str) -> float | None:
        until = self.blacklist.get(ip)
        if until is None:
            return None
        left = until - self.now()
        if left <= 0:
            del self.blacklist[ip]
            return None
        return left

    def admit(self, ip: str, login: bool = False) -> Verdict | None:
        """None to serve the request, else the refusal."""
        with self._lock:
            return self._admit(ip, login)

    def _admit(self, ip: str, login: bool) -> Verdict | None:
        now = self.now()
        left = self._blacklisted(ip)
        if left is not None:
            return Verdict(403, "address blacklisted after an abnormal flow of requests", int(left) + 1)
        c = self._client(ip, now)
        c.seen = now
        # abnormal flow: sliding-window estimate of the request rate (two fixed windows blended)
        window = self.cfg.abuse_window_s
        elapsed = now - c.win_start
        if elapsed >= window:
            c.prev_count = c.win_count if elapsed < 2 * window else 0
            c.win_start += window * int(elapsed // window)
            c.win_count = 0
            elapsed = now - c.win_start
        c.win_count += 1
        estimate = c.prev_count * (1.0 - elapsed / window) + c.win_count
        if estimate > self.cfg.abuse_requests_per_s * window:
            return self._ban(ip, now, f"more than {self.cfg.abuse_requests_per_s:g} requests/s over {window:g} s")
        # token buckets
        lim = self.limits
        dt = now - c.stamp
        c.stamp = now
        c.tokens = min(lim.client_burst, c.tokens + dt * lim.client_per_s)
        c.login_tokens = min(lim.token_burst, c.login_tokens + dt * lim.token_per_s)
        if c.tokens < 1.0:
            return Verdict(429, "too many requests: slow down", int((1.0 - c.tokens) / lim.client_per_s) + 1)
        if login and c.login_tokens < 1.0:
            refused = Verdict(
                429,
                "too many login attempts: wait before trying again",
                int((1.0 - c.login_tokens) / lim.token_per_s) + 1,
            )
            return self._login_failed(ip) or refused
        c.tokens -= 1.0
        if login:
            c.login_tokens -= 1.0
        return None

    def login_failed(self, ip: str) -> Verdict | None:
        """Count a failed (or refused) login; the blacklisting Verdict when that was one too many."""
        with self._lock:
            return self._login_failed(ip)

    def _login_failed(self, ip: str) -> Verdict | None:
        now = self.now()
        c = self._client(ip, now)
        c.failures.append(now)
        while c.failures and now - c.failures[0] > self.cfg.failed_logins_window_s:
            c.failures.popleft()
        if len(c.failures) >= self.cfg.failed_logins:
            return self._ban(ip, now, f"{len(c.failures)} failed logins within {self.cfg.failed_logins_window_s:g} s")
        return None

    # ---- expensive reports -----------------------------------------------------------------------

    @contextmanager
    def report_slot(self, role: str) -> Iterator[bool]:
        """Whether a report may be computed for a caller of `role` now (held while it is); a role's
        callers share `reports_per_role` slots, so the lowest role cannot take every core."""
        with self._lock:
            admitted = self.reports_in_flight[role] < self.limits.reports_per_role
            if admitted:
                self.reports_in_flight[role] += 1
        try:
            yield admitted
        finally:
            if admitted:
                with self._lock:
                    self.reports_in_flight[role] -= 1

    # ---- accounts ----------------------------------------------------------------------------------

    def account_locked(self, name: str) -> Verdict | None:
        """The refusal of a login as `name` while that name is locked, else None."""
        with self._lock:
            until = self.locked_accounts.get(name)
            if until is None:
                return None
            left = until - self.now()
            if left <= 0:
                del self.locked_accounts[name]
                return None
            return Verdict(429, "too many failed logins for this user: wait before trying again", int(left) + 1)

    def account_failed(self, name: str) -> str | None:
        """Count a failed login as `name`; the reason, when this failure locked the name."""
        with self._lock:
            now = self.now()
            failures = self.account_failures.get(name)
            if failures is None:
                if len(self.account_failures) >= self.limits.max_clients:
                    self._prune_accounts(now)
                failures = self.account_failures[name] = deque()
            failures.append(now)
            while failures and now - failures[0] > self.cfg.account_window_s:
                failures.popleft()
            if len(failures) < self.cfg.account_failed_logins:
                return None
            del self.account_failures[name]
            self.locked_accounts[name] = now + self.cfg.account_lock_s
            self._save_bans()
            reason = f"{len(failures)} failed logins within {self.cfg.account_window_s:g} s"
            log.warning("REST API: logins as %r locked for %g s (%s)", name, self.cfg.account_lock_s, reason)
            return reason


def client_ip(scope) -> str:
    client = scope.get("client")
    return client[0] if client else "unknown"


def is_login(scope, token_path: str) -> bool:
    return scope["path"] == token_path and scope["method"] == "POST"


class SecurityMiddleware:
    """Pure ASGI (no per-request task or body buffering): the guard, then the headers."""

    def __init__(
        self,
        app,
        guard: Guard,
        headers: list[tuple[bytes, bytes]],
        token_path: str,
        on_blacklist: Callable[[str, str, float], Awaitable[None]],
        page_headers: list[tuple[bytes, bytes]] | None = None,
        page_paths: tuple[str, ...] = (),
        page_prefixes: tuple[str, ...] = (),
    ):
        self.app = app
        self.guard = guard
        self.headers = headers
        self.page_headers = page_headers or headers
        self.page_paths = page_paths  # the pages
        self.page_prefixes = page_prefixes  # ... and their assets' folders
        self.token_path = token_path
        self.on_blacklist = on_blacklist

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        path = scope["path"]
        is_page = path in self.page_paths or path.startswith(self.page_prefixes)
        extra = self.page_headers if is_page else self.headers

        async def send_with_headers(message):
            if message["type"] == "http.response.start":
                message["headers"] = [*message.get("headers", ()), *extra]
            await send(message)

        ip = client_ip(scope)
        verdict = self.guard.admit(ip, login=is_login(scope, self.token_path))
        if verdict is None:
            await self.app(scope, receive, send_with_headers)
            return
        if verdict.newly_blacklisted:
            await self.on_blacklist(ip, verdict.newly_blacklisted, self.guard.cfg.duration_s)
        body = orjson.dumps({"detail": verdict.detail})
        await send_with_headers(
            {
                "type": "http.response.start",
                "status": verdict.status,
                "headers": [
                    (b"content-type", b"application/json"),
                    (b"content-length", str(len(body)).encode()),
                    (b"retry-after", str(verdict.retry_after_s).encode()),
                ],
            }
        )
        await send_with_headers({"type": "http.response.body", "body": body})


def blacklist_event(vehicle_id: str, ip: str, reason: str, duration_s: float, now: datetime, t: float):
    """The StoredEvent that tells those responsible (auditors read events; fleet GUIs show them)."""
    from ares.core.messages import EventLevel, StoredEvent

    until = now + timedelta(seconds=duration_s)
    return StoredEvent(
        vehicle_id=vehicle_id,
        time=now,
        t=t,
        source="api",
        kind="ip_blacklisted",
        level=EventLevel.WARNING,
        message=f"REST API: {ip} blacklisted until {until.isoformat()} ({reason})",
        data={"ip": ip, "reason": reason, "duration_s": float(duration_s)},
    )
