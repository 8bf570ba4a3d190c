"""ARES messages as Foxglove's well-known schemas, so that a recording (or the live bus) opens in
Foxglove with the shuttle, its clouds and its plan in 3-D.

Frames: `local` is the stack's local frame (metres east and north of the site's origin), `vehicle`
the rear-axle centre (x forward, y left), `lidar/<name>` each LiDAR as mounted on the vehicle
profile. Each fused pose gives the transforms local -> vehicle -> every LiDAR (all in one
`foxglove.FrameTransforms`, so a viewer that starts in the middle of a recording has them at once).

| ARES topic                 | Foxglove topic                 | schema                         |
|----------------------------|--------------------------------|--------------------------------|
| localization/pose          | foxglove/pose/location         | foxglove.LocationFix           |
| localization/pose          | foxglove/tf                    | foxglove.FrameTransforms       |
| gnss/fix                   | foxglove/gnss/location         | foxglove.LocationFix           |
| lidar/<name>/points        | foxglove/lidar/<name>/points   | foxglove.PointCloud (x,y,z,i)  |
| perception/grid            | foxglove/perception/grid       | foxglove.Grid                  |
| path/match                 | foxglove/path/ahead            | foxglove.SceneUpdate (a line)  |
| control/mpc/trajectory     | foxglove/control/mpc/trajectory| foxglove.SceneUpdate (a line)  |
| obstacle/state             | foxglove/obstacle/area         | foxglove.SceneUpdate (a loop)  |
| (the route, once)          | foxglove/route                 | foxglove.SceneUpdate (a line)  |

Timestamps are the messages' own stamps on the run's UTC epoch (`utc_epoch + t`).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import foxglove
import numpy as np
from foxglove import messages as fg  # foxglove.schemas is the deprecated name of the same classes

from ares.core import config
from ares.core import messages as m
from ares.core.geodesy import LocalFrame
from ares.core.route import Route
from ares.core.schema import Msg

log = logging.getLogger("ares.app.bus_record.views")

LOCAL_FRAME = "local"
VEHICLE_FRAME = "vehicle"


@dataclass(frozen=True)
class View:
    """One Foxglove message made from one ARES message."""

    topic: str
    schema: foxglove.Schema
    data: bytes


def _schema(cls: Any) -> foxglove.Schema:
    return cls.get_schema()


SCHEMAS: dict[str, foxglove.Schema] = {
    name: _schema(getattr(fg, name)) for name in ("LocationFix", "FrameTransforms", "PointCloud", "Grid", "SceneUpdate")
}

# x, y, z, intensity as float32, one point every 16 bytes (the ring stays in the raw channel)
_CLOUD_FIELDS = [
    fg.PackedElementField(name=name, offset=4 * i, type=fg.PackedElementFieldNumericType.Float32)
    for i, name in enumerate(("x", "y", "z", "intensity"))
]
_CLOUD_STRIDE = 16


def timestamp(utc_epoch: float, t: float) -> fg.Timestamp:
    whole = math.floor(utc_epoch)  # apart from the fraction: a float of 1.8e9 s holds no nanoseconds
    ns = whole * 1_000_000_000 + int(round((utc_epoch - whole + t) * 1e9))
    return fg.Timestamp(ns // 1_000_000_000, ns % 1_000_000_000)


def quaternion_rpy(roll: float, pitch: float, yaw: float) -> fg.Quaternion:
    """The rotation of roll about x, pitch about y, yaw about z, applied z, then y, then x (ZYX)."""
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return fg.Quaternion(
        x=sr * cp * cy - cr * sp * sy,
        y=cr * sp * cy + sr * cp * sy,
        z=cr * cp * sy - sr * sp * cy,
        w=cr * cp * cy + sr * sp * sy,
    )


def _line(entity: str, frame: str, stamp: fg.Timestamp, xs: Any, ys: Any, color: fg.Color, loop: bool = False) -> bytes:
    points = [fg.Point3(x=float(x), y=float(y), z=0.0) for x, y in zip(xs, ys)]
    line = fg.LinePrimitive(
        type=fg.LinePrimitiveLineType.LineLoop if loop else fg.LinePrimitiveLineType.LineStrip,
        thickness=0.15,
        points=points,
        color=color,
    )
    scene = fg.SceneUpdate(entities=[fg.SceneEntity(timestamp=stamp, frame_id=frame, id=entity, lines=[line])])
    return scene.encode()


class FoxgloveViews:
    """Makes the Foxglove messages of one vehicle's run: `views(topic, msg)` for each ARES message,
    `route_view()` once."""

    def __init__(self, cfg: dict[str, Any], utc_epoch: float):
        core = config.core(cfg)
        self.utc_epoch = utc_epoch
        self.frame = LocalFrame(core.origin_utm)
        # each LiDAR's frame, position and rotation on the vehicle (the profile's extrinsics)
        self._mounts = [
            (f"lidar/{name}", mount.xyz_m, tuple(math.radians(a) for a in mount.rpy_deg))
            for name, mount in core.vehicle_profile.lidars.items()
        ]
        self._makers: dict[type[Msg], Callable[[str, Any], list[View]]] = {
            m.Pose: self._pose,
            m.GnssFix: self._gnss_fix,
            m.PointCloud: self._cloud,
            m.OccupancyGrid: self._grid,
            m.PathMatch: self._path_ahead,
            m.PredictedTrajectory: self._trajectory,
            m.ObstacleState: self._obstacle_area,
        }

    @property
    def lidar_frames(self) -> list[str]:
        return [frame for frame, _, _ in self._mounts]

    def handles(self, schema: type[Msg]) -> bool:
        return schema in self._makers

    def cloud_preview(self, topic: str, cloud: m.PointCloud, stride: int) -> list[View]:
        return self._cloud(topic, cloud, stride)

    def views(self, topic: str, msg: Msg) -> list[View]:
        maker = self._makers.get(type(msg))
        if maker is None:
            return []
        try:
            return maker(topic, msg)
        except (ValueError, OverflowError) as exc:  # a pose beyond UTM, say: no view, never a crash
            log.debug("no Foxglove view of %s: %s", topic, exc)
            return []

    def route_view(self, route: Route) -> View:
        stamp = timestamp(self.utc_epoch, 0.0)
        data = _line("route", LOCAL_FRAME, stamp, route.x, route.y, fg.Color(r=0.6, g=0.6, b=0.6, a=1.0), route.closed)
        return View("foxglove/route", SCHEMAS["SceneUpdate"], data)

    # ---- one maker per message type -----------------------------------------------------------
    def _pose(self, topic: str, pose: m.Pose) -> list[View]:
        stamp = timestamp(self.utc_epoch, pose.t)
        views = [self._transforms(stamp, pose)]
        lat, lon = self.frame.to_latlon(pose.x, pose.y)
        fix = fg.LocationFix(
            timestamp=stamp,
            frame_id=VEHICLE_FRAME,
            latitude=lat,
            longitude=lon,
            altitude=self.frame.origin.altitude_m + pose.z,
            position_covariance=[pose.cov_xx, pose.cov_xy, 0.0, pose.cov_xy, pose.cov_yy, 0.0, 0.0, 0.0, 0.0],
            position_covariance_type=fg.LocationFixPositionCovarianceType.Known,
            heading=(math.pi / 2 - pose.yaw) % (2 * math.pi),
        )
        views.append(View("foxglove/pose/location", SCHEMAS["LocationFix"], fix.encode()))
        return views

    def _transforms(self, stamp: fg.Timestamp, pose: m.Pose) -> View:
        body = fg.FrameTransform(
            timestamp=stamp,
            parent_frame_id=LOCAL_FRAME,
            child_frame_id=VEHICLE_FRAME,
            translation=fg.Vector3(x=pose.x, y=pose.y, z=pose.z),
            rotation=quaternion_rpy(0.0, 0.0, pose.yaw),
        )
        mounts = [
            fg.FrameTransform(
                timestamp=stamp,
                parent_frame_id=VEHICLE_FRAME,
                child_frame_id=frame,
                translation=fg.Vector3(x=xyz[0], y=xyz[1], z=xyz[2]),
                rotation=quaternion_rpy(*rpy),
            )
            for frame, xyz, rpy in self._mounts
        ]
        return View("foxglove/tf", SCHEMAS["FrameTransforms"], fg.FrameTransforms(transforms=[body, *mounts]).encode())

    def _gnss_fix(self, topic: str, fix: m.GnssFix) -> list[View]:
        var_z = fix.var_z if fix.var_z is not None else 0.0
        location = fg.LocationFix(
            timestamp=timestamp(self.utc_epoch, fix.t),
            frame_id="gnss",
            latitude=fix.lat,
            longitude=fix.lon,
            altitude=self.frame.origin.altitude_m + (fix.z or 0.0),
            position_covariance=[fix.var_x, 0.0, 0.0, 0.0, fix.var_y, 0.0, 0.0, 0.0, var_z],
            position_covariance_type=fg.LocationFixPositionCovarianceType.DiagonalKnown,
        )
        return [View("foxglove/gnss/location", SCHEMAS["LocationFix"], location.encode())]

    def _cloud(self, topic: str, cloud: m.PointCloud, stride: int = 1) -> list[View]:
        """The sweep as Foxglove draws it; with `stride`, every n-th point (a recording's preview)."""
        x, y, z, intensity = (a[::stride] for a in (cloud.x, cloud.y, cloud.z, cloud.intensity))
        packed = np.empty((len(x), 4), dtype="<f4")
        packed[:, 0], packed[:, 1], packed[:, 2], packed[:, 3] = x, y, z, intensity
        message = fg.PointCloud(
            timestamp=timestamp(self.utc_epoch, cloud.t),
            frame_id=cloud.frame,
            point_stride=_CLOUD_STRIDE,
            fields=_CLOUD_FIELDS,
            data=packed.tobytes(),
        )
        return [View(f"foxglove/{topic}", SCHEMAS["PointCloud"], message.encode())]

    def _grid(self, topic: str, grid: m.OccupancyGrid) -> list[View]:
        rows, cols = grid.cells.shape
        message = fg.Grid(
            timestamp=timestamp(self.utc_epoch, grid.t),
            frame_id=grid.frame,
            pose=fg.Pose(
                position=fg.Vector3(x=grid.origin_x, y=grid.origin_y, z=0.0),
                orientation=fg.Quaternion(x=0.0, y=0.0, z=0.0, w=1.0),
            ),
            column_count=cols,
            cell_size=fg.Vector2(x=grid.resolution_m, y=grid.resolution_m),
            row_stride=cols,
            cell_stride=1,
            fields=[fg.PackedElementField(name="occupancy", offset=0, type=fg.PackedElementFieldNumericType.Uint8)],
            data=np.ascontiguousarray(grid.cells).tobytes(),
        )
        return [View(f"foxglove/{topic}", SCHEMAS["Grid"], message.encode())]

    def _path_ahead(self, topic: str, match: m.PathMatch) -> list[View]:
        stamp = timestamp(self.utc_epoch, match.t)
        data = _line(
            "path_ahead", LOCAL_FRAME, stamp, match.ahead_x, match.ahead_y, fg.Color(r=0.1, g=0.8, b=0.2, a=1.0)
        )
        return [View("foxglove/path/ahead", SCHEMAS["SceneUpdate"], data)]

    def _trajectory(self, topic: str, trajectory: m.PredictedTrajectory) -> list[View]:
        stamp = timestamp(self.utc_epoch, trajectory.t)
        color = fg.Color(r=0.9, g=0.3, b=0.9, a=1.0)
        data = _line(trajectory.controller, LOCAL_FRAME, stamp, trajectory.x, trajectory.y, color)
        return [View(f"foxglove/{topic}", SCHEMAS["SceneUpdate"], data)]

    def _obstacle_area(self, topic: str, state: m.ObstacleState) -> list[View]:
        stamp = timestamp(self.utc_epoch, state.t)
        color = {"clear": (0.2, 0.6, 1.0), "ready": (1.0, 0.9, 0.1), "slow": (1.0, 0.5, 0.0)}.get(
            state.band, (1.0, 0.1, 0.1)
        )
        data = _line(
            "obstacle_area",
            VEHICLE_FRAME,
            stamp,
            state.area_x,
            state.area_y,
            fg.Color(r=color[0], g=color[1], b=color[2], a=1.0),
            loop=True,
        )
        return [View("foxglove/obstacle/area", SCHEMAS["SceneUpdate"], data)]
