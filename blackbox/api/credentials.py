"""Who may use the REST API: users with Argon2 password hashes, and short-lived signed tokens.

- Users live in the black box store (RecordStore.get_user/put_user/list_users/delete_user); the
  password hash is Argon2id (argon2-cffi) and is re-hashed on the next successful login whenever
  the configured cost parameters change, so stored hashes follow the configuration.
- Tokens are JWTs signed with an HMAC key (HS256 by default). Decoding always names the one
  accepted algorithm, so `alg: none` and algorithm-confusion tokens are refused, and requires
  exp/iat/sub/role/iss/aud/jti/gen. A token lives `token_ttl_s` (15 min); a holder renews it
  before it expires (ARES §3.8: "a time-limited token they must renew"). A token that claims a
  longer life than that (exp - iat), or to be issued in the future, is refused even when its
  signature is right: the key alone must not make a token that outlives the rules.
- A token is bound to the black box that issued it: its audience (`aud`) is the API's vehicle id,
  so a token of one shuttle's API is refused by another's, even with the same key.
- Every request checks the account, not only the signature (`Accounts`): the user must still
  exist, be enabled, have the token's role, and the token must be of the account's current
  generation (a change of role or password, or a disabling, bumps it: every token issued before
  is refused) and its id (`jti`) not revoked (POST /auth/revoke, a logout). An account found
  allowing a token is trusted for `account_cache_s` (1 s) before the store is asked again, so a
  dashboard polling `latest` does not pay two store look-ups and a thread hop each time (measured:
  half the throughput); the API's own changes to users forget that at once, a change by `ares
  users` or another API process is seen within it.
- The key comes from the file `auth.secret_file` when set (a deployment's compose secret), else
  from the environment variable `auth.secret_env` when set, else from a file
  `api_secret` in the API's state directory, created on first use (0600) and kept, so tokens
  survive a restart of the API.
- Verified signatures are cached for a few seconds (never past their expiry): a dashboard polling
  `latest` many times a second must not pay an HMAC and a JSON parse each time.
"""

from __future__ import annotations

import os
import re
import secrets
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import argon2
import jwt

from ares.core.config import Params, param, read_secret
from blackbox.register.store.record_store import RecordStore, User, utc_now

ROLES = ("auditor", "operator", "fleet", "admin", "passenger")  # passenger: a kiosk's, the passenger page only
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
    clock_skew_s: int = param(
        30, "a token issued up to this far in the future (another clock) is accepted", unit="s", ge=0, le=300
    )
    secret_file: str | None = param(
        None, "signing key from this file (a compose secret, >= 32 characters); null: secret_env, then the state dir"
    )
    secret_env: str = param(
        "ARES_API_SECRET", "signing key from this variable when set (>= 32 chars), else <state_dir>/api_secret"
    )
    verify_cache_s: float = param(
        5.0,
        "a verified signature is trusted this long without re-checking it (never past exp); the account is "
        "checked on every request",
        unit="s",
        ge=0.0,
        le=60.0,
    )
    verify_cache_max: int = param(10000, "verified tokens remembered at most", ge=0)
    account_cache_s: float = param(
        1.0,
        "an account found to allow a token is trusted this long before the store is asked again; the API's own "
        "changes to users end it at once, `ares users` and other processes' within this",
        unit="s",
        ge=0.0,
        le=5.0,
    )
    min_password_length: int = param(10, "shortest password accepted", ge=1, le=MAX_PASSWORD_CHARS)
    argon2: Argon2Settings = param(doc="password hashing cost", factory=Argon2Settings)


class AuthError(Exception):
    """Not authenticated (401): missing, malformed, expired or forged credentials."""


class UserError(ValueError):
    """A user cannot be created or changed as asked (bad name, role or password, or already exists)."""


class NoSuchUser(UserError):
    """The user named does not exist."""


@dataclass(frozen=True)
class Claims:
    name: str
    role: str
    expires: float  # epoch seconds
    token_id: str  # the token's jti: what POST /auth/revoke refuses from then on
    generation: int  # the account's generation the token was issued under


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
        if user is None or user.disabled:
            return None
        if self.hasher.check_needs_rehash(user.password_hash):
            user = replace(user, password_hash=self.hasher.hash(password))  # the same password: tokens stay
            store.put_user(user)
        return user


def check_new_user(name: str, role: str, password: str, min_length: int) -> None:
    if not USERNAME_RE.match(name):
        raise UserError(
            f"invalid user name {name!r}: 2-32 characters, lower-case letters, digits, '_', '.', '-', "
            "starting with a letter"
        )
    check_role(role)
    check_password(password, min_length)


def check_role(role: str) -> None:
    if role not in ROLES:
        raise UserError(f"unknown role {role!r}; roles: {', '.join(ROLES)}")


def check_password(password: str, min_length: int) -> None:
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


def existing_user(store: RecordStore, name: str) -> User:
    user = store.get_user(name) if USERNAME_RE.match(name) else None
    if user is None:
        raise NoSuchUser(f"no user {name!r}")
    return user


def change_user(store: RecordStore, name: str, **changes: object) -> User:
    """The user with `changes` (role, password_hash, disabled), stored under a new generation:
    every token issued before is refused from now on."""
    user = existing_user(store, name)
    user = replace(user, **changes, generation=user.generation + 1)  # type: ignore[arg-type]
    store.put_user(user)
    return user


