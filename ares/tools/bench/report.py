"""One table of measured figures from the benches' `--json` results: each result's goals (the
figure, its value, the bound, met or not) and the figures that say what else it measured.
README's "Measured figures" is this table (`ares bench report`)."""

from __future__ import annotations

import json
from pathlib import Path

from ares.tools.bench.common import BenchError, figure

# the figures shown besides each bench's goals, by the result's `bench`
HEADLINES: dict[str, tuple[str, ...]] = {
    "bus": ("cloud_latency_p99_ms",),
    "path": ("query_p99_us", "ukf_step_p50_ms"),
    "perception": (
        "pipeline_ms_p50",
        "pipeline_cpu_ms_p50",
        "road_ms_p50",
        "raycast_ms_p50",
        "scan_pipeline_ms_p50",
    ),
    "perception_reference": ("summary.simulated.iou_p50.ours", "summary.simulated.cpu_ms_p50.ours"),
    "mpc": ("solve_max_ms", "xte_rmse_m"),
    "supervisor": ("sigkill_running_again_s_median", "sigstop_noticed_s_median", "gil_hang_noticed_s_median"),
    "obstacle-zone": (
        "trapezoid_false_stops",
        "trapezoid_arc_false_stops",
        "rectangle_false_stops",
        "rectangle_arc_false_stops",
    ),
    "blackbox": ("api_latest_req_per_s", "latency_p50_ms"),
    "live": ("lag_p50_ms", "lag_p95_ms"),
    "drivers": (
        "lidar.VLP-16.p50_ms",
        "lidar.HDL-32E.p50_ms",
        "lidar.VLP-32C.p50_ms",
        "lidar.HDL-64E.p50_ms",
        "lidar.VLS-128.p50_ms",
        "lidar.VLS-128.packets_message_p50_ms",
        "can.codec.decode_frames_per_s_p50",
        "can.udp_multicast.wire_to_bus_latency_p50_ms",
    ),
    "stack": ("speedup", "vehicle_cpu_s_per_vehicle_s", "lap.xte_rmse_m", "lap.xte_max_m", "lap.collisions"),
}


def read_result(path: Path) -> dict:
    """A bench's result from a file of its `--json` output: the last line that is a JSON object
    (whatever came before it, e.g. progress that went to the same file)."""
    try:
        lines = path.read_text().splitlines()
    except OSError as exc:
        raise BenchError(f"cannot read {path}: {exc.strerror}") from None
    for line in reversed(lines):
        if line.startswith("{"):
            try:
                result = json.loads(line)
            except json.JSONDecodeError:
                continue
            if "bench" not in result:
                raise BenchError(f"{path}: a JSON object, but no bench's result (no `bench` key)")
            return result
    raise BenchError(f"{path}: no JSON result line (the output of `ares bench NAME --json`)")


def _value(value: object) -> str:
    if isinstance(value, bool) or not isinstance(value, int | float):
        return "n/a" if value is None else str(value)
    if abs(value) >= 1000:
        return f"{value:,.0f}"
    return f"{value:.4g}"


def _bound(bound: dict[str, float]) -> str:
    return ", ".join(f"{'≥' if side == 'at_least' else '≤'} {_value(limit)}" for side, limit in bound.items())


def rows(result: dict) -> list[tuple[str, str, str, str, str]]:
    """(bench, figure, value, goal, met) of one result: its goals first, then its headlines."""
    bench = result["bench"]
    out = []
    for path, met in result.get("goals_met", {}).items():
        bound = _bound(result.get("goals", {}).get(path, {}))
        out.append((bench, path, _value(figure(result, path)), bound, "yes" if met else "**no**"))
    for path in HEADLINES.get(bench, ()):
        if path not in result.get("goals_met", {}) and figure(result, path) is not None:
            out.append((bench, path, _value(figure(result, path)), "", ""))
    return out


def markdown_table(results: list[dict]) -> str:
    lines = ["| bench | figure | value | goal | met |", "|---|---|---|---|---|"]
    for result in results:
        lines += [f"| `{b}` | `{f}` | {v} | {g} | {m} |" for b, f, v, g, m in rows(result)]
    return "\n".join(lines) + "\n"
