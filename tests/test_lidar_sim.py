"""The simulated world and LiDARs (simulator/world.py, lidar.py, obstacles.py) and scenarios."""

from __future__ import annotations

import math

import numpy as np
import pytest

from ares.core.config import ConfigError, LidarMount, load_vehicle
from ares.core.route import Route
from simulator.lidar import LidarSimParams, SimulatedLidar, mount_pose, vehicle_pose
from simulator.obstacles import ObstacleField
from simulator.params import SimParams
from simulator.road import grade_at, roughness_for
from simulator.scenario import Scenario, ScenarioObstacle, ScenarioPlace, load_scenario
from simulator.vehicle import VehiclePlant
from simulator.world import World

LIGHT = LidarSimParams(azimuth_decimation=4, ghosts_per_sweep=0.0, dropout=0.0)


@pytest.fixture(scope="module")
def tour():
    return Route.from_tour("default")


@pytest.fixture(scope="module")
def world(tour):
    return World(tour, roughness_for(tour, SimParams(), 2.8))


@pytest.fixture(scope="module")
def shuttle():
    return load_vehicle("ares_shuttle")


def sweep_in_vehicle_frame(world, tour, shuttle, name, s, params=LIGHT, seed=0, lateral_m=0.0, obstacles=None):
    sensor = SimulatedLidar(name, shuttle.lidars[name], shuttle, params, np.random.default_rng(seed))
    x, y, _, yaw = tour.point_at(s)
    x, y = x - math.sin(yaw) * lateral_m, y + math.cos(yaw) * lateral_m
    pitch = -math.atan(grade_at(tour, s))  # nose down downhill, as the plant's body
    rotation, position = vehicle_pose(x, y, float(world.centre_height(s)), yaw, pitch)
    sweep = sensor.sweep(world.scene, rotation, position, obstacles, world.material_of)
    pts = np.stack([sweep.x, sweep.y, sweep.z], axis=1)
    r, t = mount_pose(shuttle.lidars[name])
    return pts @ r.T + t, sweep, sensor


def test_the_wheels_ride_the_surface_the_lidars_see(tour, world):
    plant = VehiclePlant(tour, "ares_shuttle", SimParams(), s0=100.0)
    st = plant.state
    # at standstill the body rests on the road: the plant's height is the world's crown there
    assert st.z == pytest.approx(float(world.centre_height(st.s)), abs=1e-6)
    # and the surface joins itself at the start line of the closed tour
    assert float(world.centre_height(0.0)) == pytest.approx(float(world.centre_height(tour.length)), abs=1e-9)


def test_verges_come_from_the_tour_and_intersections_are_open(tour, world):
    assert tour.verge_at(100) == ("rock_wall", "rock_wall")
    assert tour.verge_at(1000) == ("grass", "grass")
    assert tour.verge_at(515) == ("open", "open")  # the crossing: no boundary
    assert world.road_edges(100) == (1.6, -1.6)  # the narrow lane, 3.2 m
    assert world.road_edges(750) == (3.0, -3.0)
    assert world.road_edges(1570) == (None, None)  # the road opening


@pytest.mark.parametrize("s, kind", [(750, "kerb"), (420, "rock_wall/ravine"), (1000, "grass")])
def test_a_cross_section_of_the_roof_sweep_shows_the_verge(world, tour, shuttle, s, kind):
    pts, _, _ = sweep_in_vehicle_frame(world, tour, shuttle, "roof", s)
    band = pts[(np.abs(pts[:, 0] - 12.0) < 0.5) & (np.abs(pts[:, 1]) < 6.0)]
    road = band[np.abs(band[:, 1]) < 2.5]
    assert len(road) > 20 and np.ptp(road[:, 2]) < 0.2  # the crowned road, flat-ish
    level = np.median(road[:, 2])
    left = band[band[:, 1] > 3.3] - [0.0, 0.0, level]
    right = band[band[:, 1] < -3.3] - [0.0, 0.0, level]
    if kind == "kerb":
        assert np.median(left[:, 2]) > 0.02 and np.median(right[:, 2]) > 0.02  # up on the pavement
    elif kind == "rock_wall/ravine":
        assert left[:, 2].max() > 1.0  # the wall
        assert len(right) == 0 or right[:, 2].max() < -0.2  # the drop
    else:
        assert 0.0 < np.median(left[:, 2]) < 0.3  # a gentle rise, no step


