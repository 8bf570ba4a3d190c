"""A real drive, imported as `ares route import` does, gets a world whose road is clear.

tests/data/munich_town_drive.nmea is a receiver's log of 88 s of driving in Munich (1 Hz GGA,
3-6 satellites, HDOP 2-10, no RTK; see tests/data/README.md): two sharp town corners, a wait, a
jumpy start. Its route wiggles and its curvature spikes where the fixes jump, which is where the
world's cross-sections, laid along each station's own normal, used to fold verges and kerbs onto
the road. Here the world built for it is checked against the whole centre line: looking down on
the drivable corridor (half the shuttle, the obstacle manager's margin and an allowance for the
cross-track error) nothing stands above the road's surface, no tree, pole or crown comes near any
stretch, and the obstacle manager's view of simulated LiDAR frames at the sharpest corners finds
nothing in the way.

The import itself makes the drive drivable: the receiver's altitude (it climbs 350 m in 88 s while
it converges) is not used, the fixes of the waits and of the creeping start and stop collapse to one
point each, the path is smoothed until no turn is sharper than the shuttle can steer, and the road is
a town street's 5.5 m.
"""

from __future__ import annotations

import numpy as np
import pytest

from ares.app import route_import
from ares.core.config import load_vehicle
from ares.core.route import Route
from simulator import world as world_mod
from simulator.world import World

LOG = "tests/data/munich_town_drive.nmea"
XTE_ALLOWANCE_M = 0.6  # the cross-track error the whole drive may show (issue 25 saw 0.59 m)
ABOVE_ROAD_TOL_M = 0.05  # the grid calls 0.2 m above the local ground an obstacle


@pytest.fixture(scope="module")
def imported(tmp_path_factory) -> tuple[route_import.ImportResult, Route]:
    out = tmp_path_factory.mktemp("drive") / "route.csv"
    result = route_import.import_route(LOG, output=out)
    assert result.fmt == "nmea" and result.points_in == 88 and result.log.non_rtk == 88
    assert 300 < result.length_m < 400
    return result, Route.from_csv(out)


@pytest.fixture(scope="module")
def route(imported) -> Route:
    return imported[1]


@pytest.fixture(scope="module")
def flat_route(route) -> Route:
    """The route as imported: flat, since the import does not use altitudes without RTK."""
    return route


@pytest.fixture(scope="module")
def world(flat_route) -> World:
    return World(flat_route, None, seed=7)


def corridor_half_width() -> float:
    from managers.obstacle import ObstacleParams

    return load_vehicle("ares_shuttle").width_m / 2 + ObstacleParams().near_margin_m + XTE_ALLOWANCE_M


