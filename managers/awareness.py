"""Self-awareness checks (ARES §3.7), without a bus: each sensor's and each process's health and
the level they add up to.

| what                  | healthy                                              | else      |
|-----------------------|------------------------------------------------------|-----------|
| each LiDAR            | >= lidar_min_hz and >= lidar_min_road_points          | level 1   |
| LiDAR status itself   | arriving                                             | level 2   |
| IMU                   | >= imu_min_hz, and its readings not all identical    | level 2   |
| GNSS                  | >= gnss_min_hz, variance <= gnss_max_var_m2, RTK     | level 2   |
|                       | corrections: any of them wrong for longer than       | after     |
|                       | gnss_max_outage_s (5 min) is an outage               | 5 min     |
| whitelisted processes | running (the supervisor judges hangs by heartbeat)   | level 2   |
| the black box         | losing no record (blackbox/status: dropped, lost)     | level 2   |

A blocked LiDAR is level 1 because the shuttle is then blind on that side, whatever its
localization; the others are level 2: the shuttle stops under control and goes on by itself once
they clear. The level is the most severe of the causes (1 before 2).

The corrections' own state (gnss/corrections: the NTRIP client's, or the simulated 4G link's) is
`sensors["corrections"]`, and names the cause of a loss of RTK ("no RTK corrections (link down (no
4G here), the newest 23 s old)"), so a 4G outage is seen for what it is, not only as a covariance.

A GNSS that is slow, imprecise or without corrections for less than five minutes is no cause:
driving through such stretches on the road the LiDARs see is what the control manager's road
reactive control is for (ARES §3.6; the `dead_reckoning_drift` scenario), and the paper's
awareness calls only an outage longer than 5 min level 2. Until then `sensors["gnss"]` says what
is wrong and for how long.

The black box (blackbox/status, each second) is `sensors["blackbox"]`: a store that is down while
the spool or the writer's memory holds every record is said there and is no cause (nothing is
lost, and the must of ARES §3.8, a record every second, still holds). A record or event the black
box could not keep (its store, spool and memory all full) is level 2 for `blackbox_loss_hold_s`
after the last loss: the shuttle stops under control rather than drive unrecorded, and goes on by
itself once the black box keeps everything again.
"""

from __future__ import annotations

import collections
from dataclasses import dataclass, field

from ares.core.config import Params, param
from ares.core.messages import (
    BlackboxStatus,
    CorrectionsStatus,
    GnssFix,
    Imu,
    LidarStatus,
    ProcessState,
    SupervisorState,
)

NOMINAL, CRITICAL, LOW = 0, 1, 2


class AwarenessParams(Params):
    rate_hz: float = param(
        10.0,
        "checks per second: the paper's 0.5 s at most; a covered LiDAR must stop the "
        "shuttle within 0.5 s, and its status comes at 10 Hz",
        unit="Hz",
        gt=0,
    )
    window_s: float = param(2.0, "rates are counted over this window of message stamps", unit="s", gt=0)
    lidar_min_hz: float = param(8.0, "each LiDAR's sweeps per second at least (they turn at 10 Hz)", unit="Hz", gt=0)
    lidar_min_road_points: int = param(200, "road points a LiDAR's sweep must hold (a covered sensor sees none)", ge=0)
    lidar_status_timeout_s: float = param(
        1.0, "no LiDAR status this long: the LiDARs' health is unknown", unit="s", gt=0
    )
    imu_min_hz: float = param(30.0, "IMU messages per second at least", unit="Hz", gt=0)
    imu_frozen_s: float = param(0.5, "an IMU repeating exactly the same reading this long is frozen", unit="s", gt=0)
    gnss_min_hz: float = param(4.0, "GNSS fixes per second at least", unit="Hz", gt=0)
    gnss_max_var_m2: float = param(
        1.0, "a fix's position variance (x + y) at most (without corrections ~0.5 m²)", unit="m^2", gt=0
    )
    gnss_max_outage_s: float = param(
        300.0,
        "the GNSS slow, imprecise or without RTK corrections longer than this: "
        "level 2 (ARES §3.7: an outage longer than 5 min)",
        unit="s",
        gt=0,
    )
    rtk_recent_s: float = param(2.0, "corrections count as in use while the last RTK fix is younger", unit="s", gt=0)
    supervisor_timeout_s: float = param(
        1.5, "no process table from the supervisor this long: processes unknown", unit="s", gt=0
    )
    blackbox_status_timeout_s: float = param(
        5.0, "no black-box status this long (it comes each second): its health is unknown", unit="s", gt=0
    )
    blackbox_loss_hold_s: float = param(
        10.0, "a record or event the black box lost keeps level 2 this long after the last loss", unit="s", gt=0
    )