def test_sweep_size_rings_and_intensity(world, tour, shuttle):
    _, sweep, sensor = sweep_in_vehicle_frame(world, tour, shuttle, "roof", 1000, params=LidarSimParams())
    assert sensor.rays_per_sweep == 64 * round(360 / 0.17)
    assert 0.4 * sensor.rays_per_sweep < sweep.size < sensor.rays_per_sweep
    assert sweep.ring.max() == 63 and sweep.ring.min() == 0
    assert 0.0 <= sweep.intensity.min() and sweep.intensity.max() <= 1.0
    r = np.sqrt(sweep.x**2 + sweep.y**2 + sweep.z**2)
    assert r.min() >= 0.9 - 0.1 and r.max() <= 120.0 + 0.1


def test_self_hits_occur_and_a_covered_sensor_sees_nothing(world, tour, shuttle):
    pts, _, sensor = sweep_in_vehicle_frame(world, tour, shuttle, "front_left", 1000)
    overhang = (shuttle.length_m - shuttle.wheelbase_m) / 2
    on_body = (
        (pts[:, 0] > -overhang - 0.05)
        & (pts[:, 0] < shuttle.length_m - overhang + 0.05)
        & (np.abs(pts[:, 1]) < shuttle.width_m / 2 + 0.05)
        & (pts[:, 2] > 0.2)
    )
    assert on_body.sum() > 100  # the corner sensor sees the shuttle's own front
    sensor.blocked = True
    x, y, _, yaw = tour.point_at(1000)
    assert sensor.sweep(world.scene, *vehicle_pose(x, y, 0.0, yaw, 0.0), None, world.material_of).size == 0


def test_ghosts_appear_in_front_of_the_sensor(world, tour, shuttle):
    params = LidarSimParams(azimuth_decimation=8, ghosts_per_sweep=50.0)
    sensor = SimulatedLidar("roof", shuttle.lidars["roof"], shuttle, params, np.random.default_rng(3))
    xg, yg, zg, intensity, ring = sensor._ghosts()
    r = np.sqrt(xg**2 + yg**2 + zg**2)
    assert 20 < len(r) < 100 and r.min() >= 0.9 and r.max() <= 3.0 and np.all(xg > 0)


def test_a_tilted_mount_points_down(shuttle):
    rotation, _ = mount_pose(LidarMount(model="vlp16", xyz_m=(0, 0, 1), rpy_deg=(0, 15, 45)))
    forward = rotation @ [1.0, 0.0, 0.0]
    assert forward[2] == pytest.approx(-math.sin(math.radians(15)))  # nose down
    assert math.degrees(math.atan2(forward[1], forward[0])) == pytest.approx(45.0)


def test_obstacles_along_the_tour_stand_beside_the_path(tour, world):
    field = ObstacleField(load_scenario("obstacles_along_tour"), tour, world.centre_height)
    static = [o for o in field.obstacles if not o.moving]
    assert len(static) > 20 and {o.spec.kind for o in static} == {"box", "crate", "pedestrian", "cart", "vehicle"}
    for ob in static:
        s, xte, _ = tour.project(*ob.xy[0])
        assert abs(xte) - ob.spec.size()[1] / 2 >= 1.5 - 1e-6  # clear of the shuttle's swept path
        assert tour.width[tour.index_at(s)] >= 5.0  # none in the narrow lane
        assert not tour.in_zone(s, "intersection") and not tour.in_zone(s, "road_opening")


def test_a_pedestrian_starts_crossing_when_the_vehicle_comes_near(tour, world):
    field = ObstacleField(load_scenario("obstacles_along_tour"), tour, world.centre_height)
    walker = next(o for o in field.obstacles if o.spec.name == "walker_lakeside")
    before = walker.where(100.0)
    assert field.update(100.0, 700.0) == []  # the vehicle is still far
    assert "walker_lakeside" in field.update(101.0, 720.0)
    mid = walker.where(101.0 + 3.2)
    end = walker.where(101.0 + 60.0)
    _, xte_before, _ = tour.project(before[0], before[1])
    _, xte_mid, _ = tour.project(mid[0], mid[1])
    _, xte_end, _ = tour.project(end[0], end[1])
    assert xte_before == pytest.approx(4.5, abs=0.05)
    assert abs(xte_mid) < 0.1  # in the middle of the road after 3.2 s
    assert xte_end == pytest.approx(-4.5, abs=0.05)  # and stays on the far side


