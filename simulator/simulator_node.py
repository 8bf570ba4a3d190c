"""The simulated shuttle: vehicle, road and sensors as one process on the bus.

Physics advances in fixed steps of 1/sim.physics_hz until it reaches the stack clock, so the
vehicle lives on the same timeline as every other process, at any `--speed`. With `--speed max`
the simulator drives that clock itself (ares.core.lockstep): it advances it only when every process
it feeds has finished its step. The hardware's own fail-safe is modelled too: when the bridge
goes quiet for sim.actuator_timeout_s the board brakes, whatever the bridge's last command was.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

from ares.core.geodesy import LocalFrame
from ares.core.lockstep import LockstepMaster, Pacer
from ares.core.messages import (
    Ack,
    ActuatorCommand,
    BodyCommand,
    BodyState,
    CanFrame,
    CorrectionsStatus,
    DriverCommand,
    EventLevel,
    GnssSentences,
    Imu,
    PanelEvent,
    PanelInput,
    ProcessState,
    SensorFault,
    VehicleTruth,
)
from ares.core.node import Input, Node, Output, service
from ares.core.route import load_route
from simulator.body import BodySim
from simulator.params import SimParams
from simulator.scenario import ScenarioDriverAction, ScenarioFault, load_scenario
from simulator.sensors import SensorSuite
from simulator.vehicle import VehiclePlant

ACTION_PANEL = {
    "THROTTLE": PanelInput.THROTTLE_PEDAL,
    "BRAKE": PanelInput.BRAKE_PEDAL,
    "STEER": PanelInput.STEERING_WHEEL,
}


@dataclass
class DriverInputs:
    """What the (simulated) human is doing, each with the stack time it ends."""

    throttle: float = 0.0
    throttle_until: float = -1.0
    brake: float = 0.0
    brake_until: float = -1.0
    steer_deg: float | None = None
    steer_until: float = -1.0

    def active(self, t: float) -> bool:
        return t < self.throttle_until or t < self.brake_until or t < self.steer_until

    def release(self) -> None:
        self.throttle_until = self.brake_until = self.steer_until = -1.0


class Simulator(Node):
    """The simulated shuttle: plant, road and sensors (and the clock, at --speed max)."""

    name = "sim"
    Params = SimParams
    rate = "physics_hz"
    actuators = Input("dbw/actuators", max_age="actuator_timeout_s", doc="efforts from the bridge's inner loops")
    gnss = Output("sensors/gnss", rate="gnss_hz", doc="NMEA GGA + GST")
    corrections = Output(
        "gnss/corrections", rate=1.0, doc="the receiver's RTK corrections over the simulated 4G link (no NTRIP)"
    )
    imu = Output("sensors/imu", rate="imu_hz")
    can = Output("sensors/can", rate="can_hz")
    truth = Output("sim/truth", rate="truth_hz", doc="ground truth, for evaluation only")
    panel = Output("vehicle/panel", doc="driver actions")
    body_command = Input("body/command", queue=64, doc="doors, ramp and media, from the mission manager")
    body_state = Output("body/state", rate="body.rate_hz", doc="the doors' and ramp's end switches, the entrance")
    clock_ticks = Output("sim/clock", doc="--speed max: the stack time, moved on when every participant is done")
    participant_ticks = Output("sim/clock/*", doc="--speed max: the time, to each participant when it is due")
    clock_done = Input("clock/done", doc="--speed max: each participant's next due time (ares.core.lockstep)")
    supervisor = Input("supervisor/state", doc="--speed max: a process found dead or hung does not hold the clock")

    def setup(self) -> None:
        sim = self.params
        pace = self.core.lockstep.pace
        self._pacer = Pacer(pace) if pace else None  # --speed paced
        self.route = load_route(self.core)
        scenario = load_scenario(self.core.scenario) if self.core.scenario else None
        start = scenario.start_s_m if scenario is not None and scenario.start_s_m is not None else sim.start_s_m
        self.plant = VehiclePlant(self.route, self.vehicle, sim, s0=start)
        self.sensors = SensorSuite(
            self.route,
            sim,
            LocalFrame(self.core.origin_utm),
            self.vehicle.wheel_radius_m,
            faults=scenario.faults if scenario else (),
        )
        self.dt = 1.0 / sim.physics_hz
        self.periods = {
            "gnss": 1.0 / sim.gnss_hz,
            "imu": 1.0 / sim.imu_hz,
            "can": 1.0 / sim.can_hz,
            "truth": 1.0 / sim.truth_hz,
            "body": 1.0 / sim.body.rate_hz,
            "corrections": 1.0,
        }
        self.body = BodySim(
            sim.body.door_travel_s,
            sim.body.ramp_travel_s,
            sim.body.per_person_s,
            passengers=self.plant.passengers,
            stops={p.poi: p for p in (scenario.passengers if scenario else ())},
        )
        unknown = sorted(set(self.body.stops) - {p.name for p in self.route.pois})
        if unknown:
            raise ValueError(
                f"scenario passengers at {unknown}: no such POI on '{self.route.name}' "
                f"(its POIs: {', '.join(p.name for p in self.route.pois) or 'none'})"
            )
        now = self.clock.now()
        # physics step k is at t0 + k dt exactly: summing dt would drift off the clock's ticks
        self._t0, self._k = now, 0
        self.plant.state.t = now
        self.next_due = {name: now for name in self.periods}
        self.driver = DriverInputs()
        # the scenario's driver actions still to come, and where the shuttle stood at the last step
        self._scripted: list[ScenarioDriverAction] = list(scenario.driver) if scenario else []
        self._scripted_s = self.plant.state.s
        self._injected: list[ScenarioFault] = []  # faults injected at run time (sim/sensor_fault)
        self._failsafe = False
        self.progress_m = 0.0  # along the route, unwrapped: laps = progress // length
        self._last_s = self.plant.state.s

    # ---- driver ---------------------------------------------------------------------------
    @service("sim/driver")
    def _driver_command(self, cmd: DriverCommand) -> Ack:
        return self._drive(cmd, self.clock.now())

    def _drive(self, cmd: DriverCommand, now: float) -> Ack:
        until = now + cmd.duration_s
        if cmd.action == "BUTTON":
            self._panel(PanelInput.BUTTON)
            return Ack(t=now, ok=True, detail="Auto/Manual button pressed")
        if cmd.action == "RELEASE":
            self.driver.release()
            return Ack(t=now, ok=True, detail="driver let go of the controls")
        if cmd.action in ("THROTTLE", "BRAKE") and not 0.0 <= cmd.value <= 1.0:
            return Ack(t=now, ok=False, detail=f"pedal position must be within 0..1, got {cmd.value}")
        if cmd.action == "THROTTLE":
            self.driver.throttle, self.driver.throttle_until = cmd.value, until
        elif cmd.action == "BRAKE":
            self.driver.brake, self.driver.brake_until = cmd.value, until
        else:
            self.driver.steer_deg, self.driver.steer_until = cmd.value, until
        self._panel(ACTION_PANEL[cmd.action], cmd.value)
        return Ack(t=now, ok=True, detail=f"{cmd.action.lower()} {cmd.value:g} for {cmd.duration_s:g} s")

    def _play_scripted(self, t: float) -> None:
        """The scenario's driver actions whose time has come or whose place the shuttle has reached."""
        s_before, s_now = self._scripted_s, self.plant.state.s
        self._scripted_s = s_now
        due = [a for a in self._scripted if self._reached(a, t, s_before, s_now)]
        for action in due:
            self._scripted.remove(action)
            cmd = DriverCommand(action=action.action.upper(), value=action.value, duration_s=action.duration_s)
            ack = self._drive(cmd, t)
            where = f"at t={t:.2f} s" if action.at_t_s is not None else f"at s={s_now:.1f} m"
            self.event(
                "driver_action",
                f"the scenario's driver {where}: {ack.detail}",
                action=action.action,
                value=action.value,
                duration_s=action.duration_s,
                ok=ack.ok,
            )

    def _reached(self, action: ScenarioDriverAction, t: float, s_before: float, s_now: float) -> bool:
        if action.at_t_s is not None:
            return t >= action.at_t_s - 1e-9
        at = float(action.at_s_m or 0.0)
        if self.route.closed and s_now < s_before - 0.5 * self.route.length:  # across the start line
            return at > s_before or at <= s_now
        return s_before < at <= s_now

    # ---- fault injection at run time (a soak: ares.tools.soak) ------------------------------------
    @service("sim/sensor_fault")
    def _sensor_fault(self, request: SensorFault) -> Ack:
        now = self.clock.now()
        fault = ScenarioFault(kind=request.kind, at_t_s=now, duration_s=request.duration_s)
        # the scenario's own faults stay; those injected earlier and over are dropped (a long soak adds many)
        over = {id(f) for f in self._injected if not f.active(now)}
        self._injected = [f for f in self._injected if id(f) not in over] + [fault]
        for sensor in (self.sensors.gnss, self.sensors.imu):
            sensor.faults = [f for f in sensor.faults if id(f) not in over]
        (self.sensors.imu if request.kind == "freeze_imu" else self.sensors.gnss).faults.append(fault)
        return Ack(t=now, ok=True, detail=f"{request.kind} for {request.duration_s:g} s from t={now:.2f}")

    def _panel(self, what: PanelInput, value: float = 1.0) -> None:
        self._send("panel", PanelEvent(t=self.clock.now(), input=what, value=value))

    # ---- the vehicle's side of its wires: the bus here, the devices' formats with --wire --------------
    def _send(self, what: str, msg) -> None:
        """A sensor reading or a driver action, as the vehicle's hardware gives it."""
        {
            "gnss": self.gnss,
            "imu": self.imu,
            "can": self.can,
            "body": self.body_state,
            "panel": self.panel,
        }[what].put(msg)

    def _actuator_command(self, t: float) -> ActuatorCommand | None:
        """The bridge's latest efforts, if fresh at t (else the board's fail-safe acts)."""
        return self.actuators.fresh(t)

    def _body_commands(self) -> list[BodyCommand]:
        return [cmd for _, cmd in self.body_command.drain()]

    # ---- physics --------------------------------------------------------------------------
    def _physics_time(self, k: int) -> float:
        return round(self._t0 + k * self.dt, 9)

    def _physics_step(self) -> None:
        st = self.plant.state
        t = self._physics_time(self._k + 1)
        if self._scripted:
            self._play_scripted(t)
        command = self._actuator_command(t)
        fresh = command is not None
        if self.driver.active(t):
            d = self.driver
            throttle = d.throttle if t < d.throttle_until else 0.0
            brake = d.brake if t < d.brake_until else 0.0
            steer = d.steer_deg if t < d.steer_until and d.steer_deg is not None else st.steering_wheel_deg
            self.plant.step_manual(throttle, brake, steer, self.dt)
        elif fresh and not command.engaged:
            self.plant.step(0.0, -self.params.parking_brake_effort, self.dt)  # Manual, nobody driving: parked
        elif fresh:
            self.plant.step(command.steer_effort, command.drive_effort, self.dt)
        else:
            self.plant.step(0.0, -1.0, self.dt)  # the board's own fail-safe: brake, hold the wheel
        self._failsafe = not fresh and not self.driver.active(t)
        self._k += 1
        st.t = t
        self.progress_m += self.route.step_between(self._last_s, st.s)
        self._last_s = st.s
        for cmd in self._body_commands():
            self.body.command(cmd.doors, cmd.ramp, cmd.media)
        self.body.step(self.dt, self._poi_here())
        if self.body.passengers != self.plant.passengers:
            self.plant.passengers = self.body.passengers  # the laden mass the traction feels

    def _poi_here(self) -> str | None:
        st = self.plant.state
        if abs(st.v) > 0.05:
            return None
        for poi in self.route.pois:
            if abs(self.route.step_between(poi.s, st.s)) <= self.params.body.at_poi_m:
                return poi.name
        return None

    def step(self, now: float) -> None:
        steps = 0
        while self._physics_time(self._k + 1) <= now + 1e-9:
            if steps == self.params.max_catch_up_steps:
                self.log.warning("physics fell %.2f s behind the clock; skipping ahead", now - self.plant.state.t)
                self._k = int((now - self._t0) / self.dt + 1e-9)
                self.plant.state.t = self._physics_time(self._k)
                break
            self._physics_step()
            steps += 1
            self._publish_sensors()

    def _laps(self) -> int:
        return int(self.progress_m // self.route.length) if self.route.closed else 0

    def _due(self, name: str) -> bool:
        t = self.plant.state.t
        if t + 1e-9 < self.next_due[name]:
            return False
        self.next_due[name] = max(round(self.next_due[name] + self.periods[name], 9), t)
        return True

    def _publish_sensors(self) -> None:
        st = self.plant.state
        t = st.t
        if self._due("can"):
            self._send("can", CanFrame(t=t, **self.sensors.can.measure(st)))
        if self._due("imu"):
            self._send("imu", Imu(t=t, **self.sensors.imu.measure(st)))
        if self._due("gnss") and self.sensors.gnss.fix_available(st.s, t):  # an outage: the receiver is silent
            self._send("gnss", GnssSentences(t=t, **self.sensors.gnss.measure(st)))
        if self._due("corrections") and self.corrections is not None:
            self.corrections.put(self._corrections_status(st.s, t))
        if self._due("truth"):
            self.truth.put(
                VehicleTruth(
                    t=t,
                    x=st.x,
                    y=st.y,
                    z=st.z,
                    yaw=st.yaw,
                    pitch=st.pitch,
                    v=st.v,
                    yaw_rate=st.yaw_rate,
                    accel=st.accel,
                    steering_wheel_deg=st.steering_wheel_deg,
                    wheel_angle_rad=st.wheel_angle_rad,
                    s=st.s,
                    odometer_m=st.odometer,
                    lap=self._laps(),
                    rtk_available=self.sensors.gnss.rtk_available(st.s, t),
                    passengers=self.plant.passengers,
                    board_failsafe=self._failsafe,
                )
            )
        if self._due("body"):
            b = self.body
            self._send(
                "body",
                BodyState(
                    t=t,
                    doors=b.door_state,
                    ramp=b.ramp_state,
                    entrance_clear=b.entrance_clear,
                    media=b.media,
                    passengers=b.passengers,
                ),
            )

    def _corrections_status(self, s: float, t: float) -> CorrectionsStatus:
        """The simulated 4G link's corrections, as the NTRIP client reports a real one's."""
        gnss = self.sensors.gnss
        up = gnss.link is not None and gnss.link.up(s, t)
        age = gnss.receiver.age(t)
        why = "" if up else ("no 4G here" if self.route.in_zone(s, "no_4g") else "corrections stopped (a fault)")
        return CorrectionsStatus(
            t=t,
            source="simulated 4G link",
            link="streaming" if up else "down",
            age_s=round(age, 3) if age is not None else None,
            frames=gnss.receiver.frames,
            station_id=1,
            detail=why or f"fix {gnss.fix_kind(s, t).name}",
        )

    # ---- --speed max: this process drives the clock ------------------------------------------
    def loop(self) -> None:
        if not self._driven:
            super().loop()
            return
        master = LockstepMaster(
            self.bus,
            self.core.lockstep,
            start=self.clock.now(),
            ticks=self.clock_ticks,
            participant_ticks=self.participant_ticks,
        )
        while not self.stopping and not self.parent_gone():
            self._leave_the_dead(master)
            done = master.wait_done(self._stop, self._hb_period_s)
            self._report_lockstep(master)
            if not done:
                master.repeat_tick()
                self.bus.poll_services()
                self.heartbeat()
                continue
            due = master.next_due()
            target = (
                master.t + self.core.lockstep.max_step_s
                if due is None
                else min(due, master.t + self.core.lockstep.max_step_s)
            )
            # on the physics grid: sensors and ticks share one timeline
            target = round(
                max(math.ceil(target / self.dt - 1e-9), math.floor(master.t / self.dt + 1e-9) + 1) * self.dt, 9
            )
            self._keep_pace(master.t, target)
            self.step_once(target)
            self.clock.advance(target)
            master.tick(target)
            self.heartbeat()

    def _keep_pace(self, now: float, target: float) -> None:
        """`--speed paced`: wait (answering services) until the wall clock allows `target`."""
        if self._pacer is None:
            return
        due = time.monotonic() + self._pacer.wait_s(now, target, time.monotonic())
        while not self.stopping and (left := due - time.monotonic()) > 0:
            time.sleep(min(left, 0.02))
            self.bus.poll_services()

    def _leave_the_dead(self, master: LockstepMaster) -> None:
        """A participant the supervisor is restarting (dead, or killed for a hang) is left out at
        once: the vehicle's world does not wait for a crashed process."""
        self.supervisor.latch()  # read between steps: while the clock waits, no step latches it
        state = self.supervisor.latest
        if state is None:
            return
        for proc in state.processes:
            if proc.state == ProcessState.RESTARTING or (proc.state == ProcessState.STARTING and proc.restarts > 0):
                master.leave(proc.name)

    def _report_lockstep(self, master: LockstepMaster) -> None:
        for process, left_out in master.take_changes():
            if left_out:
                self.event(
                    "lockstep",
                    f"{process} did not finish its step within {self.core.lockstep.max_wait_s:g} s: "
                    "the clock goes on without it until it reports again",
                    EventLevel.WARNING,
                    process=process,
                )
            else:
                self.event("lockstep", f"{process} is back in step", process=process)
