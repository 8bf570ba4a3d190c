"""`ares bench record`: what a recording costs, per profile and cloud encoding, on a real run's bus.

A recording of a run (`--recording FILE.mcap`, or a short `ares run --headless --speed max --record`
the bench makes) is read back (each payload as it travelled) and offered again, message by
message, to the recorder (ares.app.bus_record.recorder) with each of the variants below, one after
the other, in this process. For each: the file's bytes per second of stack time, the writer
thread's CPU seconds per second of stack time (its share of a core at real time) and the file
against the bytes received. For the default (full profile, clouds on the grid), also each topic
class recorded alone: what clouds, the grid, the JSON messages and Foxglove's views each add to the
file. The messages are offered a stack second at a time, the next second once the writer has
written the last, so that no message is dropped and the writer's CPU is its own.
"""

from __future__ import annotations

import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ares.tools.bench.common import BenchError, Goal, judge, versions

# the bounds (docs/recording.md): a lap of the default tour at most 2.5 GB in about 600 s,
# the writer within 10 % of a core at real time; the light log at most 50 MB a lap
RECORD_GOALS = {
    "variants.full.mb_per_stack_s": Goal(2500 / 600),
    "variants.full.writer_core_share": Goal(0.10),
    "variants.light.mb_per_stack_s": Goal(50 / 600),
}
SOURCE_SECONDS = 20.0


@dataclass(frozen=True)
class Variant:
    name: str
    doc: str
    settings: dict[str, Any]
    compression: str = "zstd"


VARIANTS = (
    Variant(
        "before",
        "what --record wrote before: float32 clouds and a Foxglove copy of every sweep",
        {"cloud_encoding": "float32", "cloud_view_every_s": 1e-6, "cloud_view_stride": 1},
    ),
    Variant(
        "float32",
        "float32 clouds as they travelled, no cloud previews",
        {"cloud_encoding": "float32", "cloud_view_every_s": 0},
    ),
    Variant("grid", "clouds on the sensor's grid, no cloud previews", {"cloud_view_every_s": 0}),
    Variant("full", "the full profile as configured: clouds on the grid, a preview a second", {}),
    Variant("full_lz4", "... with lz4 chunks instead of zstd", {}, "lz4"),
    Variant("light", "the light profile", {"profile": "light"}),
)
CLASSES = {
    "clouds": lambda topic: topic.startswith("lidar/") and topic.endswith("/points"),
    "grid": lambda topic: topic == "perception/grid",
    "json": lambda topic: not (topic.startswith("lidar/") and topic.endswith("/points")) and topic != "perception/grid",
}


def make_source(folder: Path, seconds: float, progress: Callable[[str], None]) -> Path:
    """A recording of a short headless run at --speed max (its own process: a stack of processes)."""
    path = folder / "source.mcap"
    progress(f"recording a {seconds:g} s headless run at --speed max (the bench's input)")
    command = [
        sys.executable, "-m", "ares", "run", "--headless", "--speed", "max", "--seconds", str(seconds),
        "--record", f"full:{path}", "--run-dir", str(folder / "run"),
    ]  # fmt: skip
    done = subprocess.run(command, capture_output=True, text=True, timeout=600)
    if done.returncode != 0 or not path.exists():
        raise BenchError(f"the source run failed ({done.returncode}): {done.stderr.strip()[-400:]}")
    return path


def _rerecord(
    messages: Callable[[], Iterator[Any]], cfg: dict[str, Any], utc_epoch: float, variant: Variant, out: Path,
    keep: Callable[[str], bool] | None = None, views: bool = True,
) -> dict[str, Any]:  # fmt: skip
    from ares.app.bus_record.foxglove_views import FoxgloveViews
    from ares.app.bus_record.recorder import McapRecorder
    from ares.core import config

    settings = config.core(cfg).recording.model_copy(update=variant.settings)
    recorder = McapRecorder(
        out, cfg, utc_epoch=utc_epoch, views=FoxgloveViews(cfg, utc_epoch) if views else None,
        settings=settings, compression=variant.compression,
    )  # fmt: skip
    recorder.start()
    second = None
    for message in messages():
        if keep is not None and not keep(message.topic):
            continue
        if second is not None and int(message.stamp) != second:
            _drain(recorder)
        second = int(message.stamp)
        recorder.offer(message.topic, message.encoding, message.payload)
    stats = recorder.close()
    return {"size_bytes": out.stat().st_size, **stats.as_dict()}


def _drain(recorder: Any) -> None:
    deadline = time.monotonic() + 60
    while recorder._queued_bytes > 0 and time.monotonic() < deadline:
        time.sleep(0.002)


