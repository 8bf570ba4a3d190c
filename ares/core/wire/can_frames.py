"""The vehicle's CAN frames (ares/core/wire/ares.dbc) to and from ARES messages, and the bus they travel on.

Shared by the CAN driver (drivers/can_node.py: reads the vehicle's frames, sends the computer's)
and the simulator's side of the wire (simulator/can_wire.py: the other way round), so both speak
exactly the DBC. The DBC's header comment says why each id, scale and rate.

- `CanCodec`: the DBC loaded once (the packaged one or a given file): each frame's layout, its
  period (GenMsgCycleTime, `periods_s`) and timeout (ARES_TimeoutMs, `timeouts_s`), and the
  end-to-end protection every frame carries: a 4-bit rolling counter and a CRC-8 SAE J1850 over
  the frame id and the data in its last byte.
- `CanEncoder`: an ARES message -> its frames (`can.Message`), counters moving on per frame id;
  a value beyond its signal's range saturates, as a real sensor's does (counted in `saturated`).
- `CanDecoder`: a received `can.Message` -> an ARES message once a sample is complete (the
  CanFrame and the Imu are each spread over three frames), with the frames lost (counter gaps)
  and a refusal by cause (unknown id, bad length, bad checksum, repeated counter, out of range)
  instead of an exception: whatever arrives on a wire must never stop the reader.
- `open_can_bus`: the python-can bus of a `CanDevice` (socketcan on a vehicle, udp_multicast in
  simulation). On udp_multicast every sender hears its own frames too (the group loops back), so
  a decoder skips the frames sent by its own side ("own direction").
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Any, Literal

import can
import cantools
from cantools.database.can import Database
from cantools.database.can import Message as DbcMessage
from pydantic import ValidationError

from ares.core.config.vehicle_io import CanDevice
from ares.core.messages import ActuatorCommand, BodyCommand, BodyState, CanFrame, Imu, PanelEvent, PanelInput
from ares.core.schema import Msg

DBC_PATH = Path(__file__).with_name("ares.dbc")
COMPUTER = "COMPUTER"  # the DBC's node for the vehicle computer: its frames go to the vehicle
COUNTER = "Counter"
CHECKSUM = "Checksum"
COUNTER_MODULO = 16

# refusal causes (WireCounters.refuse) and what is set aside on purpose (WireCounters.skip)
UNKNOWN_ID = "unknown id"
BAD_LENGTH = "bad length"
BAD_CHECKSUM = "bad checksum"
REPEATED = "repeated counter"
OUT_OF_RANGE = "out of range"
UNDECODABLE = "undecodable"
OWN_DIRECTION = "own direction"
INCOMPLETE = "incomplete sample"
NOT_DATA = "error or remote frame"

Side = Literal["computer", "vehicle"]  # who receives: the computer (the driver) or the vehicle (the simulator)

# An ARES message spread over several frames: its frames in sending order, the last one closes it.
SAMPLES: dict[str, tuple[str, ...]] = {
    "CanFrame": ("SteeringWheel", "Pedals", "VehicleSpeed"),
    "Imu": ("Imu_Attitude", "Imu_Gyro", "Imu_Accel"),
}
ANGLES = ("Yaw", "Roll", "Pitch")  # wrapped to [-pi, pi] before encoding


# ---- CRC-8 SAE J1850 -------------------------------------------------------------------------


def _crc8_table(poly: int = 0x1D) -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte
        for _ in range(8):
            crc = ((crc << 1) ^ poly) & 0xFF if crc & 0x80 else (crc << 1) & 0xFF
        table.append(crc)
    return tuple(table)


_CRC8 = _crc8_table()


def crc8(data: bytes | bytearray) -> int:
    """CRC-8 SAE J1850 (poly 0x1D, init 0xFF, final xor 0xFF; check value of b"123456789": 0x4B)."""
    crc = 0xFF
    for byte in data:
        crc = _CRC8[crc ^ byte]
    return crc ^ 0xFF


# ---- the database --------------------------------------------------------------------------------


@dataclass(frozen=True)
class SignalSpec:
    name: str
    minimum: float
    maximum: float
    tolerance: float  # half a step: what rounding may put a decoded value beyond its range
    choices: frozenset[int] | None  # the valid raw values of an enumerated signal


@dataclass(frozen=True)
class FrameSpec:
    """One frame of the DBC as the codec uses it."""

    name: str
    frame_id: int
    length: int
    to_vehicle: bool  # sent by the computer
    checksum_byte: int
    signals: tuple[SignalSpec, ...]  # the data signals (not the counter and the checksum)
    message: DbcMessage
    period_s: float | None  # GenMsgCycleTime; None: sent when something happens
    timeout_s: float | None  # ARES_TimeoutMs: the receiver's silence limit (None: none declared)
    sample: str | None  # the ARES message it is part of, when spread over several frames
    choice_names: dict[str, dict[int, str]] = field(default_factory=dict)  # signal -> raw -> name


class CanCodec:
    """The DBC's frames, loaded once per file (`CanCodec.load`)."""

    def __init__(self, dbc: str | Path | None = None):
        path = Path(dbc) if dbc else DBC_PATH
        db = cantools.database.load_file(str(path))
        if not isinstance(db, Database):
            raise ValueError(f"{path}: not a CAN database")
        self.path = path
        self.db = db
        self.by_id: dict[int, FrameSpec] = {}
        self.by_name: dict[str, FrameSpec] = {}
        sample_of = {frame: sample for sample, frames in SAMPLES.items() for frame in frames}
        for message in db.messages:
            spec = _frame_spec(message, sample_of.get(message.name), path)
            self.by_id[spec.frame_id] = spec
            self.by_name[spec.name] = spec
        for sample, frames in SAMPLES.items():
            missing = [f for f in frames if f not in self.by_name]
            if missing:
                raise ValueError(f"{path}: the {sample} sample needs the frames {', '.join(missing)}")
        for single in ("DBW_Command", "Body_Command", "PanelEvent", "Body_State"):
            if single not in self.by_name:
                raise ValueError(f"{path}: no frame {single}")

    @staticmethod
    @lru_cache(maxsize=8)
    def load(dbc: str | None = None) -> CanCodec:
        """The codec of a DBC file (None: the packaged ares.dbc), parsed once per process."""
        return CanCodec(dbc)

    @property
    def periods_s(self) -> dict[str, float | None]:
        """Each frame's period (GenMsgCycleTime), None for a frame sent when something happens."""
        return {name: spec.period_s for name, spec in self.by_name.items()}

    @property
    def timeouts_s(self) -> dict[str, float | None]:
        return {name: spec.timeout_s for name, spec in self.by_name.items()}

    def rate_hz(self, frame: str) -> float | None:
        period = self.by_name[frame].period_s
        return 1.0 / period if period else None

    def frame(self, name: str, values: dict[str, float], counter: int, timestamp: float = 0.0) -> can.Message:
        """One frame: `values` saturated to their signals' ranges, the counter and the checksum set."""
        spec = self.by_name[name]
        data = bytearray(
            spec.message.encode({**values, COUNTER: counter % COUNTER_MODULO, CHECKSUM: 0}, scaling=True, strict=True)
        )
        data[spec.checksum_byte] = checksum(spec, data)
        return can.Message(
            timestamp=timestamp, arbitration_id=spec.frame_id, is_extended_id=False, dlc=spec.length, data=data
        )


