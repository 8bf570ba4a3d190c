"""What a headless run measures of perception, against the simulator's truth.

Road detection (perception/road): each frame is paired with the true pose at the same stack time
(the sweep's time). A frame counts towards `road_detect_rate` where the road has a boundary on
both sides from 2 to 10 m ahead (a verge other than open, within 6 m of the centre line): the
share of those frames with both boundaries found. Each found boundary is sampled 2–10 m ahead,
taken into the local frame with the true pose and projected on the route: its lateral error is
its distance from the true edge (route offset ± half the width) where that edge exists; the
centre line's is its distance from the route.

Occupancy grid (perception/grid), paired with the true pose and the world's obstacles at its
time: `grid_obstacle_recall` is the share of (frame, obstacle) pairs, obstacles at least 0.3 m
tall lying ahead of the front bumper within 10 m of the grid's centre and wholly on the grid,
whose footprint (grown by one cell) holds an occupied cell. `grid_false_occupied_road` is the
share of road-surface cells (0.2 m or more inside the edges, no obstacle within 0.5 m, within
10 m of the grid's centre) marked occupied.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass, field

import numpy as np
from scipy.spatial import cKDTree

from ares.core.geometry import vehicle_to_local
from ares.core.messages import LidarStatus, OccupancyGrid, RoadDetection, WorldTruth
from ares.core.route import Route
from ares.core.stats import percentile
from simulator.world import BOUNDARY_VERGES

AHEAD_M = (2.0, 4.0, 6.0, 8.0, 10.0)
EDGE_WITHIN_M = 6.0
MIN_OBSTACLE_HEIGHT_M = 0.3
RECALL_REACH_M = 10.0
ROAD_INSET_M = 0.2
OBSTACLE_MARGIN_M = 0.5


CONFIDENCE_RIGHT_M = 0.3  # a detection whose centre line is this close to the truth at the vehicle is right
CONFIDENCE_WRONG_M = 0.5  # ... this far off, wrong


@dataclass
class PerceptionTracker:
    route: Route
    front_bumper_x_m: float  # in the vehicle frame (rear axle at 0)
    truth_t: list[float] = field(default_factory=list)
    truth: list[tuple[float, float, float, float]] = field(default_factory=list)  # x, y, yaw, s
    worlds: dict[float, WorldTruth] = field(default_factory=dict)
    frames_with_edges: int = 0
    frames_both_found: int = 0
    edge_err: list[float] = field(default_factory=list)
    centre_err: list[float] = field(default_factory=list)
    confidence_right: list[float] = field(default_factory=list)  # the centre line within 0.3 m at the vehicle
    confidence_wrong: list[float] = field(default_factory=list)  # ... more than 0.5 m off (or a wrong find)
    recall_seen: int = 0
    recall_total: int = 0
    road_cells: int = 0
    road_cells_occupied: int = 0
    stage_ms: list[float] = field(default_factory=list)
    stage_cpu_ms: list[float] = field(default_factory=list)
    blocked_points: dict[str, list[int]] = field(default_factory=dict)
    waiting: list = field(default_factory=list)  # messages whose truth has not arrived yet

    def __post_init__(self) -> None:
        self.tree = cKDTree(np.stack([self.route.x, self.route.y], axis=1))

    # ---- inputs ------------------------------------------------------------------------------
    def add_truth(self, t: float, x: float, y: float, yaw: float, s: float) -> None:
        self.truth_t.append(t)
        self.truth.append((x, y, yaw, s))

    def add_world(self, msg: WorldTruth) -> None:
        self.worlds[round(msg.t, 3)] = msg

    def _pose_at(self, t: float):
        i = bisect.bisect_left(self.truth_t, t - 1e-6)
        if i < len(self.truth_t) and abs(self.truth_t[i] - t) < 1e-3:
            return self.truth[i]
        return None

    def _to_local(self, pose, xv: np.ndarray, yv: np.ndarray):
        x, y, yaw, _ = pose
        return vehicle_to_local(x, y, yaw, xv, yv)

    def _edges(self, s: float) -> tuple[float | None, float | None]:
        left, right = self.route.verge_at(s)
        half = float(self.route.width[self.route.index_at(s)]) / 2
        ok = half <= EDGE_WITHIN_M
        return (half if ok and left in BOUNDARY_VERGES else None, -half if ok and right in BOUNDARY_VERGES else None)

    def add_road(self, msg: RoadDetection) -> None:
        if not self._road(msg):
            self.waiting.append(msg)

    def add_grid(self, grid: OccupancyGrid) -> None:
        if not self._grid(grid):
            self.waiting.append(grid)

    def retry(self, give_up_s: float = 2.0) -> None:
        """Judge what waited for its truth; drop what waited too long (the run's end, a gap)."""
        latest = self.truth_t[-1] if self.truth_t else -math.inf
        still = []
        for msg in self.waiting:
            done = self._road(msg) if isinstance(msg, RoadDetection) else self._grid(msg)
            if not done and latest - msg.t < give_up_s:
                still.append(msg)
        self.waiting = still
        horizon = latest - give_up_s - 1.0
        for t in [t for t in self.worlds if t < horizon]:
            del self.worlds[t]

    def _road(self, msg: RoadDetection) -> bool:
        """One detection; False if the truth at its time is not known (yet)."""
        pose = self._pose_at(msg.t)
        if pose is None:
            return False
        s = pose[3]
        ahead = [self._edges(s + d) for d in AHEAD_M]
        if all(left is not None and right is not None for left, right in ahead):
            self.frames_with_edges += 1
            if msg.found and msg.left is not None and msg.right is not None:
                self.frames_both_found += 1
        xs = np.array(AHEAD_M)
        for side, boundary in ((0, msg.left), (1, msg.right)):
            if boundary is None:
                continue
            for xv in xs:
                wx, wy = self._to_local(pose, xv, boundary.y_at(xv))
                s_hit, xte, _ = self.route.project(wx, wy, s_hint=s + xv)
                edge = self._edges(s_hit)[side]
                if edge is not None:
                    self.edge_err.append(abs(xte - edge))
        if (
            msg.found
            and msg.centre is not None
            and all(left is not None and right is not None for left, right in ahead)
        ):
            wx, wy = self._to_local(pose, 0.0, msg.centre.y_at(0.0))
            off = abs(self.route.project(wx, wy, s_hint=s)[1])
            if off < CONFIDENCE_RIGHT_M:
                self.confidence_right.append(msg.confidence)
            elif off > CONFIDENCE_WRONG_M:
                self.confidence_wrong.append(msg.confidence)
        if msg.centre is not None and all(left is not None and right is not None for left, right in ahead):
            for xv in xs:
                wx, wy = self._to_local(pose, xv, msg.centre.y_at(xv))
                _, xte, _ = self.route.project(wx, wy, s_hint=s + xv)
                self.centre_err.append(abs(xte))
        return True

    def _grid(self, grid: OccupancyGrid) -> bool:
        pose = self._pose_at(grid.t)
        world = self.worlds.get(round(grid.t, 3))
        if pose is None or world is None:
            return False
        cells = np.asarray(grid.cells)
        rows, cols = cells.shape
        res = grid.resolution_m
        centre_x = grid.origin_x + cols * res / 2
        centre_y = grid.origin_y + rows * res / 2
        occupied = cells == 100
        # obstacles ahead
        x, y, yaw, _ = pose
        c, s = math.cos(yaw), math.sin(yaw)
        footprints = []
        for ob in world.obstacles:
            dx, dy = ob.x - x, ob.y - y
            ox, oy = c * dx + s * dy, -s * dx + c * dy  # in the vehicle frame
            reach = math.hypot(ob.length_m, ob.width_m) / 2
            footprints.append((ox, oy, ob.yaw - yaw, ob.length_m, ob.width_m, reach))
            if ob.height_m < MIN_OBSTACLE_HEIGHT_M:
                continue
            on_grid = (
                grid.origin_x + reach <= ox <= grid.origin_x + cols * res - reach
                and grid.origin_y + reach <= oy <= grid.origin_y + rows * res - reach
            )
            if (
                not on_grid
                or ox - reach < self.front_bumper_x_m
                or math.hypot(ox - centre_x, oy - centre_y) > RECALL_REACH_M
            ):
                continue
            self.recall_total += 1
            inside = _in_box(grid, ox, oy, ob.yaw - yaw, ob.length_m + 2 * res, ob.width_m + 2 * res)
            if occupied[inside].any():
                self.recall_seen += 1
        # road surface cells
        jj, ii = np.mgrid[0:rows, 0:cols]
        cx = grid.origin_x + (ii + 0.5) * res
        cy = grid.origin_y + (jj + 0.5) * res
        near = np.hypot(cx - centre_x, cy - centre_y) <= RECALL_REACH_M
        wx, wy = self._to_local(pose, cx[near], cy[near])
        dist, idx = self.tree.query(np.stack([wx, wy], axis=1))
        road = dist <= self.route.width[idx] / 2 - ROAD_INSET_M
        clear = np.ones(road.shape, dtype=bool)
        for ox, oy, oyaw, length, width, _reach in footprints:
            clear &= ~_in_box_points(
                cx[near], cy[near], ox, oy, oyaw, length + 2 * OBSTACLE_MARGIN_M, width + 2 * OBSTACLE_MARGIN_M
            )
        road &= clear
        self.road_cells += int(road.sum())
        self.road_cells_occupied += int((occupied[near] & road).sum())
        return True

    def add_status(self, status: LidarStatus) -> None:
        if "total" in status.stage_ms:
            self.stage_ms.append(status.stage_ms["total"])
        if "cpu" in status.stage_ms:
            self.stage_cpu_ms.append(status.stage_ms["cpu"])
        world = self.worlds.get(round(status.t, 3))
        for name in world.blocked_lidars if world else []:
            if name in status.sensors:
                self.blocked_points.setdefault(name, []).append(status.sensors[name].points)

    # ---- the figures -------------------------------------------------------------------------
    def summary(self) -> dict:
        return {
            "road_detect_rate": round(self.frames_both_found / self.frames_with_edges, 4)
            if self.frames_with_edges
            else None,
            "road_frames": self.frames_with_edges,
            "road_edge_err_p50_m": percentile(self.edge_err, 50, 4),
            "road_edge_err_p95_m": percentile(self.edge_err, 95, 4),
            "road_centre_err_p50_m": percentile(self.centre_err, 50, 4),
            # what the control manager's road thresholds are chosen from (docs/control.md, "The thresholds")
            "road_confidence_right_p05": percentile(self.confidence_right, 5, 4),
            "road_confidence_right_p50": percentile(self.confidence_right, 50, 4),
            "road_confidence_wrong_p50": percentile(self.confidence_wrong, 50, 4),
            "road_confidence_wrong_p95": percentile(self.confidence_wrong, 95, 4),
            "road_confidence_frames": [len(self.confidence_right), len(self.confidence_wrong)],
            "grid_obstacle_recall": round(self.recall_seen / self.recall_total, 4) if self.recall_total else None,
            "grid_obstacle_frames": self.recall_total,
            "grid_false_occupied_road": round(self.road_cells_occupied / self.road_cells, 5)
            if self.road_cells
            else None,
            "perception_ms_p50": percentile(self.stage_ms, 50, 4),
            "perception_ms_p95": percentile(self.stage_ms, 95, 4),
            "perception_cpu_ms_p50": percentile(self.stage_cpu_ms, 50, 4),
            **(
                {"blocked_lidar_points_max": {k: int(max(v)) for k, v in self.blocked_points.items()}}
                if self.blocked_points
                else {}
            ),
        }


def _in_box_points(px, py, ox, oy, yaw, length, width) -> np.ndarray:
    c, s = math.cos(yaw), math.sin(yaw)
    dx, dy = px - ox, py - oy
    along, across = c * dx + s * dy, -s * dx + c * dy
    return (np.abs(along) <= length / 2) & (np.abs(across) <= width / 2)


def _in_box(grid: OccupancyGrid, ox, oy, yaw, length, width) -> np.ndarray:
    rows, cols = np.asarray(grid.cells).shape
    jj, ii = np.mgrid[0:rows, 0:cols]
    cx = grid.origin_x + (ii + 0.5) * grid.resolution_m
    cy = grid.origin_y + (jj + 0.5) * grid.resolution_m
    return _in_box_points(cx, cy, ox, oy, yaw, length, width)