def run_record_bench(recording: Path | None, progress: Callable[[str], None]) -> dict[str, Any]:
    from ares.app.bus_record import mcap_replay

    with tempfile.TemporaryDirectory(prefix="ares-bench-record-") as tmp:
        folder = Path(tmp)
        source = recording if recording is not None else make_source(folder, SOURCE_SECONDS, progress)
        opened = mcap_replay.open_recording(source)
        cfg, utc_epoch = opened.cfg, float(opened.run["utc_epoch"])
        progress(f"reading {source}")
        messages = opened.messages  # read again for each variant: a lap's recording does not fit in memory
        count, bytes_in, first, last = 0, 0, float("inf"), float("-inf")
        for message in messages():
            count, bytes_in = count + 1, bytes_in + len(message.payload)
            if message.stamp > 0:
                first, last = min(first, message.stamp), max(last, message.stamp)
        stack_s = last - first
        if not count or stack_s <= 0:
            raise BenchError(f"{source}: no bus messages spanning any time")
        result: dict[str, Any] = {
            "source": str(source) if recording is not None else f"a {SOURCE_SECONDS:g} s headless run, --speed max",
            "stack_s": round(stack_s, 2),
            "messages": count,
            "mb_in_per_stack_s": round(bytes_in / stack_s / 1e6, 3),
            "variants": {},
            "classes": {},
        }
        for variant in VARIANTS:
            progress(f"{variant.name}: {variant.doc}")
            figures = _rerecord(messages, cfg, utc_epoch, variant, folder / f"{variant.name}.mcap")
            result["variants"][variant.name] = _per_second(figures, stack_s) | {"doc": variant.doc}
        full = next(v for v in VARIANTS if v.name == "full")
        for name, keep in CLASSES.items():
            progress(f"the {name} alone ({full.name})")
            figures = _rerecord(messages, cfg, utc_epoch, full, folder / f"class-{name}.mcap", keep, views=False)
            result["classes"][name] = _per_second(figures, stack_s)
        views_only = _rerecord(messages, cfg, utc_epoch, full, folder / "with-views.mcap")
        result["classes"]["foxglove_views"] = {
            "mb_per_stack_s": round(
                (views_only["size_bytes"] - sum(result["classes"][c]["size_bytes"] for c in CLASSES)) / stack_s / 1e6,
                3,
            )
        }
        before, after = result["variants"]["before"], result["variants"]["full"]
        result["full_vs_before"] = round(after["mb_per_stack_s"] / before["mb_per_stack_s"], 3)
        result["lap_gb_full"] = round(after["mb_per_stack_s"] * 600 / 1000, 2)
        result["lap_mb_light"] = round(result["variants"]["light"]["mb_per_stack_s"] * 600, 1)
        result["versions"] = versions("mcap", "zstandard")
        return judge(result, RECORD_GOALS)


def _per_second(figures: dict[str, Any], stack_s: float) -> dict[str, Any]:
    bytes_in = max(figures["bytes_in"], 1)
    return {
        "size_bytes": figures["size_bytes"],
        "mb_per_stack_s": round(figures["size_bytes"] / stack_s / 1e6, 3),
        "writer_core_share": round(figures["writer_cpu_s"] / stack_s, 4),
        "file_vs_bytes_in": round(figures["size_bytes"] / bytes_in, 4),
        "messages": figures["messages"],
        "views": figures["views"],
        "dropped": figures["dropped"],
    }


def format_record_result(result: dict[str, Any], out: Any) -> None:
    out.write(f"source: {result['source']}, {result['stack_s']} s of stack time, {result['messages']} messages, ")
    out.write(f"{result['mb_in_per_stack_s']} MB/s on the bus\n\n")
    out.write(f"{'variant':10} {'MB/s':>8} {'core':>7} {'file/in':>8}  what\n")
    for name, v in result["variants"].items():
        out.write(
            f"{name:10} {v['mb_per_stack_s']:8.3f} {v['writer_core_share']:7.1%} "
            f"{v['file_vs_bytes_in']:8.3f}  {v['doc']}\n"
        )
    out.write("\nthe full profile's file, by topic class (MB per stack second):\n")
    for name, c in result["classes"].items():
        out.write(f"  {name:16} {c['mb_per_stack_s']:.3f}\n")
    out.write(
        f"\nfull vs before: {result['full_vs_before']}x; a 600 s lap: {result['lap_gb_full']} GB full, "
        f"{result['lap_mb_light']} MB light\n"
    )