def test_the_crossing_pedestrian_stands_in_the_middle_as_long_as_the_scenario_says(tour, world):
    field = ObstacleField(load_scenario("pedestrian_crossing"), tour, world.centre_height)
    walker = field.obstacles[0]
    field.update(10.0, 760.0)  # starts walking (1.2 m/s, 5 m to the middle)
    offsets = {dt: tour.project(*walker.where(10.0 + dt)[:2])[1] for dt in (0.0, 2.0, 5.0, 9.0, 12.5, 30.0)}
    assert offsets[0.0] == pytest.approx(5.0, abs=0.05) and offsets[2.0] == pytest.approx(2.6, abs=0.05)
    assert abs(offsets[5.0]) < 0.05 and abs(offsets[9.0]) < 0.05  # standing in the way for wait_s
    assert offsets[12.5] == pytest.approx(-(12.5 - 4.17 - 8.0) * 1.2, abs=0.05)
    assert offsets[30.0] == pytest.approx(-5.0, abs=0.05)


def test_an_obstacle_is_seen_by_the_roof_lidar(tour, world, shuttle):
    scenario = Scenario(
        name="one",
        obstacles=[ScenarioObstacle(name="crate", kind="crate", path=[ScenarioPlace(s=1012.0, offset_m=0.0)])],
    )
    field = ObstacleField(scenario, tour, world.centre_height)
    import open3d as o3d

    mesh = field.mesh_near(0.0, *tour.point_at(1000.0)[:2], 50.0)
    scene = o3d.t.geometry.RaycastingScene()
    scene.add_triangles(o3d.core.Tensor(mesh.vertices), o3d.core.Tensor(mesh.triangles))
    pts, _, _ = sweep_in_vehicle_frame(world, tour, shuttle, "roof", 1000.0, obstacles=scene)
    hits = pts[(np.abs(pts[:, 0] - 12.0) < 0.5) & (np.abs(pts[:, 1]) < 0.35)]
    assert len(hits) > 10 and hits[:, 2].max() > 0.4


def test_scenarios_load_and_a_bad_one_says_what_is_wrong(tmp_path):
    assert load_scenario("lidar_blocked").faults[0].sensor == "roof"
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: bad\nobstacles:\n  - {name: a, kind: tank, path: [{s: 1}]}\n")
    with pytest.raises(ConfigError, match="kind"):
        load_scenario(str(bad))
    with pytest.raises(ConfigError, match="unknown scenario 'nope'"):
        load_scenario("nope")


def test_the_simulator_reports_a_collision_once_per_contact(tmp_path):
    """A crate on the path: the `collision` event (a fault: an incident snapshot's trigger) when the body
    first touches it, none while it stays in contact, one more after it has left and come back."""
    from ares.app import run_config as stack_config
    from ares.core.clock import ManualClock
    from ares.core.membus import MemoryNetwork
    from ares.core.messages import VehicleTruth
    from ares.core.route import load_route
    from simulator.lidar_node import LidarSimulator

    scenario = tmp_path / "crate.yaml"
    scenario.write_text(
        "name: crate_on_the_path\ndescription: a crate in the lane\n"
        "obstacles:\n  - {name: crate1, kind: crate, path: [{s: 100.0}]}\n"
    )
    cfg = stack_config.build(
        overrides={
            "scenario": str(scenario),
            "lidar_sim": {"azimuth_decimation": 16},
            "bus": {"router": "tcp/127.0.0.1:1"},
        }
    )
    clock, network = ManualClock(), MemoryNetwork()
    node = LidarSimulator(cfg, clock=clock, bus=network.bus("lidar_sim", clock))
    node.setup()
    route = load_route(node.core)
    bus = network.bus("test", clock)
    events = bus.subscribe("events", queue=100)
    bumper = node.vehicle.front_bumper_m

    def at(t: float, s_bumper: float) -> None:  # the truth with the front bumper at s_bumper
        clock.set(t)
        x, y, z, yaw = route.point_at(s_bumper - bumper)
        bus.publish(
            "sim/truth",
            VehicleTruth(
                t=t,
                x=x,
                y=y,
                z=z,
                yaw=yaw,
                v=1.2,
                steering_wheel_deg=0.0,
                wheel_angle_rad=0.0,
                s=s_bumper - bumper,
                odometer_m=0.0,
            ),
        )
        node.step_once(t)

    def collisions() -> list:
        return [e for _, e in events.drain() if e.kind == "collision"]

    at(0.1, 95.0)  # short of the crate
    assert collisions() == []
    at(0.2, 100.0)  # the bumper in the crate
    hit = collisions()
    assert [e.data["obstacle"] for e in hit] == ["crate1"] and hit[0].level == "fault", hit
    at(0.3, 100.1)  # still touching: no second event
    assert collisions() == []
    at(0.4, 90.0)  # backed away, then in again: a new contact
    at(0.5, 100.0)
    assert [e.data["obstacle"] for e in collisions()] == ["crate1"]
