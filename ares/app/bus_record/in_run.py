"""`ares run --record [FILE]` and `ares run --foxglove [[HOST:]PORT]`: the recorder and the
Foxglove bridge as threads of the run's own process, on the supervisor's session (the embedded
router's), subscribed before any process is spawned so that the recording misses nothing of the
run. Neither forks; both only queue on Zenoh's threads (ares.app.bus_record.recorder, foxglove_live).
"""

from __future__ import annotations

import logging
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ares.core.clock import Clock
from ares.core.route import Route

if TYPE_CHECKING:  # imported when asked for: a run without --record or --foxglove loads neither mcap nor foxglove
    from ares.app.bus_record.foxglove_live import FoxgloveBridge
    from ares.app.bus_record.recorder import McapRecorder

log = logging.getLogger("ares.app.bus_record.in_run")

RECORDING_NAME = "bus.mcap"  # in the run's folder, unless --record names a file


def host_port(text: str) -> tuple[str, int]:
    """`PORT`, `HOST:PORT` or `HOST` (the default port): where the Foxglove bridge listens."""
    from ares.app.bus_record.foxglove_live import DEFAULT_HOST, DEFAULT_PORT

    host, sep, port = text.rpartition(":")
    if not sep:
        return (DEFAULT_HOST, int(text)) if text.isdigit() else (text or DEFAULT_HOST, DEFAULT_PORT)
    return host or DEFAULT_HOST, int(port)


@dataclass
class RunTaps:
    """What a run records or serves beside its processes."""

    recorder: McapRecorder | None = None
    bridge: FoxgloveBridge | None = None
    bus: Any = None
    closed: dict[str, Any] = field(default_factory=dict)

    def close(self) -> dict[str, Any]:
        """Stop both (the recording's summary written); the recording's figures."""
        if self.bridge is not None:
            self.bridge.close(self.bus)
            self.bridge = None
        if self.recorder is not None:
            stats = self.recorder.close()
            size = self.recorder.path.stat().st_size if self.recorder.path.exists() else 0
            wall = max(stats.closed_wall - stats.started_wall, 1e-9)
            self.closed = {
                "file": str(self.recorder.path),
                "size_bytes": size,
                **stats.as_dict(),
                "mb_per_s_in": round(stats.bytes_in / wall / 1e6, 2),
                "mb_per_s_written": round(size / wall / 1e6, 2),
            }
            self.recorder = None
        return self.closed


def start(
    record: str | None, foxglove: str | None, cfg: dict[str, Any], bus: Any, clock: Clock, run_dir: Path, route: Route
) -> RunTaps:
    """The taps a run asks for (`record`: None, or "" for the run folder's file, or a path;
    `foxglove`: None or [HOST:]PORT), attached to `bus` and started."""
    taps = RunTaps(bus=bus)
    if record is None and foxglove is None:
        return taps
    from ares.app.bus_record.foxglove_live import FoxgloveBridge
    from ares.app.bus_record.foxglove_views import FoxgloveViews
    from ares.app.bus_record.recorder import McapRecorder

    utc_epoch = clock.utc(0.0).timestamp()
    if record is not None:
        path = Path(record) if record else Path(run_dir) / RECORDING_NAME
        taps.recorder = McapRecorder(path, cfg, utc_epoch=utc_epoch, views=FoxgloveViews(cfg, utc_epoch), route=route)
        taps.recorder.attach(bus)
        taps.recorder.start()
        print(f"ares run: recording the bus to {path}", file=sys.stderr, flush=True)
    if foxglove is not None:
        host, port = host_port(foxglove)
        try:
            taps.bridge = FoxgloveBridge(cfg, utc_epoch=utc_epoch, host=host, port=port, route=route).attach(bus)
        except RuntimeError as exc:  # the port taken, say: no run half set up
            taps.close()
            raise RuntimeError(f"--foxglove: cannot serve on {host}:{port}: {exc}") from None
        print(
            f"ares run: Foxglove bridge on ws://{host}:{taps.bridge.port} (open it in Foxglove: Open connection)",
            file=sys.stderr,
            flush=True,
        )
    return taps
