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

from ares.core import config
from ares.core.clock import Clock
from ares.core.route import Route

if TYPE_CHECKING:  # imported when asked for: a run without --record or --foxglove loads neither mcap nor foxglove
    from ares.app.bus_record.foxglove_live import FoxgloveBridge
    from ares.app.bus_record.recorder import McapRecorder
    from ares.app.bus_record.snapshots import SnapshotKeeper

log = logging.getLogger("ares.app.bus_record.in_run")

RECORDING_NAME = "bus.mcap"  # in the run's folder, unless --record names a file
LIGHT_LOG_NAME = "bus-light.mcap"  # the light profile's, in the run's folder
PROFILES = ("full", "light")


def record_target(text: str) -> tuple[str | None, str]:
    """`--record`'s argument: `full`, `light`, `FILE.mcap` or `PROFILE:FILE.mcap` (profile None: the
    configuration's, `recording.profile`; file "": the run folder's)."""
    if text in PROFILES:
        return text, ""
    head, sep, tail = text.partition(":")
    if sep and head in PROFILES:
        return head, tail
    return None, text


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
    light_log: McapRecorder | None = None  # `recording.light_always`: beside a full --record, or alone
    snapshots: SnapshotKeeper | None = None  # `recording.snapshots.enabled`
    bridge: FoxgloveBridge | None = None
    bus: Any = None
    closed: dict[str, Any] = field(default_factory=dict)

    def close(self) -> dict[str, Any]:
        """Stop both (the recording's summary written); the recording's figures."""
        if self.bridge is not None:
            self.bridge.close(self.bus)
            self.bridge = None
        if self.recorder is not None:
            self.closed = _figures(self.recorder)
            self.recorder = None
        if self.snapshots is not None:
            kept = self.snapshots.close()
            self.closed = {
                **self.closed,
                "snapshots": {
                    "folder": str(self.snapshots.folder),
                    "triggered": kept.triggered,
                    "saved": kept.saved,
                    "failed": kept.failed,
                    "files": kept.saved_files,
                    "evicted_early": kept.evicted_early,
                    "pruned": kept.pruned,
                    "ring_cpu_s": round(kept.ring_cpu_s, 2),
                    "saver_cpu_s": round(kept.saver_cpu_s, 2),
                },
            }
            self.snapshots = None
        if self.light_log is not None:
            self.closed = (
                {**self.closed, "light_log": _figures(self.light_log)} if self.closed else _figures(self.light_log)
            )
            self.light_log = None
        return self.closed


def _figures(recorder: McapRecorder) -> dict[str, Any]:
    stats = recorder.close()
    size = recorder.path.stat().st_size if recorder.path.exists() else 0
    wall = max(stats.closed_wall - stats.started_wall, 1e-9)
    return {
        "file": str(recorder.path),
        "profile": recorder.settings.profile,
        "size_bytes": size,
        **stats.as_dict(),
        "mb_per_s_in": round(stats.bytes_in / wall / 1e6, 2),
        "mb_per_s_written": round(size / wall / 1e6, 2),
        "writer_cpu_share": round(stats.writer_cpu_s / wall, 3),
    }


def start(
    record: str | None, foxglove: str | None, cfg: dict[str, Any], bus: Any, clock: Clock, run_dir: Path, route: Route
) -> RunTaps:
    """The taps a run asks for (`record`: None, or `--record`'s argument, record_target; `foxglove`:
    None or [HOST:]PORT) and the light log if the configuration keeps one always, attached to
    `bus` and started."""
    taps = RunTaps(bus=bus)
    settings = config.core(cfg).recording
    if record is None and foxglove is None and not settings.light_always and not settings.snapshots.enabled:
        return taps
    from ares.app.bus_record.foxglove_live import FoxgloveBridge
    from ares.app.bus_record.foxglove_views import FoxgloveViews
    from ares.app.bus_record.recorder import McapRecorder

    utc_epoch = clock.utc(0.0).timestamp()

    def recorder(path: Path, profile: str) -> McapRecorder:
        chosen = settings.model_copy(update={"profile": profile})
        started = McapRecorder(
            path, cfg, utc_epoch=utc_epoch, views=FoxgloveViews(cfg, utc_epoch), route=route, settings=chosen
        )
        started.attach(bus)
        started.start()
        print(f"ares run: recording the bus ({profile}) to {path}", file=sys.stderr, flush=True)
        return started

    if record is not None:
        profile, file = record_target(record)
        profile = profile or settings.profile
        default_name = LIGHT_LOG_NAME if profile == "light" else RECORDING_NAME
        taps.recorder = recorder(Path(file) if file else Path(run_dir) / default_name, profile)
    if settings.light_always and (taps.recorder is None or taps.recorder.settings.profile != "light"):
        taps.light_log = recorder(Path(run_dir) / LIGHT_LOG_NAME, "light")
    if settings.snapshots.enabled:
        from ares.app.bus_record.snapshots import SnapshotKeeper
        from blackbox.register import snapshot_files
        from blackbox.register.store.record_store import StoreSettings

        where = snapshot_files.folder(settings.snapshots, config.section(cfg, "blackbox_store", StoreSettings))
        taps.snapshots = SnapshotKeeper(cfg, settings.snapshots, where, utc_epoch=utc_epoch, route=route)
        taps.snapshots.attach(bus)
        taps.snapshots.start()
        print(f"ares run: incident snapshots to {where}", file=sys.stderr, flush=True)
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