def checksum(spec: FrameSpec, data: bytes | bytearray) -> int:
    """The frame's CRC: over its id (2 bytes, little endian) and every data byte but the checksum's."""
    i = spec.checksum_byte
    return crc8(spec.frame_id.to_bytes(2, "little") + bytes(data[:i]) + bytes(data[i + 1 :]))


def _frame_spec(message: DbcMessage, sample: str | None, path: Path) -> FrameSpec:
    names = {s.name for s in message.signals}
    if COUNTER not in names or CHECKSUM not in names:
        raise ValueError(f"{path}: frame {message.name} lacks its {COUNTER} or {CHECKSUM} signal")
    crc = message.get_signal_by_name(CHECKSUM)
    if crc.length != 8 or crc.start % 8 or crc.byte_order != "little_endian":
        raise ValueError(f"{path}: frame {message.name}: {CHECKSUM} must be one whole byte")
    if message.is_extended_frame:
        raise ValueError(f"{path}: frame {message.name}: ARES uses standard 11-bit ids")
    signals = []
    choice_names: dict[str, dict[int, str]] = {}
    for s in message.signals:
        if s.name in (COUNTER, CHECKSUM):
            continue
        lo = s.minimum if s.minimum is not None else -math.inf
        hi = s.maximum if s.maximum is not None else math.inf
        choices = frozenset(int(k) for k in s.choices) if s.choices else None
        if s.choices:
            choice_names[s.name] = {int(k): str(v) for k, v in s.choices.items()}
        signals.append(SignalSpec(s.name, lo, hi, 0.0 if s.is_float else abs(s.scale) / 2, choices))
    timeout = message.dbc.attributes.get("ARES_TimeoutMs") if message.dbc else None
    return FrameSpec(
        name=message.name,
        frame_id=message.frame_id,
        length=message.length,
        to_vehicle=COMPUTER in message.senders,
        checksum_byte=crc.start // 8,
        signals=tuple(signals),
        message=message,
        period_s=message.cycle_time / 1e3 if message.cycle_time else None,
        timeout_s=float(timeout.value) / 1e3 if timeout is not None and timeout.value else None,
        sample=sample,
        choice_names=choice_names,
    )