def sharpest_corners(route: Route, count: int, apart_m: float = 20.0) -> list[float]:
    """Arc lengths of the route's sharpest turns: the heading's change over 16 m (a corner, not a
    wiggle of the fixes), peaks apart_m apart, away from the route's ends."""
    span = 32  # samples of 0.5 m
    heading = np.unwrap(route.yaw)
    turn = np.zeros_like(heading)
    turn[span // 2 : -span // 2] = np.abs(heading[span:] - heading[:-span])
    picked: list[float] = []
    for i in np.argsort(-turn):
        if all(abs(route.s[i] - s) > apart_m for s in picked):
            picked.append(float(route.s[i]))
        if len(picked) == count:
            break
    return picked


def turn_at(route: Route, s: float, span: int = 32) -> float:
    heading = np.unwrap(route.yaw)
    i = route.index_at(s)
    return float(np.degrees(abs(heading[min(i + span // 2, len(heading) - 1)] - heading[max(i - span // 2, 0)])))


def test_the_log_imports_as_a_town_drive_with_sharp_corners(route):
    assert route.width[0] == pytest.approx(5.5)  # route_import.road_width_m, a town street
    # the import rounds them to what the shuttle steers (fixes with metres of noise, smoothed over ~30 m):
    # still over 50 deg within 40 m each
    assert [turn_at(route, s, span=80) > 50.0 for s in sharpest_corners(route, 2)] == [True, True]


def test_the_altitude_without_rtk_is_not_used(imported):
    result, route = imported
    assert result.log.altitude_dropped == 88
    assert np.all(route.z == 0.0) and np.all(route.grade == 0.0)  # not 178 -> 523 m, +-1000 % grades
    assert "altitude of the 88 fixes without RTK not used" in result.summary()
    assert "the route is flat" in result.summary()


def test_the_shuttle_can_steer_every_turn_and_the_ends_have_no_hooks(imported):
    """Before: a hook of 2.4 m radius at the start (a jump of the second fix) and a 150 deg swing at
    s ~ 307 m (the fixes wandering while the car stood), curvatures up to 1/0.35 m."""
    result, route = imported
    vehicle = load_vehicle("ares_shuttle")
    assert np.abs(route.curvature).max() <= vehicle.max_curvature  # radius >= 8.7 m
    heading = np.degrees(np.unwrap(route.yaw))
    for end in (slice(0, 21), slice(-21, None)):  # the first and last 10 m
        assert np.ptp(heading[end]) < 15.0
    # the two waits (22 identical fixes, then the creep to a stop) and the wander at the end: a point each
    assert result.kept < 50
    assert "fixes without RTK wander" in result.summary() and "smoothed over" in result.summary()
    assert "sharper than the vehicle" not in result.summary()
    # the corners are rounded, not moved: the route passes within a few metres of every fix it drives by
    fixes = route_import.project_fixes(result.log, _frame(result), "log")
    gap = np.min(np.hypot(fixes[:, None, 0] - route.x[None, :], fixes[:, None, 1] - route.y[None, :]), axis=1)
    assert np.median(gap) < 1.0 and gap.max() < 6.0


def _frame(result):
    from ares.core.geodesy import LocalFrame

    return LocalFrame(result.origin)


def test_nothing_stands_above_the_road_in_the_corridor(world, flat_route):
    """Rays straight down onto every point of the corridor (0.25 m grid) meet the road's surface first."""
    route = flat_route
    half_corridor = corridor_half_width()
    assert half_corridor <= route.width.min() / 2  # the corridor lies within the road
    lo = np.array([route.x.min(), route.y.min()]) - 3.0
    hi = np.array([route.x.max(), route.y.max()]) + 3.0
    gx, gy = np.meshgrid(np.arange(lo[0], hi[0], 0.25), np.arange(lo[1], hi[1], 0.25))
    points = np.stack([gx.ravel(), gy.ravel()], axis=1)
    tree, station = world._centre_line()
    dist, j = tree.query(points)
    inside = dist <= half_corridor
    points, dist, st = points[inside], dist[inside], station[j[inside]]
    surface = world.centre_height(world.route.s[st]) - world_mod.CROSSFALL * dist  # (its road runs on past the end)
    top = float(route.z.max()) + 50.0
    o3d = world_mod.open3d()
    rays = np.zeros((len(points), 6), dtype=np.float32)
    rays[:, :2], rays[:, 2], rays[:, 5] = points, top, -1.0
    hit = top - world.scene.cast_rays(o3d.core.Tensor(rays))["t_hit"].numpy()
    above = hit - surface
    worst = int(np.argmax(above))
    assert above[worst] < ABOVE_ROAD_TOL_M, (
        f"{above[worst]:.2f} m above the road at ({points[worst][0]:.1f}, {points[worst][1]:.1f}), "
        f"s {world.route.s[st[worst]]:.1f} m, {dist[worst]:.2f} m from the centre line"
    )


def test_the_road_goes_on_past_the_routes_end(world, flat_route):
    """Where an open route ends, the road does not: a shuttle stopping at the end still has road
    ahead for its LiDARs' road detection (else the awareness manager stops it short, road hidden)."""
    assert world.route.length >= flat_route.length + world_mod.RUNOUT_M - 1e-6
    assert np.allclose(world.route.s[: len(flat_route.s)], flat_route.s)  # the route's own arc lengths unchanged
    yaw = float(flat_route.yaw[-1])
    top = float(flat_route.z.max()) + 50.0
    rays = np.array(
        [
            [flat_route.x[-1] + d * np.cos(yaw), flat_route.y[-1] + d * np.sin(yaw), top, 0.0, 0.0, -1.0]
            for d in (5.0, 15.0, 25.0)
        ],
        dtype=np.float32,
    )
    hit = world.scene.cast_rays(world_mod.open3d().core.Tensor(rays))
    materials = world.material_of(hit["geometry_ids"].numpy(), hit["primitive_ids"].numpy())
    assert set(materials.tolist()) == {world_mod.MATERIAL_IDS["asphalt"]}


def test_trees_and_poles_keep_off_every_stretch(world):
    assert world.objects, "the kerb verges of an imported route get trees and poles"
    for obj in world.objects:
        gap = world.clearance(obj.vertices[:, :2])
        assert gap.min() >= world_mod.CROWN_ROAD_GAP_M - 0.05  # crowns and trunks beyond every edge


def test_the_obstacle_manager_sees_the_sharpest_corners_clear(flat_route, world):
    from ares.tools.bench.obstacle_zone import path_ahead
    from managers.obstacle import ObstacleParams, judge, occupied_cells, zone_for
    from perception.lidar_perception import LidarPipeline, SensorSweep
    from simulator.lidar import LidarSimParams, SimulatedLidar, vehicle_pose

    route = flat_route
    vehicle = load_vehicle("ares_shuttle")
    params = ObstacleParams()
    speed = 3.0  # the zone reaches 7.5 m ahead
    sensors = {
        name: SimulatedLidar(name, mount, vehicle, LidarSimParams(), np.random.default_rng([7, k]))
        for k, (name, mount) in enumerate(sorted(vehicle.lidars.items()))
    }
    verdicts = {}
    for apex in sharpest_corners(route, 3):
        for s in (apex - 4.0, apex):  # entering the corner, and at its apex
            s = min(max(s, 1.0), route.length - 1.0)
            x, y, _, yaw = route.point_at(s)
            rotation, position = vehicle_pose(x, y, float(world.centre_height(s)), yaw, 0.0)
            pipeline = LidarPipeline(vehicle)
            sweeps = []
            for name, sensor in sensors.items():
                sw = sensor.sweep(world.scene, rotation, position, None, world.material_of)
                sweeps.append(SensorSweep(name, np.stack([sw.x, sw.y, sw.z], axis=1).astype(np.float32), sw.ring))
            result = pipeline.process(sweeps)
            grid = pipeline.mapper.grid
            ox, oy = occupied_cells(result.grid, grid.origin_x, grid.origin_y, grid.cell_m)
            kappa = float(route.curvature[route.index_at(s)])
            centre = path_ahead(route, s, vehicle.front_bumper_m + params.headway_s * speed + 5.0)
            zone = zone_for(params, speed, kappa, vehicle.width_m, vehicle.front_bumper_m, centre=centre)
            verdicts[round(s, 1)] = judge(params, zone, ox, oy, speed)
    blocked = {s: (v.band, v.nearest_m, v.cells) for s, v in verdicts.items() if v.band not in ("clear", "ready")}
    assert not blocked, f"obstacles in the way at s (band, nearest m, cells): {blocked}"


def test_a_headless_run_that_ends_held_says_by_what_why_and_where(route):
    """`ares run --headless` ending held: its JSON's `stopped` names what holds it (a manager, an emergency
    stop), why and where."""
    from ares.app import run_config
    from ares.app.headless import Measurements
    from ares.core.clock import ManualClock
    from ares.core.membus import MemoryNetwork
    from ares.core.messages import MovementStatus, ObstacleState, VehicleTruth

    cfg = run_config.build(overrides={"lidars": False})
    net, clock = MemoryNetwork(), ManualClock()
    m = Measurements(cfg, route, net.bus("headless", clock), lambda process, action: "")
    sim = net.bus("sim", clock)
    x, y, _, yaw = route.point_at(120.0)

    def tick(t: float, limit: float, obstacle_band: str) -> None:
        sim.publish(
            "sim/truth",
            VehicleTruth(
                t=t,
                x=x,
                y=y,
                z=0.0,
                yaw=yaw,
                v=0.0,
                steering_wheel_deg=0.0,
                wheel_angle_rad=0.0,
                s=120.0,
                odometer_m=120.0,
            ),
        )
        reason = "obstacle 1.5 m ahead (3 cells)" if obstacle_band == "stop" else ""
        sim.publish(
            "obstacle/state",
            ObstacleState(
                t=t,
                score=0.3,
                band=obstacle_band,
                nearest_m=1.5,
                limit_mps=limit,
                length_m=5.0,
                cells=3,
                area_x=[],
                area_y=[],
                reason=reason,
            ),
        )
        sim.publish(
            "movement/status",
            MovementStatus(
                t=t,
                level=0,
                latched=False,
                stopping=False,
                limit_mps=limit,
                limited_by="obstacle" if limit == 0 else "",
                limits={"obstacle": limit},
                v=0.0,
                kappa=0.0,
                reason=f"limited by obstacle ({limit:.2f} m/s)",
            ),
        )
        m.take(t)

    tick(1.0, 2.0, "clear")
    assert "stopped" not in m.partial()
    tick(2.0, 0.0, "stop")
    tick(3.0, 0.0, "stop")
    stopped = m.partial()["stopped"]
    assert stopped == {
        "by": "obstacle_manager",
        "since_t_s": 2.0,
        "at_s_m": 120.0,
        "x": round(x, 2),
        "y": round(y, 2),
        "reason": "obstacle 1.5 m ahead (3 cells)",
    }
    tick(4.0, 2.0, "clear")  # the way clears: not held any more
    assert "stopped" not in m.partial()
    # an emergency stop latched by the awareness manager: the gate's reason carries the cause
    cause = "lidar roof: 7.0 Hz < 8"
    sim.publish(
        "movement/status",
        MovementStatus(
            t=5.0,
            level=1,
            latched=True,
            latch_cause=cause,
            stopping=False,
            limit_mps=0.0,
            limited_by="emergency",
            limits={"obstacle": 2.0},
            v=0.0,
            kappa=0.0,
            reason=f"emergency stop latched ({cause}): waiting for a re-arm",
        ),
    )
    m.take(5.0)
    stopped = m.partial()["stopped"]
    assert stopped["by"] == "emergency" and cause in stopped["reason"] and stopped["since_t_s"] == 5.0