@dataclass
class Assessment:
    level: int = NOMINAL
    causes: list[str] = field(default_factory=list)
    sensors: dict[str, str] = field(default_factory=dict)
    processes: dict[str, str] = field(default_factory=dict)

    def add(self, level: int, cause: str) -> None:
        self.causes.append(cause)
        if self.level == NOMINAL or level < self.level:  # 1 is more severe than 2
            self.level = level


class RateWatch:
    """Message stamps over a window: a rate that does not depend on when it is asked."""

    def __init__(self, window_s: float):
        self.window_s = window_s
        self.stamps: collections.deque[float] = collections.deque()

    def add(self, t: float) -> None:
        self.stamps.append(t)

    def rate_hz(self, now: float) -> float:
        while self.stamps and self.stamps[0] <= now - self.window_s:
            self.stamps.popleft()
        return len(self.stamps) / self.window_s


class AwarenessChecks:
    """Fed every sensor message as it arrives; `assess(now)` gives the level and its causes."""

    def __init__(self, params: AwarenessParams, lidars: list[str], started_at: float = 0.0):
        self.p = params
        self.lidars = lidars
        self.imu_rate, self.gnss_rate = RateWatch(params.window_s), RateWatch(params.window_s)
        self._imu_last: tuple | None = None
        self._imu_same_since: float | None = None
        self._gnss_var: float | None = None
        self._rtk_last_seen = started_at
        self._gnss_good_at = started_at  # the last check that found the GNSS well
        self._started_at = started_at
        self._lidar_since: float | None = None  # the first LiDAR status: rates are judged a window later
        self._corrections: CorrectionsStatus | None = None  # the corrections' latest state, if any comes
        self._blackbox: BlackboxStatus | None = None
        self._blackbox_losses: int | None = None  # dropped + lost of the latest status
        self._blackbox_lost_at: float | None = None  # when those last grew

    def on_imu(self, imu: Imu) -> None:
        self.imu_rate.add(imu.t)
        reading = (imu.gyro_x, imu.gyro_y, imu.gyro_z, imu.accel_x, imu.accel_y, imu.accel_z, imu.yaw)
        if reading != self._imu_last:
            self._imu_last, self._imu_same_since = reading, imu.t
        elif self._imu_same_since is None:
            self._imu_same_since = imu.t

    def on_corrections(self, status: CorrectionsStatus | None) -> None:
        self._corrections = status

    def on_blackbox(self, status: BlackboxStatus) -> None:
        losses = status.dropped + status.events_dropped + status.lost
        # a count below the last is a restarted recorder, counting from 0: no loss in that
        if self._blackbox_losses is not None and losses > self._blackbox_losses:
            self._blackbox_lost_at = status.t
        self._blackbox_losses, self._blackbox = losses, status

    def on_gnss(self, fix: GnssFix) -> None:
        self.gnss_rate.add(fix.t)
        self._gnss_var = fix.var_x + fix.var_y
        if fix.rtk:
            self._rtk_last_seen = fix.t

    def assess(
        self,
        now: float,
        lidar: LidarStatus | None,
        supervisor: SupervisorState | None,
        whitelist: set[str] | None = None,
    ) -> Assessment:
        p, out = self.p, Assessment()
        warm = now - self._started_at >= p.window_s  # rates need a full window
        self._lidars(now, lidar, out)
        imu_hz = self.imu_rate.rate_hz(now)
        frozen = self._imu_same_since is not None and now - self._imu_same_since >= p.imu_frozen_s
        if warm and imu_hz < p.imu_min_hz:
            out.sensors["imu"] = f"{imu_hz:.0f} Hz < {p.imu_min_hz:.0f}"
        elif frozen:
            out.sensors["imu"] = f"frozen: the same reading for {now - self._imu_same_since:.1f} s"
        else:
            out.sensors["imu"] = "ok"
        gnss_hz = self.gnss_rate.rate_hz(now)
        problems = []
        if warm and gnss_hz < p.gnss_min_hz:
            problems.append(f"{gnss_hz:.1f} Hz < {p.gnss_min_hz:.0f}")
        if self._gnss_var is not None and self._gnss_var > p.gnss_max_var_m2:
            problems.append(f"variance {self._gnss_var:.2f} m² > {p.gnss_max_var_m2:.2f}")
        corrections = self._corrections
        outage = None
        if corrections is not None:
            stale = corrections.stale(now)
            outage = "state unknown (no word from its source for a while)" if stale else corrections.outage()
            out.sensors["corrections"] = "ok" if outage is None else outage
        if warm and now - self._rtk_last_seen > p.rtk_recent_s:
            problems.append("no RTK corrections" + (f" ({outage})" if outage else ""))
        if not problems:
            self._gnss_good_at = now
            out.sensors["gnss"] = "ok"
        else:
            out.sensors["gnss"] = f"{', '.join(problems)} for {now - self._gnss_good_at:.0f} s"
            if now - self._gnss_good_at > p.gnss_max_outage_s:
                out.add(LOW, f"gnss: an outage longer than {p.gnss_max_outage_s:.0f} s: {out.sensors['gnss']}")
        if out.sensors["imu"] != "ok":
            out.add(LOW, f"imu: {out.sensors['imu']}")
        self._processes(now, supervisor, whitelist, out)
        self._blackbox_health(now, out)
        return out

    def _blackbox_health(self, now: float, out: Assessment) -> None:
        status = self._blackbox
        if status is None:
            return  # no black box on this run (yet): nothing to say
        if now - status.t > self.p.blackbox_status_timeout_s:
            out.sensors["blackbox"] = f"no status for {now - status.t:.0f} s"
        elif status.store_up:
            out.sensors["blackbox"] = "ok"
        else:
            waiting = f"{status.spooled} spooled, {status.in_memory} in memory"
            out.sensors["blackbox"] = f"store down ({waiting}): {status.last_error or 'no reason given'}"
        if self._blackbox_lost_at is not None and now - self._blackbox_lost_at <= self.p.blackbox_loss_hold_s:
            lost = status.dropped + status.events_dropped + status.lost
            out.add(LOW, f"blackbox: losing records ({lost} lost since it started)")

    def _lidars(self, now: float, status: LidarStatus | None, out: Assessment) -> None:
        p = self.p
        if not self.lidars:
            return
        if status is None or now - status.t > p.lidar_status_timeout_s:
            for name in self.lidars:
                out.sensors[f"lidar {name}"] = "unknown: no LiDAR status"
            out.add(LOW, "lidars: no status from perception")
            self._lidar_since = None  # back after a gap (a restart): the rates count a window later
            return
        if self._lidar_since is None:
            self._lidar_since = status.t
        warm = status.t - self._lidar_since >= p.window_s  # a sensor's rate counts once it has run a window
        for name in self.lidars:
            health = status.sensors.get(name)
            level = CRITICAL
            if health is None:
                problem = "missing from the status"
            elif health.blind:
                problem = "blind: no points (covered or failed)"
            elif (
                warm if health.counting_s is None else health.counting_s >= p.window_s
            ) and health.rate_hz < p.lidar_min_hz:
                problem = f"{health.rate_hz:.1f} Hz < {p.lidar_min_hz:.0f}"
            elif health.road_points < p.lidar_min_road_points:
                # it returns points, but not of the road: something close in front hides it (a person
                # by the bumper) - a stop until it clears, not a failed sensor that needs a person
                problem = f"{health.road_points} road points < {p.lidar_min_road_points} (the road hidden)"
                level = LOW
            else:
                problem = ""
            out.sensors[f"lidar {name}"] = problem or "ok"
            if problem:
                out.add(level, f"lidar {name}: {problem}")

    def _processes(
        self, now: float, supervisor: SupervisorState | None, whitelist: set[str] | None, out: Assessment
    ) -> None:
        if supervisor is None or now - supervisor.t > self.p.supervisor_timeout_s:
            out.add(LOW, "processes: no state from the supervisor")
            return
        for proc in supervisor.processes:
            if whitelist is not None and proc.name not in whitelist:
                continue
            if whitelist is None and not proc.safety_relevant:
                continue
            problem = (
                ""
                if proc.state == ProcessState.RUNNING
                else proc.state.value + (f" ({proc.last_failure})" if proc.last_failure else "")
            )
            out.processes[proc.name] = problem or "ok"
            if problem:
                out.add(LOW, f"process {proc.name}: {problem}")