# ---- ARES messages -> frames --------------------------------------------------------------------


def _choice(spec: FrameSpec, signal: str, name: str) -> int:
    """The raw value of an enumerated signal's choice, by its name in the DBC (any case)."""
    for raw, choice in spec.choice_names[signal].items():
        if choice.lower() == name.lower():
            return raw
    raise ValueError(f"{spec.name}.{signal} has no choice {name!r}")


class CanEncoder:
    """ARES messages to frames; one rolling counter per frame id (a sample's frames share theirs)."""

    def __init__(self, codec: CanCodec):
        self.codec = codec
        self.counters: Counter[str] = Counter()
        self.saturated: Counter[str] = Counter()  # "Frame.Signal": values beyond range, sent at its limit

    def encode(self, msg: Msg, timestamp: float = 0.0) -> list[can.Message]:
        """The frames that carry `msg`, in sending order (a sample's closing frame last)."""
        by_name = self.codec.by_name
        if isinstance(msg, CanFrame):
            frames = {
                "SteeringWheel": {"Angle": msg.steering_wheel_deg, "SteeringTorque": int(msg.steering_torque)},
                "Pedals": {"Throttle": msg.throttle_pedal, "Brake": msg.brake_pedal},
                "VehicleSpeed": {"WheelSpeed": msg.wheel_speed_rad_s, "Speed": msg.speed_mps},
            }
        elif isinstance(msg, Imu):
            frames = {
                "Imu_Attitude": {"Yaw": msg.yaw, "Roll": msg.roll, "Pitch": msg.pitch},
                "Imu_Gyro": {"GyroX": msg.gyro_x, "GyroY": msg.gyro_y, "GyroZ": msg.gyro_z},
                "Imu_Accel": {"AccelX": msg.accel_x, "AccelY": msg.accel_y, "AccelZ": msg.accel_z},
            }
        elif isinstance(msg, ActuatorCommand):
            frames = {
                "DBW_Command": {
                    "Engaged": int(msg.engaged),
                    "SteerEffort": msg.steer_effort,
                    "DriveEffort": msg.drive_effort,
                }
            }
        elif isinstance(msg, BodyCommand):
            spec = by_name["Body_Command"]
            frames = {
                "Body_Command": {
                    "Doors": _choice(spec, "Doors", msg.doors or "none"),
                    "Ramp": _choice(spec, "Ramp", msg.ramp or "none"),
                    "Media": int(msg.media),
                }
            }
        elif isinstance(msg, PanelEvent):
            spec = by_name["PanelEvent"]
            frames = {"PanelEvent": {"Input": _choice(spec, "Input", msg.input.value), "Value": msg.value}}
        elif isinstance(msg, BodyState):
            spec = by_name["Body_State"]
            frames = {
                "Body_State": {
                    "Doors": _choice(spec, "Doors", msg.doors),
                    "Ramp": _choice(spec, "Ramp", msg.ramp),
                    "EntranceClear": int(msg.entrance_clear),
                    "Media": int(msg.media),
                    "Passengers": msg.passengers,
                }
            }
        else:
            raise TypeError(f"no CAN frame carries {type(msg).__name__}")
        out = []
        for name, values in frames.items():
            spec = by_name[name]
            key = spec.sample or name  # a sample's frames share one counter: the receiver matches them by it
            out.append(self.codec.frame(name, self._saturate(spec, values), self.counters[key], timestamp))
        for key in {by_name[name].sample or name for name in frames}:
            self.counters[key] = (self.counters[key] + 1) % COUNTER_MODULO
        return out

    def _saturate(self, spec: FrameSpec, values: dict[str, float]) -> dict[str, float]:
        out = {}
        for s in spec.signals:
            v = values[s.name]
            if s.name in ANGLES:
                v = math.remainder(v, math.tau)
            if v < s.minimum or v > s.maximum:
                self.saturated[f"{spec.name}.{s.name}"] += 1
                v = min(max(v, s.minimum), s.maximum)
            out[s.name] = v
        return out


