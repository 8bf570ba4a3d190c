"""ARES paper Fig. 14 and §3.5.3: the obstacle manager's trapezoidal search area beside a
rectangular one. The paper: the trapezoid "can be tuned with more precision than a rectangular
one" and avoids the rectangle's detections of what lies beside a narrow road (Fig. 14a-b). ARES
counts the false slows and stops of each along the tour's narrow lane between rock walls
(`ares bench obstacle-zone`), where nothing stands in the way."""

from __future__ import annotations

from ares.tools.bench.obstacle_zone import run_obstacle_zone_bench
from ares.tools.reproduce.experiment import Context, ExperimentResult, Row


def run(ctx: Context) -> ExperimentResult:
    found = run_obstacle_zone_bench(step_m=10.0 if ctx.quick else 2.0, progress=ctx.progress)
    rows = [Row("frames in the narrow lane", None, found["frames"], "")]
    for shape in ("trapezoid", "rectangle", "trapezoid_arc", "rectangle_arc"):
        label = shape.replace("_arc", " along the wheels' arc")
        rows.append(Row(f"false stops, {label}", None, found[f"{shape}_false_stops"], ""))
        rows.append(Row(f"false slows, {label}", None, found[f"{shape}_false_slows"], ""))
    fewer = found["trapezoid_false_stops"] + found["trapezoid_false_slows"]
    more = found["rectangle_false_stops"] + found["rectangle_false_slows"]
    rows.append(Row("the trapezoid avoids the rectangle's false detections", "yes (Fig. 14a-b)",
                    "yes" if fewer < more else "no: no advantage shown on this lane", ""))  # fmt: skip
    return ExperimentResult(
        "ares-fig14",
        "Obstacle search area: trapezoid beside rectangle",
        "ARES paper Fig. 14, §3.5.3",
        rows,
        notes=[
            "The simulated LiDARs of the ARES shuttle at full resolution, the lane of the default tour (s 60-200 m)."
        ],
    )