def set_role(store: RecordStore, name: str, role: str) -> User:
    check_role(role)
    user = existing_user(store, name)
    return user if user.role == role else change_user(store, name, role=role)  # the same role: no change


def set_password(store: RecordStore, passwords: Passwords, name: str, password: str, min_length: int) -> User:
    check_password(password, min_length)
    return change_user(store, name, password_hash=passwords.hash(password))


def set_disabled(store: RecordStore, name: str, disabled: bool) -> User:
    return change_user(store, name, disabled=disabled)


def delete_user(store: RecordStore, name: str) -> None:
    if not (USERNAME_RE.match(name) and store.delete_user(name)):
        raise NoSuchUser(f"no user {name!r}")


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


class Accounts:
    """The check of every request past its token's signature: the account as it is in the store,
    trusted for `cache_s` once found allowing a token (`forget` ends that at once)."""

    def __init__(self, store: RecordStore, cache_s: float = 0.0, now: Callable[[], float] = time.monotonic):
        self.store = store
        self.cache_s = cache_s
        self.now = now
        self._allowed: dict[str, float] = {}  # token id -> until when its account was found allowing it

    def recently_allowed(self, claims: Claims) -> bool:
        """The token's account was found allowing it less than cache_s ago (no store call)."""
        until = self._allowed.get(claims.token_id)
        return until is not None and until > self.now()

    def check(self, claims: Claims) -> None:
        """Raise AuthError unless the token's account still allows it (asks the store)."""
        user = self.store.get_user(claims.name)
        if user is None or user.disabled:
            raise AuthError("this account is disabled or removed")
        if user.role != claims.role or user.generation != claims.generation:
            raise AuthError("the account changed since this token was issued: log in again")
        if self.store.token_revoked(claims.token_id):
            raise AuthError("token revoked: log in again")
        if self.cache_s > 0:
            if len(self._allowed) >= 10_000:
                self._allowed.clear()  # bounded; refills within cache_s
            self._allowed[claims.token_id] = self.now() + self.cache_s

    def forget(self) -> None:
        """A user changed or a token was revoked: every token's account is asked again."""
        self._allowed.clear()


class Tokens:
    """Tokens of one black box (`audience`: its vehicle id). `accounts`: the account check each
    verification ends with (None: the signature and claims only, for tools without a store)."""

    def __init__(
        self,
        cfg: AuthSettings,
        secret: bytes,
        audience: str,
        accounts: Accounts | None = None,
        now: Callable[[], float] = time.time,
    ):
        self.cfg = cfg
        self.secret = secret
        self.audience = audience
        self.accounts = accounts
        self.now = now
        self._cache: dict[str, tuple[Claims, float]] = {}

    def issue(self, name: str, role: str, generation: int) -> tuple[str, int]:
        """(token, lifetime in seconds) for the account `name` as it is now (its role and generation)."""
        now = int(self.now())
        payload = {
            "sub": name,
            "role": role,
            "gen": generation,
            "iss": self.cfg.issuer,
            "aud": self.audience,
            "iat": now,
            "exp": now + self.cfg.token_ttl_s,
            "jti": uuid.uuid4().hex,
        }
        return jwt.encode(payload, self.secret, algorithm=self.cfg.algorithm), self.cfg.token_ttl_s

    def verify(self, token: str) -> Claims:
        """The token's claims when its signature, claims and account allow it; else AuthError."""
        claims = self.signed_claims(token)
        if self.accounts is not None and not self.accounts.recently_allowed(claims):
            self.accounts.check(claims)
        return claims

    def signed_claims(self, token: str) -> Claims:
        """The token's claims when its signature and claims are right (the account not asked)."""
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
                audience=self.audience,
                options={"require": ["exp", "iat", "sub", "iss", "aud", "jti"]},
            )
        except jwt.ExpiredSignatureError:
            raise AuthError("token expired: get a new one at /api/v1/auth/token") from None
        except jwt.InvalidAudienceError:
            raise AuthError("this token is for another vehicle's black box") from None
        except jwt.InvalidTokenError:
            raise AuthError("invalid token") from None
        role, name, exp, iat = payload.get("role"), payload.get("sub"), payload["exp"], payload["iat"]
        token_id, generation = payload.get("jti"), payload.get("gen")
        if (
            role not in ROLES
            or not isinstance(name, str)
            or not isinstance(token_id, str)
            or not isinstance(generation, int)
            or isinstance(generation, bool)
        ):
            raise AuthError("invalid token")
        if exp - iat > self.cfg.token_ttl_s or iat > now + self.cfg.clock_skew_s:
            # signed with the key, yet not a token this API issues: longer-lived than the rules
            raise AuthError(f"invalid token: a token lives at most {self.cfg.token_ttl_s} s")
        claims = Claims(name=name, role=role, expires=float(exp), token_id=token_id, generation=generation)
        if self.cfg.verify_cache_s > 0 and self.cfg.verify_cache_max > 0:
            if len(self._cache) >= self.cfg.verify_cache_max:
                self._cache.clear()  # crude but bounded; refills within seconds
            self._cache[token] = (claims, min(now + self.cfg.verify_cache_s, claims.expires))
        return claims
