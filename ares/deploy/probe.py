"""Small Zenoh probes the rehearsal runs inside a host's network namespace (`ip netns exec NS
python -m ares.deploy.probe ...`), each printing one JSON line:

    link CONFIG SECONDS           does a router of CONFIG link to a router within SECONDS? {"linked": ...}
    put CONFIG KEY COUNT          COUNT puts on KEY, 0.1 s apart, from a session of CONFIG
    listen CONFIG SECONDS KEY...  how many probe samples ({"probe": n}, as put sends) of each KEY
                                  arrive within SECONDS {"received": {...}} (a running stack's own
                                  samples on the same keys are not counted)
    serve CONFIG SECONDS KEY...   answer queries on each KEY for SECONDS {"queried": {...}}
    call CONFIG PAYLOAD KEY...    query each KEY with PAYLOAD: how many answers {"answered": {...}}

CONFIG is a Zenoh session config (JSON5) made by the rehearsal.
"""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path


def _open(config: str, attempts: int = 3):
    """A session of CONFIG; a refused open is tried again (a router busy accepting the others)."""
    import zenoh

    for attempt in range(attempts):
        try:
            return zenoh.open(zenoh.Config.from_json5(Path(config).read_text()))
        except zenoh.ZError as exc:
            print(f"open {attempt + 1} of {attempts}: {str(exc).split(' at ')[0]}", file=sys.stderr, flush=True)
            if attempt == attempts - 1:
                raise
            time.sleep(1.0)
    raise AssertionError("unreachable")


def link(config: str, seconds: float) -> dict:
    Path(config).read_text()  # a config that cannot be read is an error, never a refused link
    try:
        session = _open(config, attempts=1)
    except Exception as exc:  # zenoh refuses at open when a connect must succeed
        return {"linked": False, "error": str(exc).split(" at ")[0][:200]}
    try:
        deadline = time.monotonic() + seconds
        while time.monotonic() < deadline:
            if list(session.info.routers_zid()):
                return {"linked": True}
            time.sleep(0.05)
        return {"linked": False}
    finally:
        session.close()


def put(config: str, key: str, count: int) -> dict:
    session = _open(config)
    try:
        time.sleep(1.0)  # the router learns this session's declarations first
        for i in range(count):
            session.put(key, json.dumps({"probe": i}).encode())
            time.sleep(0.1)
    finally:
        session.close()
    return {"put": count, "key": key}


def listen(config: str, seconds: float, keys: list[str]) -> dict:
    received = dict.fromkeys(keys, 0)
    session = _open(config)

    def heard(sample, key: str) -> None:
        if sample.payload.to_bytes().startswith(b'{"probe"'):
            received[key] += 1

    subs = [session.declare_subscriber(key, lambda s, k=key: heard(s, k)) for key in keys]
    try:
        print(json.dumps({"listening": keys}), flush=True)
        time.sleep(seconds)
    finally:
        for sub in subs:
            sub.undeclare()
        session.close()
    return {"received": received}


def serve(config: str, seconds: float, keys: list[str]) -> dict:
    queried = dict.fromkeys(keys, 0)

    def answer(query, key: str) -> None:
        queried[key] += 1
        query.reply(query.key_expr, json.dumps({"served": key}).encode())

    session = _open(config)
    queryables = [session.declare_queryable(key, lambda q, k=key: answer(q, k)) for key in keys]
    try:
        print(json.dumps({"serving": keys}), flush=True)
        time.sleep(seconds)
    finally:
        for queryable in queryables:
            queryable.undeclare()
        session.close()
    return {"queried": queried}


def call(config: str, payload: str, keys: list[str], timeout_s: float = 3.0) -> dict:
    session = _open(config)
    try:
        time.sleep(1.0)  # the session's routes first
        answered = {
            key: sum(r.ok is not None for r in session.get(key, payload=payload.encode(), timeout=timeout_s))
            for key in keys
        }
    finally:
        session.close()
    return {"answered": answered}


def main(argv: list[str]) -> int:
    what, config, *rest = argv
    if what == "link":
        out = link(config, float(rest[0]))
    elif what == "put":
        out = put(config, rest[0], int(rest[1]))
    elif what == "listen":
        out = listen(config, float(rest[0]), rest[1:])
    elif what == "serve":
        out = serve(config, float(rest[0]), rest[1:])
    elif what == "call":
        out = call(config, rest[0], rest[1:])
    else:
        print(f"unknown probe {what!r}", file=sys.stderr)
        return 2
    print(json.dumps(out), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
