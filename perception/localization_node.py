"""The localization process: GNSS, IMU gyro and wheel odometry fused by a UKF (ARES paper §3.1).

The fusion itself is `perception.localization.Localizer` (its docstring gives the pipeline); this
node drains its three queues into it every loop and publishes the pose carried forward to the
loop's time.
"""

from __future__ import annotations

from ares.core.node import Input, Node, Output
from perception.localization import LocalizationParams, Localizer


class LocalizationNode(Node):
    """GNSS, gyro and wheel odometry fused by a UKF into the pose of the rear-axle centre."""

    name = "localization"
    Params = LocalizationParams
    fixes = Input("gnss/fix", queue="queues", doc="validated GNSS fixes")
    imu = Input("sensors/imu", queue="queues", doc="gyro yaw rate and pitch; the magnetometer only at start")
    can = Input("sensors/can", queue="queues", doc="rear-axle speed and steering-wheel angle")
    poses = Output("localization/pose", rate="rate_hz", doc="every loop from the first fix on")

    def setup(self) -> None:
        self.localizer = Localizer(self.params, self.vehicle)
        self._announced = False

    def step(self, now: float) -> None:
        loc = self.localizer
        for kind, sub in (("gnss", self.fixes), ("imu", self.imu), ("can", self.can)):
            for _, msg in sub.drain():
                loc.push(kind, msg)
        loc.process_until(now - loc.hold_back_s)
        pose = loc.pose(now)
        if pose is None:
            return
        if not self._announced:
            self._announced = True
            self.event(
                "localization",
                f"initialised at the first GNSS fix ({'RTK' if pose.rtk else 'no RTK'})",
                x=pose.x,
                y=pose.y,
            )
        self.poses.put(pose)