# ---- frames -> ARES messages --------------------------------------------------------------------


@dataclass(slots=True)
class Decoded:
    """What one received frame gave: a complete message, or why not."""

    frame: str = ""  # its name in the DBC ("" for an unknown id)
    message: Msg | None = None  # a complete ARES message, stamped with the caller's time
    lost: int = 0  # frames of this id missing before this one (its counter jumped)
    refused: str | None = None  # the cause, when the frame is malformed
    skipped: str | None = None  # set aside on purpose: own direction, incomplete sample, ...
    detail: str = ""


class Refused(Exception):
    """A malformed frame (internal to the decoder: `decode` returns it as a `Decoded`)."""

    def __init__(self, cause: str, detail: str = "", frame: str = ""):
        super().__init__(cause, detail)
        self.cause = cause
        self.detail = detail
        self.frame = frame


class CanDecoder:
    """Received frames to ARES messages, for one side of the bus: the computer (it takes the
    vehicle's frames) or the vehicle (it takes the computer's)."""

    def __init__(self, codec: CanCodec, side: Side):
        self.codec = codec
        self.side = side
        self._counters: dict[int, int] = {}  # frame id -> its last counter
        self._parts: dict[str, dict[str, tuple[int, dict[str, float]]]] = {s: {} for s in SAMPLES}

    def decode(self, frame: can.Message, t: float) -> Decoded:
        """One received frame; the message it completes is stamped `t`. Never raises on what the
        frame holds: a malformed one comes back refused with its cause."""
        try:
            return self._decode(frame, t)
        except Refused as exc:
            return Decoded(frame=exc.frame, refused=exc.cause, detail=exc.detail)
        except (ValueError, TypeError, KeyError, OverflowError, cantools.database.DecodeError) as exc:
            return Decoded(refused=UNDECODABLE, detail=f"id 0x{frame.arbitration_id:x}: {exc}")

    def _decode(self, frame: can.Message, t: float) -> Decoded:
        if frame.is_error_frame or frame.is_remote_frame:
            return Decoded(skipped=NOT_DATA)
        spec = self.codec.by_id.get(frame.arbitration_id)
        if spec is None or frame.is_extended_id:
            raise Refused(UNKNOWN_ID, f"id 0x{frame.arbitration_id:x}{' (extended)' if frame.is_extended_id else ''}")
        if spec.to_vehicle != (self.side == "vehicle"):
            return Decoded(frame=spec.name, skipped=OWN_DIRECTION)
        data = bytes(frame.data)
        if len(data) != spec.length:
            raise Refused(BAD_LENGTH, f"{spec.name}: {len(data)} bytes, {spec.length} expected", spec.name)
        if data[spec.checksum_byte] != checksum(spec, data):
            raise Refused(BAD_CHECKSUM, f"{spec.name}: {data.hex()}", spec.name)
        # numbers only: choices are not decoded to names, so every value is an int or a float
        raw: dict[str, Any] = dict(spec.message.decode_simple(data, decode_choices=False, scaling=True))
        counter = int(raw[COUNTER])
        lost = self._count(spec, counter)  # the checksum holds: the counter is the sender's, whatever the values
        try:
            values = self._in_range(spec, raw)
            message, skipped, detail = self._message(spec, counter, values, t)
        except Refused as exc:
            return Decoded(frame=spec.name, lost=lost, refused=exc.cause, detail=exc.detail)
        return Decoded(frame=spec.name, message=message, lost=lost, skipped=skipped, detail=detail)

    def _count(self, spec: FrameSpec, counter: int) -> int:
        """Frames lost since the last one of this id; the same counter again is refused."""
        last = self._counters.get(spec.frame_id)
        self._counters[spec.frame_id] = counter
        if last is None:
            return 0
        step = (counter - last) % COUNTER_MODULO
        if step == 0:
            raise Refused(REPEATED, f"{spec.name}: counter {counter} again", spec.name)
        return step - 1

    @staticmethod
    def _in_range(spec: FrameSpec, raw: dict[str, Any]) -> dict[str, float]:
        values = {}
        for s in spec.signals:
            v = float(raw[s.name])
            if not (s.minimum - s.tolerance <= v <= s.maximum + s.tolerance) or (
                s.choices is not None and int(v) not in s.choices
            ):
                raise Refused(OUT_OF_RANGE, f"{spec.name}.{s.name} = {v:g}", spec.name)
            values[s.name] = min(max(v, s.minimum), s.maximum)  # rounding's half step back inside
        return values

    def _message(
        self, spec: FrameSpec, counter: int, v: dict[str, float], t: float
    ) -> tuple[Msg | None, str | None, str]:
        if spec.sample is not None:
            return self._sample(spec, counter, v, t)
        names = spec.choice_names
        try:
            if spec.name == "DBW_Command":
                msg: Msg = ActuatorCommand(
                    t=t, engaged=bool(v["Engaged"]), steer_effort=v["SteerEffort"], drive_effort=v["DriveEffort"]
                )
            elif spec.name == "Body_Command":
                doors = names["Doors"][int(v["Doors"])].lower()
                ramp = names["Ramp"][int(v["Ramp"])].lower()
                msg = BodyCommand.model_validate(
                    {
                        "t": t,
                        "doors": None if doors == "none" else doors,
                        "ramp": None if ramp == "none" else ramp,
                        "media": bool(v["Media"]),
                    }
                )
            elif spec.name == "PanelEvent":
                msg = PanelEvent(t=t, input=PanelInput(names["Input"][int(v["Input"])]), value=v["Value"])
            elif spec.name == "Body_State":
                msg = BodyState.model_validate(
                    {
                        "t": t,
                        "doors": names["Doors"][int(v["Doors"])].lower(),
                        "ramp": names["Ramp"][int(v["Ramp"])].lower(),
                        "entrance_clear": bool(v["EntranceClear"]),
                        "media": bool(v["Media"]),
                        "passengers": int(v["Passengers"]),
                    }
                )
            else:
                return None, None, ""  # a frame of the DBC that ARES does not read
        except ValidationError as exc:
            raise Refused(OUT_OF_RANGE, f"{spec.name}: {exc.errors()[0]['msg']}", spec.name) from None
        return msg, None, ""

    def _sample(
        self, spec: FrameSpec, counter: int, v: dict[str, float], t: float
    ) -> tuple[Msg | None, str | None, str]:
        """Keep a sample's part; on its closing frame, the message if every part has this counter."""
        assert spec.sample is not None
        frames = SAMPLES[spec.sample]
        parts = self._parts[spec.sample]
        parts[spec.name] = (counter, v)
        if spec.name != frames[-1]:
            return None, None, ""
        missing = [f for f in frames if f not in parts or parts[f][0] != counter]
        got = {name: values for name, (_, values) in parts.items()}
        parts.clear()  # each part serves one sample only: a part lost later cannot be filled by an old one
        if missing:
            return None, INCOMPLETE, f"{spec.sample} {counter}: no {', '.join(missing)}"
        try:
            if spec.sample == "CanFrame":
                steer, pedals, speed = (got[f] for f in frames)
                msg: Msg = CanFrame(
                    t=t,
                    wheel_speed_rad_s=speed["WheelSpeed"],
                    speed_mps=speed["Speed"],
                    steering_wheel_deg=steer["Angle"],
                    throttle_pedal=pedals["Throttle"],
                    brake_pedal=pedals["Brake"],
                    steering_torque=bool(steer["SteeringTorque"]),
                )
            else:
                att, gyro, acc = (got[f] for f in frames)
                msg = Imu(
                    t=t,
                    yaw=att["Yaw"],
                    roll=att["Roll"],
                    pitch=att["Pitch"],
                    gyro_x=gyro["GyroX"],
                    gyro_y=gyro["GyroY"],
                    gyro_z=gyro["GyroZ"],
                    accel_x=acc["AccelX"],
                    accel_y=acc["AccelY"],
                    accel_z=acc["AccelZ"],
                )
        except ValidationError as exc:
            raise Refused(OUT_OF_RANGE, f"{spec.sample}: {exc.errors()[0]['msg']}", spec.name) from None
        return msg, None, ""


# ---- the bus ---------------------------------------------------------------------------------------


def open_can_bus(device: CanDevice, receive_own: bool = False) -> can.BusABC:
    """The python-can bus of a device. On udp_multicast a sender hears its own frames whatever
    `receive_own` says (the group loops back; python-can refuses receive_own_messages=True there)."""
    kwargs: dict[str, Any] = {"interface": device.interface, "channel": device.channel}
    if device.interface == "udp_multicast":
        if device.port is not None:
            kwargs["port"] = device.port
    elif receive_own:
        kwargs["receive_own_messages"] = True
    return can.Bus(**kwargs)
