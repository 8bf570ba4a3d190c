"""Who may use the REST API: users with Argon2 password hashes, and short-lived signed tokens.

- Users live in the black box store (RecordStore.get_user/put_user/list_users); the password
  hash is Argon2id (argon2-cffi) and is re-hashed on the next successful login whenever the
  configured cost parameters change, so stored hashes follow the configuration.
- Tokens are JWTs signed with an HMAC key (HS256 by default). Decoding always names the one
  accepted algorithm, so `alg: none` and algorithm-confusion tokens are refused, and requires
  exp/iat/sub/role/iss. A token lives `token_ttl_s` (15 min); a holder renews it before it
  expires (ARES §3.8: "a time-limited token they must renew").
- The key comes from the file `auth.secret_file` when set (a deployment's compose secret), else
  from the environment variable `auth.secret_env` when set, else from a file
  `api_secret` in the API's state directory, created on first use (0600) and kept, so tokens
  survive a restart of the API.
- Verified tokens are cached for a few seconds (never past their expiry): a dashboard polling
  `latest` many times a second must not pay an HMAC and a JSON parse each time. A user removed
  or demoted keeps what their current token allows until it expires (at most token_ttl_s).
"""

from __future__ import annotations

import os
import re
import secrets
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import argon2
import jwt

from ares.core.config import Params, param, read_secret
from blackbox.register.store.record_store import RecordStore, User, utc_now

ROLES = ("auditor", "operator", "fleet", "admin")
USERNAME_RE = re.compile(r"^[a-z][a-z0-9_.-]{1,31}$")
MAX_PASSWORD_CHARS = 256
MAX_TOKEN_CHARS = 4096  # a real token is ~300 characters: anything huge is refused unread
SECRET_FILE = "api_secret"


class Argon2Settings(Params):
    """argon2id cost (argon2-cffi's defaults, RFC 9106 low-memory profile); hashes are upgraded at
    the next login. Tests lower them for speed."""

    time_cost: int = param(3, "iterations", ge=1, le=20)
    memory_kib: int = param(65536, "memory per hash", unit="KiB", ge=8, le=1 << 21)
    parallelism: int = param(4, "lanes", ge=1, le=64)


class AuthSettings(Params):
    algorithm: str = param("HS256", "JWT signature; decoding accepts this algorithm only", pattern=r"^HS(256|384|512)$")
    token_ttl_s: int = param(
        900, "token lifetime; POST /auth/renew with a valid token gives a fresh one", unit="s", ge=30, le=86400
    )
    issuer: str = param("ares-api", "the tokens' issuer")
    secret_file: str | None = param(
        None, "signing key from this file (a compose secret, >= 32 characters); null: secret_env, then the state dir"
    )
    secret_env: str = param(
        "ARES_API_SECRET", "signing key from this variable when set (>= 32 chars), else <state_dir>/api_secret"
    )
    verify_cache_s: float = param(
        5.0,
        "a verified token is trusted this long without re-checking its signature (never past exp)",
        unit="s",
        ge=0.0,
        le=60.0,
    )
    verify_cache_max: int = param(10000, "verified tokens remembered at most", ge=0)
    min_password_length: int = param(10, "shortest password accepted", ge=1, le=MAX_PASSWORD_CHARS)
    argon2: Argon2Settings = param(doc="password hashing cost", factory=Argon2Settings)


class AuthError(Exception):
    """Not authenticated (401): missing, malformed, expired or forged credentials."""


class UserError(ValueError):
    """A user cannot be created as asked (bad name, role or password, or already exists)."""


@dataclass(frozen=True)
class Claims:
    name: str
    role: str
    expires: float  # epoch seconds


# ---- passwords ------------------------------------------------------------------------------


class Passwords:
    """Argon2id hashing with the configured cost, and login checks against the store."""

    def __init__(self, cfg: Argon2Settings):
        self.hasher = argon2.PasswordHasher(
            time_cost=cfg.time_cost, memory_cost=cfg.memory_kib, parallelism=cfg.parallelism
        )
        self._decoy: str | None = None

    def decoy(self) -> str:
        """Verified against when the user does not exist, so an unknown name costs as much time
        as a wrong password and login timing does not reveal which names exist."""
        if self._decoy is None:
            self._decoy = self.hasher.hash(secrets.token_hex(16))
        return self._decoy

    def hash(self, password: str) -> str:
        return self.hasher.hash(password)

    def authenticate(self, store: RecordStore, name: str, password: str) -> User | None:
        """The user when the password is right, else None. Re-hashes an outdated hash."""
        user = store.get_user(name) if USERNAME_RE.match(name) else None
        try:
            self.hasher.verify(user.password_hash if user else self.decoy(), password)
        except argon2.exceptions.VerificationError:
            return None
        except argon2.exceptions.InvalidHashError:
            return None
        if user is None:
            return None
        if self.hasher.check_needs_rehash(user.password_hash):
            user = User(name=user.name, role=user.role, password_hash=self.hasher.hash(password), created=user.created)
            store.put_user(user)
        return user


