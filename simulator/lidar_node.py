"""The simulated LiDARs as a process: the 3-D world, the scenario's obstacles and three sensors.

Every 100 ms it takes the vehicle's true pose (sim/truth), moves the scenario's obstacles,
applies the scenario's faults (a covered sensor) and casts each sensor's rays (simulator/lidar.py)
into the world (simulator/world.py). It runs beside the physics process so that the two share the
machine's cores; at --speed max it is one more participant of the lockstep. What the obstacles
really are goes out on sim/world, for the evaluation only; when the body's footprint first
overlaps one, a `collision` event (a fault: an incident snapshot's trigger) says which and how
fast.
"""

from __future__ import annotations

import numpy as np

from ares.core.geometry import rectangle_corners
from ares.core.messages import Ack, EventLevel, LidarFault, ObstacleBox, PointCloud, VehicleTruth, WorldTruth
from ares.core.node import Input, Node, Output, service
from ares.core.route import load_route
from simulator.lidar import LidarSimParams, SimulatedLidar, vehicle_pose
from simulator.obstacles import ObstacleField, touching
from simulator.params import SimParams
from simulator.road import roughness_for
from simulator.scenario import Scenario, load_scenario
from simulator.world import World, open3d

OBSTACLE_REACH_M = 130.0  # beyond the longest LiDAR range


class LidarSimulator(Node):
    """Three simulated LiDARs in the world built from the route, with the scenario's obstacles."""

    name = "lidar_sim"
    Params = LidarSimParams
    sections = {"sim": SimParams}
    truth = Input("sim/truth", max_age=0.25, doc="the vehicle's true pose")
    roof = Output("lidar/roof/points", rate="rate_hz")
    front_left = Output("lidar/front_left/points", rate="rate_hz")
    front_right = Output("lidar/front_right/points", rate="rate_hz")
    world_truth = Output("sim/world", rate="rate_hz", doc="the obstacles as they are, for evaluation only")

    def setup(self) -> None:
        sim: SimParams = self.shared["sim"]
        self.route = load_route(self.core)
        self.world = World(
            self.route,
            roughness_for(self.route, sim, self.vehicle.wheelbase_m),
            seed=self.params.seed,
            roadside_objects=self.params.roadside_objects,
        )
        self.scenario: Scenario | None = load_scenario(self.core.scenario) if self.core.scenario else None
        self.obstacles = ObstacleField(self.scenario, self.route, self.world.centre_height)
        self.sensors = self.make_sensors()
        self.outputs_by_sensor = {"roof": self.roof, "front_left": self.front_left, "front_right": self.front_right}
        self.faults_done: set[int] = set()
        self.in_contact: set[str] = set()  # the obstacles the body overlaps now
        if not self.sensors:
            self.log.warning("vehicle profile %s has no lidars: nothing to simulate", self.vehicle.name)

    def make_sensors(self) -> dict[str, SimulatedLidar]:
        return {
            name: SimulatedLidar(name, mount, self.vehicle, self.params, np.random.default_rng([self.params.seed, i]))
            for i, (name, mount) in enumerate(self.vehicle.lidars.items())
        }

    @service("sim/lidar_fault")
    def _fault(self, request: LidarFault) -> Ack:
        sensor = self.sensors.get(request.sensor)
        if sensor is None:
            return Ack(t=self.clock.now(), ok=False, detail=f"this vehicle has no {request.sensor} LiDAR")
        self._set_blocked(request.sensor, request.blocked, "on command")
        return Ack(
            t=self.clock.now(), ok=True, detail=f"{request.sensor} {'covered' if request.blocked else 'uncovered'}"
        )

    def _set_blocked(self, name: str, blocked: bool, why: str) -> None:
        sensor = self.sensors[name]
        if sensor.blocked == blocked:
            return
        sensor.blocked = blocked
        self.event(
            "lidar_fault",
            f"simulated {name} LiDAR {'covered' if blocked else 'uncovered'} ({why})",
            EventLevel.WARNING if blocked else EventLevel.INFO,
            sensor=name,
            blocked=blocked,
        )

    def _faults(self, now: float) -> None:
        if self.scenario is None:
            return
        for i, fault in enumerate(self.scenario.faults):
            if fault.kind != "block_lidar" or fault.sensor not in self.sensors:
                continue
            ends = None if fault.duration_s is None else fault.at_t_s + fault.duration_s
            active = fault.active(now)
            if active and i not in self.faults_done:
                self.faults_done.add(i)
                self._set_blocked(fault.sensor, True, f"scenario {self.scenario.name}")
            elif not active and i in self.faults_done and ends is not None and now >= ends:
                self.faults_done.discard(i)
                self._set_blocked(fault.sensor, False, f"scenario {self.scenario.name}")

    def step(self, now: float) -> None:
        self._faults(now)
        truth: VehicleTruth | None = self.truth.fresh(now)
        if truth is None:
            return
        truth = self.sweep_pose(now, truth)
        stamp = truth.t  # the sweep is taken from this pose: it carries the pose's time
        progress = truth.lap * self.route.length + truth.s if self.route.closed else truth.s
        for name in self.obstacles.update(stamp, progress):
            self.event("obstacle_moving", f"scenario obstacle {name} starts moving", obstacle=name)
        rotation, position = vehicle_pose(truth.x, truth.y, truth.z, truth.yaw, truth.pitch)
        obstacle_scene = None
        mesh = self.obstacles.mesh_near(stamp, truth.x, truth.y, OBSTACLE_REACH_M)
        if mesh is not None:
            obstacle_scene = open3d().t.geometry.RaycastingScene()
            obstacle_scene.add_triangles(open3d().core.Tensor(mesh.vertices), open3d().core.Tensor(mesh.triangles))
        self.send_sweeps(stamp, rotation, position, obstacle_scene)
        boxes = self.obstacles.boxes(stamp)
        self.world_truth.put(
            WorldTruth(t=stamp, obstacles=boxes, blocked_lidars=[n for n, s in self.sensors.items() if s.blocked])
        )
        self._collisions(truth, boxes)

    def _collisions(self, truth: VehicleTruth, boxes: list[ObstacleBox]) -> None:
        v = self.vehicle
        body = rectangle_corners(
            truth.x, truth.y, truth.yaw, v.front_bumper_m, v.length_m - v.front_bumper_m, v.width_m / 2
        )
        now_touching = touching(boxes, body)
        kinds = {box.name: box.kind for box in boxes}
        for name in sorted(now_touching - self.in_contact):
            self.event(
                "collision",
                f"the shuttle touches {name} ({kinds[name]}) at {truth.v:.2f} m/s",
                EventLevel.FAULT,
                obstacle=name,
                obstacle_kind=kinds[name],
                v_mps=round(truth.v, 3),
            )
        self.in_contact = now_touching

    def sweep_pose(self, now: float, truth: VehicleTruth) -> VehicleTruth:
        """The pose a sweep is cast from: the latest true pose as it is."""
        return truth

    def send_sweeps(self, stamp: float, rotation: np.ndarray, position: np.ndarray, obstacle_scene) -> None:
        """Each sensor's sweep from the vehicle's pose, as a cloud on the bus."""
        for name, sensor in self.sensors.items():
            sweep = sensor.sweep(self.world.scene, rotation, position, obstacle_scene, self.world.material_of)
            self.outputs_by_sensor[name].put(
                PointCloud(
                    t=stamp,
                    sensor=name,
                    frame=f"lidar/{name}",
                    x=sweep.x,
                    y=sweep.y,
                    z=sweep.z,
                    intensity=sweep.intensity,
                    ring=sweep.ring,
                )
            )
