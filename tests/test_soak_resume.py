"""A soak in segments (ares/tools/soak/resume.py) on soak directories written here as the runner
writes them: what the next segment runs, and the figures of all the segments as one soak's."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from ares.tools.soak import resume
from ares.tools.soak.plan import MIN_SLOT_S, PlannedFault

LEAD_S = 60.0


def fault_row(index: int, t: float, kind: str = "kill_process", **changes) -> dict:
    row = {
        "index": index,
        "at_s": t - LEAD_S,
        "kind": kind,
        "t": t,
        "injected": True,
        "detail": "",
        "safety_relevant": True,
        "overlapped": False,
        "time_to_safe_state_s": 0.3,
        "time_to_safe_state_wall_s": 0.6,
        "time_to_standstill_s": 2.0,
        "time_to_recover_s": 5.0,
        "lost_s": 0.0,
    }
    return {**row, **changes}


def write_segment(
    path: Path,
    plan: list[PlannedFault],
    rows: list[dict],
    end_t: float,
    *,
    finished: bool = False,
    offset_s: float = 0.0,
    s: float = 640.0,
    measured_s: float = 1000.0,
    available_s: float = 900.0,
    collisions: int = 0,
    min_clearance_m: float = 5.0,
) -> None:
    path.mkdir(parents=True, exist_ok=True)
    whole = {
        "seed": 3,
        "hours": 1.0,
        "faults": len(plan),
        "lead_s": LEAD_S,
        "kinds": ["kill_process", "rtk_loss"],
        "lidars": [],
        "configs": ["/abs/no_lidars.yaml"],
        "route": None,
        **({"segment": {"of": "x", "index": 1, "plan_offset_s": offset_s}} if offset_s else {}),
        "plan": [f.as_dict() for f in plan],
    }
    (path / "plan.json").write_text(json.dumps(whole))
    (path / "faults.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    progress = {
        "t": end_t,
        "t_start_s": 20.0,
        "plan_start_s": LEAD_S,
        "s": s,
        "measured_s": measured_s,
        "available_s": available_s,
        "collisions": collisions,
        "invariant_violations": 0,
        "invariant_examples": [],
        "min_clearance_m": min_clearance_m,
        "closest_approach": {"t": end_t - 5.0, "obstacle": "cart_1", "kind": "cart", "v_mps": 0.0},
        "router_restarts": 1,
        "rearms": 2,
        "engagements": 0,
        "process_restarts": {"mpc": 2},
        "wall_s": 700.0,
    }
    (path / "progress.json").write_text(json.dumps(progress))
    result = {"ok": finished, "finished": finished, "run": {"ok": finished, **progress}}
    (path / "soak.json").write_text(json.dumps(result))
    (path / "timeline.csv").write_text("t,v,level\n" + "".join(f"{t},{2.0},0\n" for t in range(60, int(end_t))))


PLAN = [
    PlannedFault(index=k, at_s=100.0 * k + 10.0, kind="kill_process", duration_s=0.0, target="mpc") for k in range(8)
]


@pytest.fixture
def stopped(tmp_path) -> Path:
    """A soak stopped at stack time 460 s (plan time 400 s): faults 0-2 over, fault 3 (injected at
    430 s) still open when it stopped, 4-7 never injected."""
    root = tmp_path / "soak"
    rows = [fault_row(k, LEAD_S + PLAN[k].at_s) for k in range(3)]
    rows.append(fault_row(3, LEAD_S + PLAN[3].at_s, time_to_recover_s=None))  # written down at the stop
    write_segment(root, PLAN, rows, end_t=460.0)
    return root


def test_the_next_segment_runs_the_plan_s_rest_moved_back_from_where_the_shuttle_stood(stopped):
    spec = resume.next_segment(stopped)
    assert [f.index for f in spec["plan"]] == [3, 4, 5, 6, 7]  # the one cut short comes again
    assert spec["plan"][0].at_s == 0.0  # at once (its time, 310 s, lies before the plan time reached, 400 s)
    assert [f.at_s for f in spec["plan"][1:]] == [10.0, 110.0, 210.0, 310.0]  # 410 s -> 10 s, ...
    assert spec["segment"]["plan_offset_s"] == 400.0 and spec["segment"]["index"] == 1
    assert spec["out_dir"] == stopped / "segments" / "1" and spec["start_s_m"] == 640.0
    assert spec["hours"] == pytest.approx(1.0 - 400.0 / 3600.0)
    assert spec["configs"] == ("/abs/no_lidars.yaml",) and spec["seed"] == 3 and spec["lead_s"] == LEAD_S


def test_faults_cut_short_come_again_each_once_the_one_before_is_over_and_a_slot_has_passed(tmp_path):
    plan = [PlannedFault(index=k, at_s=1.0 * k, kind="rtk_loss", duration_s=0.5) for k in range(3)]
    rows = [fault_row(k, LEAD_S + k, kind="rtk_loss", time_to_recover_s=None) for k in range(3)]
    root = tmp_path / "soak"
    write_segment(root, plan, rows, end_t=LEAD_S + 3.0)
    assert [f.at_s for f in resume.next_segment(root)["plan"]] == [0.0, 0.5 + MIN_SLOT_S, 2 * (0.5 + MIN_SLOT_S)]


def test_a_fault_given_up_on_is_not_injected_again(tmp_path):
    root = tmp_path / "soak"
    rows = [fault_row(0, LEAD_S + 10.0, time_to_recover_s=None)]  # open 700 s before the stop: given up
    write_segment(root, PLAN, rows, end_t=LEAD_S + 710.0)
    assert 0 not in [f.index for f in resume.next_segment(root)["plan"]]


def test_a_finished_soak_or_none_at_all_is_not_resumed(tmp_path, stopped):
    every_fault_over = [fault_row(k, LEAD_S + PLAN[k].at_s) for k in range(8)]
    write_segment(tmp_path / "done", PLAN, every_fault_over, 900.0, finished=True)
    with pytest.raises(ValueError, match="run to its end"):
        resume.next_segment(tmp_path / "done")
    with pytest.raises(ValueError, match="no soak there"):
        resume.next_segment(tmp_path / "nothing")


def test_the_segments_figures_are_one_soak_s(stopped):
    spec = resume.next_segment(stopped)
    rest_rows = [fault_row(f.index, LEAD_S + f.at_s, time_to_safe_state_s=0.5 + f.index / 10) for f in spec["plan"]]
    write_segment(
        spec["out_dir"], spec["plan"], rest_rows, end_t=LEAD_S + 400.0, finished=True, offset_s=400.0,
        measured_s=500.0, available_s=400.0, collisions=0, min_clearance_m=2.5,
    )  # fmt: skip
    assert resume.segment_dirs(stopped) == [stopped, spec["out_dir"]]
    summary = resume.merged_summary(stopped)
    assert summary["segments"] == 2 and summary["finished"] and summary["ok"]
    assert summary["faults_injected"] == 8  # each fault once: 3 is the second segment's
    assert summary["faults_cut_short"] == 1 and summary["time_to_safe_state_max_cut_short_s"] == 0.3
    assert summary["all"]["not_recovered"] == 0
    assert summary["time_to_safe_state_max_s"] == pytest.approx(1.2)  # fault 7, in the second segment
    assert summary["vehicle_hours"] == pytest.approx(1500.0 / 3600.0, abs=1e-3)
    assert summary["availability"] == pytest.approx(1300.0 / 1500.0, abs=1e-5)
    assert summary["run"]["process_restarts"] == 4 and summary["run"]["router_restarts"] == 2
    assert summary["plan_hours_reached"] == pytest.approx(800.0 / 3600.0, abs=1e-3)
    assert summary["min_clearance_m"] == 2.5  # the second segment's, and where it was
    assert summary["closest_approach"] == {
        "t": LEAD_S + 395.0,
        "obstacle": "cart_1",
        "kind": "cart",
        "v_mps": 0.0,
        "plan_t_s": 795.0,  # the second segment began at plan time 400 s
        "segment": "1",
    }
    assert [s["faults_kept"] for s in summary["per_segment"]] == [3, 5]
    # the faults on the whole soak's plan clock: fault 4 at 410 s wherever its segment began
    rows = {r["index"]: r for seg in resume.segment_dirs(stopped) for r in resume.Segment(seg).kept_rows()}
    assert rows[4]["plan_t_s"] == pytest.approx(410.0) and rows[1]["plan_t_s"] == pytest.approx(110.0)
    written = resume.write_merged(stopped)
    assert (stopped / "soak-all.json").exists() and Path(written["picture"]).stat().st_size > 10_000
    timeline, starts = resume.merged_timeline([resume.Segment(d) for d in resume.segment_dirs(stopped)])
    assert starts == [400.0] and timeline[0][0] == 0.0 and max(r[0] for r in timeline) > 700.0


def test_a_soak_from_before_resume_existed_is_refused_and_the_start_is_the_last_one_known(tmp_path, stopped):
    old = tmp_path / "old"
    write_segment(old, PLAN, [], end_t=200.0)
    plan = json.loads((old / "plan.json").read_text())
    del plan["configs"]
    (old / "plan.json").write_text(json.dumps(plan))
    with pytest.raises(ValueError, match="does not record the soak's configuration"):
        resume.next_segment(old)
    # a resumed segment that died before it said where the shuttle stood: the one before says
    spec = resume.next_segment(stopped)
    spec["out_dir"].mkdir(parents=True)
    (spec["out_dir"] / "plan.json").write_text(json.dumps({**plan, "segment": spec["segment"]}))
    again = resume.next_segment(stopped)
    assert again["start_s_m"] == 640.0 and again["segment"]["index"] == 2
    assert again["segment"]["plan_offset_s"] == 400.0  # it got no further


def test_a_soak_s_plan_records_a_route_file_to_resume_with(tmp_path):
    from ares.tools.soak.runner import Soak, SoakOptions

    route = tmp_path / "street.csv"  # an open route file: a 300 m straight street
    route.write_text("x,y,z\n" + "".join(f"{x}.0,0.0,0.0\n" for x in range(300)))
    no_lidars = str(Path(__file__).with_name("no_lidars.yaml"))
    opts = SoakOptions(
        hours=0.1, faults=5, seed=1, out_dir=tmp_path / "soak", configs=(no_lidars,), route=str(route),
        kinds=("rtk_loss",),
    )  # fmt: skip
    Soak(opts).configure()  # (it wrote a Path into plan.json once: a TypeError)
    plan = json.loads((tmp_path / "soak" / "plan.json").read_text())
    assert plan["route"] == str(route.resolve()) and plan["configs"] == [no_lidars]
