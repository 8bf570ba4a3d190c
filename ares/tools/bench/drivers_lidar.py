"""The LiDAR driver's cost (part of `ares bench drivers`): decoding and assembling one rotation of
Velodyne packets, every model at full resolution (10 Hz, strongest return).

The packets are made by the simulator's encoder (ares/core/wire/velodyne.py) from a synthetic
scene (a ground plane 1.8 m down, walls 4 to 30 m away; every laser returns except those over
the horizon), then fed packet by packet to a RotationAssembler as the driver does (checks,
loss accounting, the cut at 0°, the vectorised decode of the finished rotation). Per rotation:
p50 and p90 wall milliseconds, packets and points; and what the driver adds to publish the
rotation's packets as received (`packets_message` and its bulk encoding, as the bus sends it), so
that recording packets in place of clouds is seen to cost little beside the decode.
"""

from __future__ import annotations

import time

import numpy as np

from ares.core.schema import encode
from ares.core.wire import velodyne as v
from ares.core.wire.velodyne_packets import packets_message


def _rotation(model: str) -> tuple[v.Calibration, list[bytes]]:
    cal = v.load_calibration(model)
    pattern = v.firing_pattern(cal, 10.0, "strongest")
    d = pattern.directions.astype(np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        ground = np.where(d[..., 2] < -1e-3, 1.8 / -d[..., 2], np.inf)
        wall_x = np.where(d[..., 0] > 0, 30.0, 4.0) / np.abs(d[..., 0])
        wall_y = 12.0 / np.abs(d[..., 1])
    distance = np.minimum(np.minimum(ground, wall_x), wall_y)
    distance = np.where(distance < 120.0, distance, 0.0)
    intensity = np.full(distance.shape, 0.4)
    return cal, v.encode_rotation(cal, pattern, distance, intensity, pattern.timestamps_us(0))


def lidar_decode_bench(repeats: int) -> dict:
    """Per model: decode + assembly of one rotation, `repeats` times (after one warm-up)."""
    out: dict = {}
    for model in v.MODELS:
        cal, packets = _rotation(model)
        times_ms, packets_ms = [], []
        points = 0
        received = [(p, 0.0) for p in packets]
        for k in range(repeats + 1):
            asm = v.RotationAssembler(cal, 10.0)
            started = time.perf_counter()
            finished = [r for p in packets for r in asm.add(p, 0.0)]
            decoded = time.perf_counter()
            payload = encode(packets_message(0.0, "roof", 0.0, received))
            published = time.perf_counter()
            assert len(finished) == 1 and not finished[0].truncated and len(payload) > len(packets) * 1206
            points = finished[0].points.size
            if k:  # the first one warms the caches (the layouts, the trigonometric table)
                times_ms.append((decoded - started) * 1e3)
                packets_ms.append((published - decoded) * 1e3)
        out[model] = {
            "p50_ms": round(float(np.percentile(times_ms, 50)), 3),
            "p90_ms": round(float(np.percentile(times_ms, 90)), 3),
            "packets_message_p50_ms": round(float(np.percentile(packets_ms, 50)), 3),
            "packets_per_rotation": len(packets),
            "points_per_rotation": points,
            "repeats": repeats,
        }
    return out


if __name__ == "__main__":  # a quick look: python -m ares.tools.bench.drivers_lidar
    import json

    print(json.dumps(lidar_decode_bench(20), indent=2))