def check_new_user(name: str, role: str, password: str, min_length: int) -> None:
    if not USERNAME_RE.match(name):
        raise UserError(
            f"invalid user name {name!r}: 2-32 characters, lower-case letters, digits, '_', '.', '-', "
            "starting with a letter"
        )
    if role not in ROLES:
        raise UserError(f"unknown role {role!r}; roles: {', '.join(ROLES)}")
    if len(password) < min_length:
        raise UserError(f"password too short: at least {min_length} characters")
    if len(password) > MAX_PASSWORD_CHARS:
        raise UserError(f"password too long: at most {MAX_PASSWORD_CHARS} characters")


def add_user(store: RecordStore, passwords: Passwords, name: str, role: str, password: str, min_length: int) -> User:
    check_new_user(name, role, password, min_length)
    if store.get_user(name) is not None:
        raise UserError(f"user {name!r} already exists")
    user = User(name=name, role=role, password_hash=passwords.hash(password), created=utc_now())
    store.put_user(user)
    return user


# ---- tokens ---------------------------------------------------------------------------------


def load_secret(cfg: AuthSettings, state_dir: Path) -> bytes:
    """The signing key: the configured file, else the environment when set, else the state directory's file."""
    if cfg.secret_file:
        text = read_secret(cfg.secret_file, "api.auth.secret_file")  # a ConfigError is a ValueError
        if len(text) < 32:
            raise ValueError(f"api.auth.secret_file {cfg.secret_file} is too short: at least 32 characters")
        return text.encode()
    env = os.environ.get(cfg.secret_env, "") if cfg.secret_env else ""
    if env:
        if len(env) < 32:
            raise ValueError(f"{cfg.secret_env} is too short: at least 32 characters")
        return env.encode()
    path = Path(state_dir) / SECRET_FILE
    try:
        return bytes.fromhex(path.read_text().strip())
    except FileNotFoundError:
        pass
    path.parent.mkdir(parents=True, exist_ok=True)
    key = secrets.token_bytes(64)
    # O_EXCL: two API processes starting together must not each write a different key
    try:
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    except FileExistsError:
        return bytes.fromhex(path.read_text().strip())
    with os.fdopen(fd, "w") as f:
        f.write(key.hex() + "\n")
    return key


class Tokens:
    def __init__(self, cfg: AuthSettings, secret: bytes, now: Callable[[], float] = time.time):
        self.cfg = cfg
        self.secret = secret
        self.now = now
        self._cache: dict[str, tuple[Claims, float]] = {}

    def issue(self, name: str, role: str) -> tuple[str, int]:
        """(token, lifetime in seconds)."""
        now = int(self.now())
        payload = {
            "sub": name,
            "role": role,
            "iss": self.cfg.issuer,
            "iat": now,
            "exp": now + self.cfg.token_ttl_s,
            "jti": uuid.uuid4().hex,
        }
        return jwt.encode(payload, self.secret, algorithm=self.cfg.algorithm), self.cfg.token_ttl_s

    def verify(self, token: str) -> Claims:
        now = self.now()
        hit = self._cache.get(token)
        if hit is not None and hit[1] > now:
            return hit[0]
        if not token or len(token) > MAX_TOKEN_CHARS:
            raise AuthError("malformed token")
        try:
            payload = jwt.decode(
                token,
                self.secret,
                algorithms=[self.cfg.algorithm],
                issuer=self.cfg.issuer,
                options={"require": ["exp", "iat", "sub", "iss"]},
            )
        except jwt.ExpiredSignatureError:
            raise AuthError("token expired: get a new one at /api/v1/auth/token") from None
        except jwt.InvalidTokenError:
            raise AuthError("invalid token") from None
        role, name, exp = payload.get("role"), payload.get("sub"), payload["exp"]
        if role not in ROLES or not isinstance(name, str):
            raise AuthError("invalid token")
        claims = Claims(name=name, role=role, expires=float(exp))
        if self.cfg.verify_cache_s > 0 and self.cfg.verify_cache_max > 0:
            if len(self._cache) >= self.cfg.verify_cache_max:
                self._cache.clear()  # crude but bounded; refills within seconds
            self._cache[token] = (claims, min(now + self.cfg.verify_cache_s, claims.expires))
        return claims
