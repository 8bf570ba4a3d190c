"""The perception process on the in-memory bus, fed with simulated sweeps of the tour: the grid,
the road and each sensor's health, and a covered sensor reported."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ares.core.clock import ManualClock
from ares.core.config import load_vehicle
from ares.core.membus import MemoryNetwork
from ares.core.messages import CarState, DriveMode, PointCloud
from ares.core.route import Route
from perception.lidar_perception_node import LidarPerception
from simulator.lidar import LidarSimParams, SimulatedLidar, vehicle_pose
from simulator.params import SimParams
from simulator.road import grade_at, roughness_for
from simulator.world import World

PERIOD = 0.1


class PerceptionOnTheBus:
    def __init__(self, cfg, s0: float):
        self.route = Route.from_tour("default")
        self.world = World(self.route, roughness_for(self.route, SimParams(), 2.8))
        shuttle = load_vehicle("ares_shuttle")
        light = LidarSimParams(azimuth_decimation=4)
        self.sensors = {
            n: SimulatedLidar(n, m, shuttle, light, np.random.default_rng(i))
            for i, (n, m) in enumerate(shuttle.lidars.items())
        }
        self.clock = ManualClock(10.0)
        network = MemoryNetwork()
        self.node = LidarPerception(cfg, clock=self.clock, bus=network.bus("lidar_perception", self.clock))
        self.node.setup()
        self.bus = network.bus("test", self.clock)
        self.clouds = {n: self.bus.publisher(f"lidar/{n}/points") for n in self.sensors}
        self.grids = self.bus.subscribe("perception/grid", queue=100)
        self.roads = self.bus.subscribe("perception/road", queue=100)
        self.status = self.bus.subscribe("perception/lidar_status", queue=100)
        self.events = self.bus.subscribe("events", queue=100)
        self.s = s0

    def frame(self, covered: tuple[str, ...] = (), step: bool = True) -> None:
        """The sensors sweep from the vehicle 0.4 m further on; the node steps (unless `step` is
        False: the sweeps came late, after the node's step)."""
        self.s += 0.4
        x, y, _, yaw = self.route.point_at(self.s)
        rotation, position = vehicle_pose(
            x, y, float(self.world.centre_height(self.s)), yaw, -math.atan(grade_at(self.route, self.s))
        )
        t = round(self.clock.now() + PERIOD, 6)
        for name, sensor in self.sensors.items():
            sensor.blocked = name in covered
            sweep = sensor.sweep(self.world.scene, rotation, position, None, self.world.material_of)
            self.clouds[name].put(
                PointCloud(
                    t=t,
                    sensor=name,
                    frame=f"lidar/{name}",
                    x=sweep.x,
                    y=sweep.y,
                    z=sweep.z,
                    intensity=sweep.intensity,
                    ring=sweep.ring,
                )
            )
        self.clock.set(t)
        if step:
            self.node.step_once(t)


@pytest.fixture(scope="module")
def kerbed_street(request):
    from ares.core.localhost import free_port
    from tests.helpers.stack import make_run_config

    bus = PerceptionOnTheBus(make_run_config(free_port()), s0=720.0)  # the lakeside promenade: kerbs
    for _ in range(12):
        bus.frame()
    return bus


def test_a_grid_a_road_and_the_sensors_health_every_frame(kerbed_street):
    grids = [m for _, m in kerbed_street.grids.drain()]
    roads = [m for _, m in kerbed_street.roads.drain()]
    status = [m for _, m in kerbed_street.status.drain()]
    assert len(grids) == len(roads) == len(status) == 12
    grid = grids[-1]
    assert grid.cells.shape == (100, 100) and grid.resolution_m == 0.2
    assert grid.origin_x == pytest.approx(1.4 - 10.0) and grid.origin_y == pytest.approx(-10.0)
    cells = np.asarray(grid.cells)
    assert (cells == 0).mean() > 0.3  # much of it seen free
    road = roads[-1]
    assert road.found and road.confidence > 0.5
    assert road.left.y_at(6.0) == pytest.approx(3.0, abs=0.2) and road.right.y_at(6.0) == pytest.approx(-3.0, abs=0.2)
    assert abs(road.lateral_offset_m) < 0.1 and abs(math.degrees(road.heading_rad)) < 2.0
    health = status[-1].sensors
    assert set(health) == {"roof", "front_left", "front_right"}
    assert all(h.points > 1000 and h.rate_hz == pytest.approx(10.0) and not h.blind for h in health.values())
    assert health["roof"].road_points > 100
    assert set(status[-1].stage_ms) >= {"transform", "filters", "ground", "grid", "road", "total"}


def test_a_covered_sensor_is_reported_blind_and_seeing_again(kerbed_street):
    kerbed_street.events.drain()
    kerbed_street.frame(covered=("roof",))
    status = kerbed_street.status.drain()[-1][1]
    assert status.sensors["roof"].points == 0 and status.sensors["roof"].blind
    events = [e for _, e in kerbed_street.events.drain()]
    assert [e.kind for e in events] == ["lidar_blind"] and events[0].data["sensor"] == "roof"
    assert kerbed_street.roads.drain()[-1][1].found  # the corner sensors still see the kerbs
    kerbed_street.frame()
    assert [e.kind for _, e in kerbed_street.events.drain()] == ["lidar_sees"]


def test_sweeps_that_came_late_count_in_the_rate(kerbed_street):
    """Under the lockstep a sweep can reach perception just after its step, and the next sweep
    replaces it before the following step: each still came from the sensor and counts (they were
    missed once, and three such in a second read 7 Hz: an emergency stop on a busy machine)."""
    for _ in range(4):  # every other step finds two sweeps waiting
        kerbed_street.frame(step=False)
        kerbed_street.frame()
    status = kerbed_street.status.drain()[-1][1]
    assert all(h.rate_hz == pytest.approx(10.0) for h in status.sensors.values())


def test_a_lost_road_is_moved_by_the_measured_speed_and_steering_to_guide_the_next_frames():
    from ares.core.localhost import free_port
    from tests.helpers.stack import make_run_config

    bus = PerceptionOnTheBus(make_run_config(free_port()), s0=700.0)
    car = bus.bus.publisher("dbw/car_state")

    def drive(covered=()):
        car.put(
            CarState(
                t=bus.clock.now(),
                mode=DriveMode.AUTOMATIC,
                engaged=True,
                watchdog_tripped=False,
                setpoint_age_s=0.0,
                v_command=4.0,
                kappa_command=0.0,
                speed_mps=4.0,
                steering_wheel_deg=0.0,
            )
        )
        bus.frame(covered)  # 0.4 m on, 0.1 s later

    for _ in range(3):
        drive()
    assert bus.roads.drain()[-1][1].found and bus.node.pipeline.since_found[3] == 0.0
    drive(covered=tuple(bus.sensors))  # nothing seen: lost
    assert not bus.roads.drain()[-1][1].found
    assert bus.node.pipeline.since_found[3] == pytest.approx(0.4)  # the frames 0.1 s apart at 4 m/s
    drive()
    assert bus.roads.drain()[-1][1].found
    drive(covered=tuple(bus.sensors))
    assert bus.node.pipeline.since_found[3] == pytest.approx(0.4)
    bus.clock.set(bus.clock.now() + 1.0)  # a gap of a second in the frames: not moved across
    drive(covered=tuple(bus.sensors))
    assert bus.node.pipeline.since_found is None
    drive()
    drive(covered=tuple(bus.sensors))
    assert bus.node.pipeline.since_found[3] == pytest.approx(0.4)
    bus.clock.set(bus.clock.now() + 1.0)  # the speed goes stale: a lost road cannot be moved
    bus.frame(covered=tuple(bus.sensors))
    assert bus.node.pipeline.since_found is None
