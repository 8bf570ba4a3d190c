"""Every topic and every service of the stack, in one declarative table.

A topic is the part of a key after `ares/<vehicle_id>/`. Each has exactly one schema, and its
encoding follows from it (JSON for `Msg`, header + raw arrays for `BulkMsg`). A topic has one
publishing process unless it says `shared=True`; the command that reaches the drive-by-wire
bridge is such a single-publisher topic. `reliable` topics are never dropped under congestion
(each message matters: events, driver actions, the clock); the others are latest-value topics.
Who publishes and who reads each topic at what rate is in the node contracts (`ares describe`,
docs/nodes.md); rates are the publishers' to declare.

Services are Zenoh queryables under `ares/<vehicle_id>/srv/<name>`, each with one request and
one reply schema.
"""

from __future__ import annotations

import fnmatch
from dataclasses import dataclass

from ares.core import messages as m
from ares.core.schema import Msg, is_bulk


@dataclass(frozen=True)
class Topic:
    name: str  # may end in /* for a family of keys (heartbeat/<process>)
    schema: type[Msg]
    doc: str
    reliable: bool = False
    shared: bool = False  # several processes publish it
    score: str | None = None  # a manager's score (a `score` field): the black box records it under this name
    optional: bool = False  # an optional device's: its readers do without it when nobody publishes it

    @property
    def encoding(self) -> str:
        return "bulk" if is_bulk(self.schema) else "json"

    @property
    def is_pattern(self) -> bool:
        return "*" in self.name


@dataclass(frozen=True)
class Service:
    name: str
    request: type[Msg]
    reply: type[Msg]
    doc: str


