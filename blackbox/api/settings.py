"""The REST API's settings (the `api:` section of the stack configuration), where the API
keeps its own state, and where it is served (PREFIX)."""

import os
from pathlib import Path
from typing import Any

from pydantic import model_validator

from ares.core.config import Params, param
from blackbox.api.connections import ConnectionSettings
from blackbox.api.credentials import AuthSettings
from blackbox.api.security import BlacklistSettings, HeaderSettings, RateLimitSettings
from blackbox.api.tls import TlsSettings
from blackbox.console.live_hub import LiveSettings

# fixed, not configurable: clients, the supervisor (api_url) and the token scheme rely on it
PREFIX = "/api/v1"
TOKEN_PATH = f"{PREFIX}/auth/token"


class LimitSettings(Params):
    default_window_s: float = param(3600.0, "start/end omitted: the last hour", unit="s", gt=0)
    start_grace_s: float = param(
        300.0,
        "a start up to this long before the 7-day retention is served as asked, "
        'not clipped (a client\'s "now - 7 days" computed a moment earlier)',
        unit="s",
        ge=0,
    )
    default_page_size: int = param(100, "items per page when not asked", ge=1)
    max_page_size: int = param(1000, "most items per page", ge=1, le=10000)
    max_page: int = param(100_000, "highest page number", ge=1)
    export_batch: int = param(2000, "records per store query while streaming an export", ge=1)
    reliability_batch: int = param(5000, "records per store query while computing reliability", ge=1)
    reliability_piece_s: float = param(
        3600.0, "reliability is tallied in pieces this long (since 1970, UTC), each settled one cached", unit="s", gt=0
    )
    reliability_settle_s: float = param(60.0, "a piece ended this long ago is settled", unit="s", ge=0)
    reliability_cache_pieces: int = param(20_000, "cached pieces' tallies (vehicles x 168 hours)", ge=1)
    max_t_hours: float = param(100_000.0, "largest t of R(t)", unit="h", gt=0)
    max_body_bytes: int = param(8192, "request bodies are a login form or a new user: small", unit="B", ge=256)
    latest_cache_s: float = param(
        1.0, "latest record per vehicle cached this long (a record is written each second)", unit="s", ge=0.0, le=1.0
    )
    vehicles_cache_s: float = param(
        5.0, "known vehicle ids (an unknown id re-reads them once before 404)", unit="s", ge=0.0
    )


class ApiSettings(Params):
    """The `api` section: the black box's REST API, the vehicle's only outside service (ARES §3.8)."""

    host: str = param("127.0.0.1", "where it listens; deployment: the VPN-facing address (0.0.0.0 in its container)")
    port: int = param(8443, "HTTPS port", ge=0, le=65535)
    state_dir: str | None = param(
        None, "token key (api_secret) and self-signed certificate; null: next to the embedded store's file"
    )
    docs: bool = param(
        False, "interactive /docs and /redoc (their scripts need a looser CSP); /openapi.json is always served"
    )
    access_log: bool = param(False, "one log line per request costs ~20 % of the latest endpoint's throughput")
    log_level: str = param("info", "uvicorn's log level")
    keep_alive_s: int = param(5, "HTTP keep-alive", unit="s", ge=1, le=300)
    limit_concurrency: int | None = param(1000, "connections+requests in flight beyond this get 503", ge=1)
    connections: ConnectionSettings = param(
        doc="per address: open connections; per connection: TLS handshake, header and read timeouts",
        factory=ConnectionSettings,
    )
    cors_origins: list[str] = param(doc="browsers' cross-origin calls: closed unless origins are listed", factory=list)
    limits: LimitSettings = param(doc="query limits and caches", factory=LimitSettings)
    auth: AuthSettings = param(doc="tokens and passwords", factory=AuthSettings)
    tls: TlsSettings = param(doc="HTTPS", factory=TlsSettings)
    rate_limit: RateLimitSettings = param(doc="per-client rate limits", factory=RateLimitSettings)
    blacklist: BlacklistSettings = param(doc="abnormal flows", factory=BlacklistSettings)
    headers: HeaderSettings = param(doc="security headers", factory=HeaderSettings)
    live: LiveSettings = param(doc="the live gateway the pages read (server-sent events)", factory=LiveSettings)

    @model_validator(mode="after")
    def _within_the_rate_limit_is_never_abnormal(self) -> "ApiSettings":
        # A client that is never refused by its bucket sends at most client_burst + client_per_s * T
        # requests in any T seconds; the abuse estimate (blacklist) of such a client stays at or
        # below that over abuse_window_s. Keep it under the abuse threshold, so that a client that
        # keeps to its rate limit is never blacklisted.
        rl, bl = self.rate_limit, self.blacklist
        most = rl.client_burst + rl.client_per_s * bl.abuse_window_s
        if most > bl.abuse_requests_per_s * bl.abuse_window_s:
            raise ValueError(
                f"rate_limit and blacklist disagree: a client keeping to its rate limit (client_burst "
                f"{rl.client_burst:g} + client_per_s {rl.client_per_s:g}/s) may send {most:g} requests in "
                f"abuse_window_s ({bl.abuse_window_s:g} s), more than blacklist.abuse_requests_per_s "
                f"({bl.abuse_requests_per_s:g}/s) allows: it would be blacklisted"
            )
        return self


def state_dir(settings: ApiSettings, store: Any) -> Path:
    """Where the API keeps its token key and certificate: configured, else beside the embedded
    store's file, else the user's state directory (a MongoDB store has no file)."""
    if settings.state_dir:
        return Path(settings.state_dir).expanduser()
    path = getattr(store, "path", None)
    if path:
        return Path(path).expanduser().resolve().parent
    base = os.environ.get("XDG_STATE_HOME") or os.path.expanduser("~/.local/state")
    return Path(base) / "ares"
