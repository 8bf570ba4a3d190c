"""Process replay's recordings: what a node latched and published, step by step (ares.core.replay reads
them back). JSON lines, gzip: the first line holds the node, its class, its configuration and the
time of its set-up; then {"t", "in": [[topic, message], ...], "out": [...]} per step (t null for
what it published while setting up). A bulk message is kept as {"$bulk": base64 of its payload}.

A process the supervisor restarts records each incarnation to its own file (`<node>.<n>.jsonl.gz`
for its n-th restart), so a crash's recording is not overwritten by what follows it. The file is
flushed every few steps, so a process killed outright leaves a readable recording."""

from __future__ import annotations

import base64
import gzip
from pathlib import Path
from typing import Any

import orjson

from ares.core.schema import MAGIC, Payload


def as_record(payload: Payload) -> Any:
    if payload[: len(MAGIC)] == MAGIC:
        return {"$bulk": base64.b64encode(payload).decode()}
    return orjson.loads(payload)


def as_payload(record: Any) -> bytes:
    if isinstance(record, dict) and set(record) == {"$bulk"}:
        return base64.b64decode(record["$bulk"])
    return orjson.dumps(record)


INCARNATION_ENV = "ARES_INCARNATION"  # set by the supervisor: 0 for a first start, n for restart n
FLUSH_EVERY_STEPS = 100


def recording_path(folder: Path, node: str, incarnation: int) -> Path:
    return folder / (f"{node}.jsonl.gz" if incarnation == 0 else f"{node}.{incarnation}.jsonl.gz")


class StepRecorder:
    """What a node latched and published, one line per step: the node taps its subscriptions with
    took() and its publishers with gave(), and calls begin(now) and end() around each step."""

    def __init__(self, path: Path, header: dict[str, Any]):
        path.parent.mkdir(parents=True, exist_ok=True)
        self.path = path
        self._file = gzip.open(path, "wb", compresslevel=6)
        self._in: list[list[Any]] = []  # [topic, record]: JSON arrays
        self._out: list[list[Any]] = []
        self._t: float | None = None
        self._steps = 0
        self._write(header)

    def took(self, topic: str, payload: bytes | None) -> None:
        self._in.append([topic, None if payload is None else as_record(payload)])

    def gave(self, topic: str, payload: Payload) -> None:
        self._out.append([topic, as_record(payload)])

    def begin(self, now: float) -> None:
        if self._out and self._t is None:  # published during set-up
            self._write({"t": None, "in": [], "out": self._out})
            self._out = []
        self._t = now

    def end(self) -> None:
        self._write({"t": self._t, "in": self._in, "out": self._out})
        self._in, self._out = [], []
        self._steps += 1
        if self._steps % FLUSH_EVERY_STEPS == 0:
            self._file.flush()

    def _write(self, obj: dict[str, Any]) -> None:
        self._file.write(orjson.dumps(obj) + b"\n")

    def close(self) -> None:
        self._file.close()