TOPIC_TABLE: list[Topic] = [
    # process health and the clock
    Topic("heartbeat/*", m.Heartbeat, "each process's heartbeat, sent from its loop", shared=True),
    Topic("supervisor/state", m.SupervisorState, "every process: state, restarts, silence"),
    Topic("events", m.Event, "things that happened, for people and the black box", reliable=True, shared=True),
    Topic(
        "sim/clock", m.ClockTick, "--speed max: the stack time, for the processes outside the lockstep", reliable=True
    ),
    Topic(
        "sim/clock/*",
        m.ClockTick,
        "--speed max: the stack time, to one participant of the lockstep when its step is due",
        reliable=True,
    ),
    Topic("clock/done", m.ClockDone, "a process finished its step (--speed max)", reliable=True, shared=True),
    # the simulated vehicle
    Topic("sim/truth", m.VehicleTruth, "ground truth, for evaluation only"),
    Topic("sim/world", m.WorldTruth, "the simulated world's obstacles, for evaluation only"),
    Topic("drivers/status", m.DriverStatus, "each driver's counts: in, out, lost, malformed, latency", shared=True),
    Topic("sensors/gnss", m.GnssSentences, "raw NMEA sentences from the receiver"),
    Topic("sensors/imu", m.Imu, "IMU: attitude, rates, specific force, magnetometer yaw"),
    Topic("sensors/can", m.CanFrame, "CAN: wheel speed, steering-wheel angle, pedals"),
    Topic("vehicle/panel", m.PanelEvent, "a driver action: Auto/Manual button, pedals, steering wheel", reliable=True),
    # localization, odometry, path, speed
    Topic("gnss/fix", m.GnssFix, "a validated GNSS fix in UTM and the local frame"),
    Topic("gnss/rtcm", m.RtcmData, "RTK corrections (RTCM 3 frames) for the receiver's port", optional=True),
    Topic("gnss/corrections", m.CorrectionsStatus, "the RTK corrections' link and age, once a second", optional=True),
    Topic("localization/pose", m.Pose, "the fused pose (UKF) with its covariance"),
    Topic("odometry/score", m.OdometryScore, "how far the pose deserves trust (ARES eq. 6)", score="odometry"),
    Topic("path/match", m.PathMatch, "where the vehicle is on its route, and the path ahead"),
    Topic("speed/limits", m.SpeedLimits, "the speed limit where the vehicle is and the next section's (ARES §3.6.3)"),
    Topic("speed/sections", m.SpeedSections, "the route's single-speed sections (ARES Figure 17), repeated slowly"),
    # control and the drive-by-wire bridge
    Topic("control/candidate/mpc", m.ControlCandidate, "the MPC's (v, kappa) (ARES §3.6.1)"),
    Topic("control/candidate/rrc", m.ControlCandidate, "road reactive control's (v, kappa) (ARES §3.6.2)"),
    Topic("control/candidate/pure_pursuit", m.ControlCandidate, "pure pursuit's (v, kappa) (DBW paper)"),
    Topic(
        "control/candidate/stanley",
        m.ControlCandidate,
        "the Stanley law's (v, kappa) (ARES Fig. 15's comparison): only when chosen",
        optional=True,
    ),
    Topic("control/mpc/trajectory", m.PredictedTrajectory, "the MPC's predicted trajectory over its horizon"),
    Topic("control/setpoint", m.Setpoint, "(v, kappa): the control manager's choice, to the movement manager"),
    Topic(
        "movement/command",
        m.MovementCommand,
        "(v, kappa, emergency): the only command the drive-by-wire bridge "
        "accepts; the movement manager's, the only one that may ask for an "
        "emergency stop",
    ),
    Topic("movement/status", m.MovementStatus, "what limits the shuttle now and why; a latched emergency stop"),
    Topic(
        "obstacle/state",
        m.ObstacleState,
        "the obstacle search area, the nearest obstacle in it and the speed limit it sets (ARES §3.5.3)",
        score="obstacle",
    ),
    Topic(
        "mission/status",
        m.MissionStatus,
        "the mission's feedback: state, the POI driven to, distance, expected arrival, its speed limit (ARES §3.3)",
    ),
    Topic("body/command", m.BodyCommand, "doors, ramp and media: the mission manager's demand to the body"),
    Topic("body/state", m.BodyState, "doors and ramp end-position sensors, the entrance, passengers"),
    Topic("blackbox/record", m.BlackboxRecord, "each second of the black box as recorded, for the fleet's store"),
    Topic(
        "blackbox/status",
        m.BlackboxStatus,
        "the black box's own health each second: store up, records written, dropped, faults, what waits",
        reliable=True,  # its last word, after the final flush, is the run's count of what was kept
    ),
    Topic(
        "recording/snapshot_request",
        m.SnapshotRequest,
        "an incident snapshot asked for now (`ares snapshot`); the recorder's `snapshot` event answers",
        reliable=True,
    ),
    Topic("awareness/state", m.AwarenessState, "self-awareness level (0, 1 critical, 2 low) and its causes"),
    Topic("control/status", m.ControllerStatus, "the controller in charge, why, and the errors along the route"),
    Topic("dbw/actuators", m.ActuatorCommand, "efforts to the steering motor and traction/brake"),
    Topic("dbw/reference", m.DbwReference, "the inner loops' references"),
    Topic("dbw/measure", m.DbwMeasure, "the inner loops' measurements"),
    Topic("dbw/car_state", m.CarState, "drive mode, watchdog, commanded and measured motion"),
    # bulk data: header + raw arrays (the LiDARs and the occupancy grid come with perception)
    Topic("lidar/roof/points", m.PointCloud, "the roof's 64-layer LiDAR, one sweep"),
    Topic("lidar/front_left/points", m.PointCloud, "the front-left 16-layer LiDAR, one sweep"),
    Topic("lidar/front_right/points", m.PointCloud, "the front-right 16-layer LiDAR, one sweep"),
    Topic("lidar/roof/packets", m.LidarPackets, "the roof LiDAR's packets as received (for recordings)", optional=True),
    Topic("lidar/front_left/packets", m.LidarPackets, "the front-left LiDAR's packets as received", optional=True),
    Topic("lidar/front_right/packets", m.LidarPackets, "the front-right LiDAR's packets as received", optional=True),
    Topic("perception/grid", m.OccupancyGrid, "the local occupancy grid around the vehicle"),
    Topic("perception/road", m.RoadDetection, "road boundaries, centre line, the vehicle's offset and heading"),
    Topic("perception/lidar_status", m.LidarStatus, "per LiDAR: rate, points, road points; stage times"),
]

