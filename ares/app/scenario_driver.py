"""What a scenario does to a headless run from outside the simulator, at its stack times: process
faults through the supervisor (kill, stop, hang) and the operator's actions through the vehicle's
services (engage: `set_automatic_mode`; re-arm, pause, resume, cancel, these four signed with the
vehicle's command key as the operator "scenario": ares/core/signed_command.py). The simulator
injects the sensor faults and plays the driver's actions itself; the faults are noted here when
their time comes, so that the safety figures can time the response to each."""

from __future__ import annotations

from collections.abc import Callable

from ares.app.evaluation.safety_eval import SafetyTracker
from ares.core.bus import BaseBus, ServiceError
from ares.core.messages import MissionRequest, RearmRequest
from ares.core.signed_command import sign
from simulator.scenario import PROCESS_FAULTS, Scenario

OPERATOR = "scenario"
SENSOR_OF = {
    "block_lidar": None,
    "freeze_imu": "imu",
    "gyro_bias": "imu",
    "gnss_outage": "gnss",
    "gnss_no_corrections": "gnss",
    "wheel_speed_scale": "can",
}  # None: the fault names its sensor


class ScenarioDriver:
    def __init__(
        self,
        scenario: Scenario | None,
        bus: BaseBus,
        inject: Callable[[str, str], str],
        tracker: SafetyTracker,
        command_key: bytes,
    ):
        self.bus, self.inject, self.tracker, self.command_key = bus, inject, tracker, command_key
        self.timed: list[tuple[float, str, object]] = []
        if scenario is not None:
            self.timed = sorted(
                [(f.at_t_s, "fault", f) for f in scenario.faults if f.at_t_s is not None]
                + [(a.at_t_s, "operator", a) for a in scenario.operator],
                key=lambda item: item[0],
            )
        self.done: list[list] = []  # [t, what, ok, detail]
        # the person at the wheel takes over (the simulator plays it): Manual is then no failure
        self.driver_takes_over = scenario is not None and bool(scenario.driver)

    def step(self, now: float) -> None:
        while self.timed and self.timed[0][0] <= now:
            at, kind, item = self.timed.pop(0)
            if kind == "fault":
                self._fault(at, item)
            else:
                self._operator(now, item.action)

    def _fault(self, at: float, fault) -> None:
        if fault.kind in PROCESS_FAULTS:
            target = fault.process
            try:
                detail, ok = self.inject(target, fault.kind.removesuffix("_process")), True
            except KeyError as exc:
                detail, ok = str(exc), False
        else:
            target = fault.sensor or SENSOR_OF[fault.kind]
            detail, ok = "injected by the simulator", True
        self.tracker.add_fault(at, fault.kind, target)
        self.done.append([round(at, 2), f"{fault.kind} {target}".strip(), ok, detail])

    def _operator(self, now: float, action: str) -> None:
        try:
            if action == "engage":  # the navigation's half of the switch: no person's signature to it
                mode = self.bus.call("set_automatic_mode")
                self.done.append([round(now, 2), action, mode.accepted, mode.reason])
                return
            if action == "rearm":
                service, request = "movement/rearm", RearmRequest(operator=OPERATOR)
            else:
                service, request = f"mission/{action}", MissionRequest(operator=OPERATOR)
            reply = self.bus.call(service, sign(self.command_key, service, request, OPERATOR))
            ok, detail = reply.accepted, reply.reason
        except ServiceError as exc:
            ok, detail = False, str(exc)
        self.done.append([round(now, 2), action, ok, detail])

    def summary(self) -> dict:
        return {"scenario_actions": self.done}