SERVICE_TABLE: list[Service] = [
    Service("set_automatic_mode", m.Empty, m.ModeReply, "Ready -> Automatic (the software half of the switch)"),
    Service("sim/driver", m.DriverCommand, m.Ack, "a driver action on the simulated vehicle"),
    Service("sim/lidar_fault", m.LidarFault, m.Ack, "cover or uncover a simulated LiDAR (fault injection)"),
    Service(
        "sim/sensor_fault", m.SensorFault, m.Ack, "a GNSS outage, RTK loss or frozen IMU from now on (fault injection)"
    ),
    Service("supervisor/status", m.Empty, m.SupervisorState, "every process's state"),
    Service(
        "movement/rearm",
        m.RearmRequest,
        m.RearmReply,
        "clear a latched emergency stop (refused while level 1 lasts); the REST API's operators only",
    ),
    Service(
        "mission/goal",
        m.MissionGoal,
        m.MissionReply,
        "a new goal (POIs in order, the route's POIs, or a drive); pre-empts the one that runs",
    ),
    Service("mission/pause", m.MissionRequest, m.MissionReply, "hold where it is (stopping first)"),
    Service("mission/resume", m.MissionRequest, m.MissionReply, "go on from a pause"),
    Service(
        "mission/cancel", m.MissionRequest, m.MissionReply, "end the goal (the doors closed and the ramp stowed first)"
    ),
    Service(
        "blackbox/records",
        m.RecordRange,
        m.RecordBatch,
        "the black-box seconds of a range the recorder holds (memory, then its store): the fleet's store fills a gap",
    ),
    Service(
        "blackbox/acknowledge",
        m.Acknowledgement,
        m.AcknowledgementReply,
        "the fleet's store holds every second of the vehicle up to a mark: the vehicle's purge may go that far",
    ),
    Service(
        "blackbox/snapshots",
        m.SnapshotListRequest,
        m.SnapshotList,
        "the incident snapshots the vehicle keeps, with their events: the fleet copies those it lacks",
    ),
    Service(
        "blackbox/snapshot_part",
        m.SnapshotPartRequest,
        m.SnapshotPart,
        "a piece of a snapshot's file: the fleet's copy goes on from where it stopped",
    ),
    Service(
        "mission/body",
        m.BodyRequest,
        m.MissionReply,
        "an operator opens or closes the doors, deploys or stows the ramp (standing, no POI's actions running)",
    ),
]

TOPICS: dict[str, Topic] = {t.name: t for t in TOPIC_TABLE}
SERVICES: dict[str, Service] = {s.name: s for s in SERVICE_TABLE}
_EVERY_SCHEMA: list[type[Msg]] = [  # annotated: mypy would join type[Msg] and a model class to `object`
    *(t.schema for t in TOPIC_TABLE),
    *(c for s in SERVICE_TABLE for c in (s.request, s.reply)),
    m.ServiceErrorReply,
]
SCHEMAS: dict[str, type[Msg]] = {cls.schema_name(): cls for cls in _EVERY_SCHEMA}


def topic(name: str) -> Topic:
    """The table's entry for a topic (a key of a `/*` family finds its family); KeyError if none."""
    found = find(name)
    if found is None:
        close = sorted(t for t in TOPICS if t.split("/")[0] == name.split("/")[0]) or sorted(TOPICS)
        raise KeyError(
            f"unknown topic {name!r}: not in the topic table (ares/core/topics.py); known: {', '.join(close)}"
        )
    return found


def find(name: str) -> Topic | None:
    entry = TOPICS.get(name)
    if entry is not None:
        return entry
    for candidate in TOPIC_TABLE:
        if (
            candidate.is_pattern
            and fnmatch.fnmatchcase(name, candidate.name)
            and name.count("/") == candidate.name.count("/")
        ):
            return candidate
    return None


def covers(pattern: str, key: str) -> bool:
    """Whether a family such as `sim/clock/*` has `key` as one of its keys."""
    return "*" in pattern and fnmatch.fnmatchcase(key, pattern) and key.count("/") == pattern.count("/")


def matching(pattern: str) -> list[Topic]:
    """The table's topics a key pattern such as `sensors/*` covers."""
    return [t for t in TOPIC_TABLE if fnmatch.fnmatchcase(t.name, pattern) and t.name.count("/") == pattern.count("/")]


def service(name: str) -> Service:
    entry = SERVICES.get(name)
    if entry is None:
        raise KeyError(
            f"unknown service {name!r}: not in the service table (ares/core/topics.py); "
            f"known: {', '.join(sorted(SERVICES))}"
        )
    return entry


def score_topics() -> dict[str, str]:
    """Record name -> topic of every manager's score."""
    return {t.score: t.name for t in TOPIC_TABLE if t.score}
