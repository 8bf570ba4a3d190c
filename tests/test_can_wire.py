"""The CAN frames of ares/core/wire/ares.dbc (ares.core.wire.can_frames): every message survives the
round trip within its signals' resolution, the DBC declares the paper's rates and timeout, and
whatever arrives (lost frames, a corrupt checksum, an unknown id, a short frame, a value out of
range, random bytes) comes back counted or refused by cause, never as an exception."""

from __future__ import annotations

import math

import can
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ares.core.messages import ActuatorCommand, BodyCommand, BodyState, CanFrame, Imu, PanelEvent, PanelInput
from ares.core.wire import can_frames
from ares.core.wire.can_frames import (
    BAD_CHECKSUM,
    BAD_LENGTH,
    INCOMPLETE,
    OUT_OF_RANGE,
    OWN_DIRECTION,
    REPEATED,
    UNKNOWN_ID,
    CanCodec,
    CanDecoder,
    CanEncoder,
    checksum,
    crc8,
)

CODEC = CanCodec.load()
FAST = settings(max_examples=150, deadline=None)


def step(frame: str, signal: str) -> float:
    """A signal's resolution (its scale)."""
    return CODEC.by_name[frame].message.get_signal_by_name(signal).scale


def near(decoded: float, sent: float, frame: str, signal: str) -> bool:
    """Within half a step (the rounding) of what was sent."""
    return abs(decoded - sent) <= step(frame, signal) / 2 + 1e-9


def through(msg, side: str = "computer", t: float = 5.0):
    """msg encoded then decoded by the side that receives it: the message the last frame completes."""
    encoder, decoder = CanEncoder(CODEC), CanDecoder(CODEC, side)  # type: ignore[arg-type]
    results = [decoder.decode(frame, t) for frame in encoder.encode(msg)]
    assert all(r.refused is None and r.skipped is None and r.lost == 0 for r in results), results
    assert all(r.message is None for r in results[:-1])  # a sample is published by its closing frame only
    return results[-1].message


def frame_with(name: str, values: dict[str, float], counter: int = 0) -> can.Message:
    """A frame as a faulty sender would make it: any raw values, a right checksum."""
    spec = CODEC.by_name[name]
    data = bytearray(
        spec.message.encode({**values, "Counter": counter, "Checksum": 0}, scaling=True, strict=False, padding=False)
    )
    data[spec.checksum_byte] = checksum(spec, data)
    return can.Message(arbitration_id=spec.frame_id, is_extended_id=False, data=data)


# ---- the DBC ---------------------------------------------------------------------------------------------


def test_the_dbc_declares_the_papers_setpoint_rate_and_timeout_and_the_simulators_rates():
    periods = CODEC.periods_s
    assert periods["DBW_Command"] == 0.1  # the paper's 100 ms communication task
    assert CODEC.timeouts_s["DBW_Command"] == 1.0  # one second without a setpoint: the board stops
    assert {periods[f] for f in ("SteeringWheel", "Pedals", "VehicleSpeed")} == {0.05}
    assert {periods[f] for f in ("Imu_Attitude", "Imu_Gyro", "Imu_Accel")} == {0.02}
    assert periods["Body_State"] == 0.1
    assert periods["PanelEvent"] is None and periods["Body_Command"] is None  # sent when something happens
    assert CODEC.rate_hz("VehicleSpeed") == pytest.approx(20.0)


def test_every_frame_has_a_standard_id_a_counter_and_a_checksum_in_its_last_byte():
    assert len(CODEC.by_id) == 10
    for spec in CODEC.by_id.values():
        assert spec.frame_id < 0x800
        assert spec.checksum_byte == spec.length - 1
        names = {s.name for s in spec.message.signals}
        assert {"Counter", "Checksum"} <= names
        assert spec.message.get_signal_by_name("Counter").length == 4
    senders = {spec.name for spec in CODEC.by_id.values() if spec.to_vehicle}
    assert senders == {"DBW_Command", "Body_Command"}
    # the setpoint wins arbitration over everything else, the driver's takeover next
    ids = sorted(CODEC.by_id)
    assert [CODEC.by_id[i].name for i in ids[:2]] == ["DBW_Command", "PanelEvent"]


def test_the_checksum_is_crc8_sae_j1850():
    assert crc8(b"123456789") == 0x4B  # the standard check value
    assert crc8(b"") == 0x00


def test_a_given_dbc_file_is_loaded_once():
    assert CanCodec.load(str(can_frames.DBC_PATH)) is CanCodec.load(str(can_frames.DBC_PATH))
    assert CanCodec.load(str(can_frames.DBC_PATH)).by_name.keys() == CODEC.by_name.keys()


# ---- round trips -------------------------------------------------------------------------------------


def signal_range(frame: str, signal: str) -> st.SearchStrategy[float]:
    s = CODEC.by_name[frame].message.get_signal_by_name(signal)
    return st.floats(s.minimum, s.maximum, allow_nan=False)


@FAST
@given(
    wheel=signal_range("VehicleSpeed", "WheelSpeed"),
    speed=signal_range("VehicleSpeed", "Speed"),
    angle=signal_range("SteeringWheel", "Angle"),
    throttle=st.floats(0.0, 1.0),
    brake=st.floats(0.0, 1.0),
    torque=st.booleans(),
)
def test_a_can_frame_survives_the_round_trip_within_resolution(wheel, speed, angle, throttle, brake, torque):
    sent = CanFrame(
        t=0.0,
        wheel_speed_rad_s=wheel,
        speed_mps=speed,
        steering_wheel_deg=angle,
        throttle_pedal=throttle,
        brake_pedal=brake,
        steering_torque=torque,
    )
    got = through(sent)
    assert isinstance(got, CanFrame) and got.t == 5.0
    assert near(got.wheel_speed_rad_s, wheel, "VehicleSpeed", "WheelSpeed")
    assert near(got.speed_mps, speed, "VehicleSpeed", "Speed")
    assert near(got.steering_wheel_deg, angle, "SteeringWheel", "Angle")
    assert near(got.throttle_pedal, throttle, "Pedals", "Throttle")
    assert near(got.brake_pedal, brake, "Pedals", "Brake")
    assert got.steering_torque is torque


@FAST
@given(
    yaw=st.floats(-math.pi, math.pi),
    roll=st.floats(-math.pi, math.pi),
    pitch=st.floats(-math.pi / 2, math.pi / 2),
    gyro=st.tuples(*[signal_range("Imu_Gyro", "GyroX")] * 3),
    accel=st.tuples(*[signal_range("Imu_Accel", "AccelX")] * 3),
)
def test_an_imu_sample_survives_the_round_trip_within_resolution(yaw, roll, pitch, gyro, accel):
    sent = Imu(
        t=0.0,
        yaw=yaw,
        roll=roll,
        pitch=pitch,
        gyro_x=gyro[0],
        gyro_y=gyro[1],
        gyro_z=gyro[2],
        accel_x=accel[0],
        accel_y=accel[1],
        accel_z=accel[2],
    )
    got = through(sent)
    assert isinstance(got, Imu)
    for name, value in (("Yaw", yaw), ("Roll", roll), ("Pitch", pitch)):
        decoded = getattr(got, name.lower())
        assert abs(math.remainder(decoded - value, math.tau)) <= step("Imu_Attitude", name) / 2 + 1e-9
    for axis, value in zip("xyz", gyro, strict=True):
        assert near(getattr(got, f"gyro_{axis}"), value, "Imu_Gyro", "GyroX")
    for axis, value in zip("xyz", accel, strict=True):
        assert near(getattr(got, f"accel_{axis}"), value, "Imu_Accel", "AccelX")


@FAST
@given(engaged=st.booleans(), steer=st.floats(-1.0, 1.0), drive=st.floats(-1.0, 1.0))
def test_an_actuator_command_survives_the_round_trip_within_resolution(engaged, steer, drive):
    got = through(ActuatorCommand(t=0.0, engaged=engaged, steer_effort=steer, drive_effort=drive), side="vehicle")
    assert isinstance(got, ActuatorCommand)
    assert got.engaged is engaged
    assert near(got.steer_effort, steer, "DBW_Command", "SteerEffort")
    assert near(got.drive_effort, drive, "DBW_Command", "DriveEffort")
    assert -1.0 <= got.steer_effort <= 1.0 and -1.0 <= got.drive_effort <= 1.0


@given(
    doors=st.sampled_from([None, "open", "close"]),
    ramp=st.sampled_from([None, "deploy", "stow"]),
    media=st.booleans(),
)
def test_a_body_command_survives_the_round_trip(doors, ramp, media):
    sent = BodyCommand(t=0.0, doors=doors, ramp=ramp, media=media)
    assert through(sent, side="vehicle") == sent.model_copy(update={"t": 5.0})


@given(
    doors=st.sampled_from(["closed", "opening", "open", "closing"]),
    ramp=st.sampled_from(["stowed", "deploying", "deployed", "stowing"]),
    clear=st.booleans(),
    media=st.booleans(),
    passengers=st.integers(0, 255),
)
def test_a_body_state_survives_the_round_trip(doors, ramp, clear, media, passengers):
    sent = BodyState(t=0.0, doors=doors, ramp=ramp, entrance_clear=clear, media=media, passengers=passengers)
    assert through(sent) == sent.model_copy(update={"t": 5.0})


@FAST
@given(what=st.sampled_from(list(PanelInput)), value=st.floats(-3600.0, 3600.0))
def test_a_panel_event_survives_the_round_trip_as_a_float32(what, value):
    got = through(PanelEvent(t=0.0, input=what, value=value))
    assert isinstance(got, PanelEvent) and got.input is what
    assert abs(got.value - value) <= 6e-8 * abs(value) + 1e-30  # IEEE single precision


def test_a_value_beyond_its_range_saturates_as_a_sensor_does_and_is_counted():
    encoder, decoder = CanEncoder(CODEC), CanDecoder(CODEC, "computer")
    hard_hit = Imu(
        t=0.0, yaw=7.0, roll=0.0, pitch=0.0, gyro_x=9.0, gyro_y=0.0, gyro_z=0.0, accel_x=0.0, accel_y=0.0, accel_z=-90.0
    )
    got = [decoder.decode(f, 1.0) for f in encoder.encode(hard_hit)][-1].message
    assert isinstance(got, Imu)
    assert got.yaw == pytest.approx(7.0 - 2 * math.pi, abs=1e-4)  # an angle wraps, it does not saturate
    assert got.gyro_x == pytest.approx(6.5534) and got.accel_z == pytest.approx(-65.534)
    assert encoder.saturated == {"Imu_Gyro.GyroX": 1, "Imu_Accel.AccelZ": 1}


# ---- loss and corruption --------------------------------------------------------------------------


def commands(n: int) -> list[can.Message]:
    encoder = CanEncoder(CODEC)
    return [
        encoder.encode(ActuatorCommand(t=0.0, engaged=True, steer_effort=0.01 * i, drive_effort=0.0))[0]
        for i in range(n)
    ]


def test_counter_gaps_count_as_lost_frames_across_the_wrap():
    frames = commands(40)
    decoder = CanDecoder(CODEC, "vehicle")
    kept = [f for i, f in enumerate(frames) if i not in (3, 4, 20)]
    results = [decoder.decode(f, 0.0) for f in kept]
    assert sum(r.lost for r in results) == 3
    assert [r.lost for r in results if r.lost] == [2, 1]
    assert all(isinstance(r.message, ActuatorCommand) for r in results)


def test_a_frame_repeated_with_the_same_counter_is_refused():
    """A sender stuck repeating its last frame must not keep the board's watchdog fed."""
    frame = commands(1)[0]
    decoder = CanDecoder(CODEC, "vehicle")
    assert decoder.decode(frame, 0.0).message is not None
    again = decoder.decode(frame, 0.1)
    assert again.refused == REPEATED and again.message is None and again.frame == "DBW_Command"


@pytest.mark.parametrize("byte", [0, 2, 7])
def test_a_corrupt_frame_is_refused_for_its_checksum(byte):
    frame = commands(1)[0]
    frame.data[byte] ^= 0x10
    result = CanDecoder(CODEC, "vehicle").decode(frame, 0.0)
    assert result.refused == BAD_CHECKSUM and result.message is None and result.frame == "DBW_Command"


def test_a_frame_sent_under_another_id_fails_its_checksum():
    frame = commands(1)[0]
    body = CODEC.by_name["Body_State"]
    moved = can.Message(arbitration_id=body.frame_id, is_extended_id=False, data=frame.data[: body.length])
    assert CanDecoder(CODEC, "computer").decode(moved, 0.0).refused == BAD_CHECKSUM


@pytest.mark.parametrize(
    "frame",
    [
        can.Message(arbitration_id=0x7FF, is_extended_id=False, data=bytes(8)),
        can.Message(arbitration_id=0x80, is_extended_id=True, data=bytes(8)),  # DBW_Command's id, but extended
    ],
)
def test_an_unknown_id_is_refused(frame):
    result = CanDecoder(CODEC, "vehicle").decode(frame, 0.0)
    assert result.refused == UNKNOWN_ID and result.message is None


@pytest.mark.parametrize("length", [0, 5, 7])
def test_a_frame_of_the_wrong_length_is_refused(length):
    frame = commands(1)[0]
    short = can.Message(arbitration_id=frame.arbitration_id, is_extended_id=False, data=frame.data[:length])
    result = CanDecoder(CODEC, "vehicle").decode(short, 0.0)
    assert result.refused == BAD_LENGTH and "8 expected" in result.detail


@pytest.mark.parametrize(
    ("name", "values"),
    [
        ("Pedals", {"Throttle": 1.023, "Brake": 0.0}),  # raw 1023: a pedal beyond full travel
        ("Body_Command", {"Doors": 3, "Ramp": 0, "Media": 0}),  # no such door command
        ("DBW_Command", {"Engaged": 1, "SteerEffort": 1.5, "DriveEffort": 0.0}),
    ],
)
def test_a_value_out_of_its_range_is_refused(name, values):
    side = "vehicle" if CODEC.by_name[name].to_vehicle else "computer"
    result = CanDecoder(CODEC, side).decode(frame_with(name, values), 0.0)  # type: ignore[arg-type]
    assert result.refused == OUT_OF_RANGE and result.message is None and name in result.detail


def test_frames_lost_before_a_refused_frame_are_still_counted():
    decoder = CanDecoder(CODEC, "computer")
    assert decoder.decode(frame_with("Pedals", {"Throttle": 0.0, "Brake": 0.0}, counter=4), 0.0).lost == 0
    wild = decoder.decode(frame_with("Pedals", {"Throttle": 1.023, "Brake": 0.0}, counter=7), 0.1)
    assert (wild.refused, wild.lost) == (OUT_OF_RANGE, 2)


def test_a_sample_missing_a_frame_is_not_published_and_the_next_one_is():
    encoder, decoder = CanEncoder(CODEC), CanDecoder(CODEC, "computer")
    sample = CanFrame(
        t=0.0,
        wheel_speed_rad_s=1.0,
        speed_mps=0.28,
        steering_wheel_deg=10.0,
        throttle_pedal=0.0,
        brake_pedal=0.0,
        steering_torque=False,
    )
    assert [decoder.decode(f, 0.0) for f in encoder.encode(sample)][-1].message is not None
    first, second = encoder.encode(sample), encoder.encode(sample.model_copy(update={"steering_wheel_deg": 20.0}))
    results = [decoder.decode(f, 1.0) for f in (first[0], first[2])]  # its Pedals frame lost
    assert results[-1].message is None and results[-1].skipped == INCOMPLETE and "Pedals" in results[-1].detail
    results = [decoder.decode(f, 2.0) for f in second]
    assert [r.lost for r in results] == [0, 1, 0]  # Pedals' counter jumped
    assert isinstance(results[-1].message, CanFrame) and results[-1].message.steering_wheel_deg == pytest.approx(20.0)


def test_frames_of_its_own_side_are_skipped():
    """On udp_multicast each side hears its own frames: the driver ignores the commands it sent."""
    result = CanDecoder(CODEC, "computer").decode(commands(1)[0], 0.0)
    assert result.skipped == OWN_DIRECTION and result.message is None and result.refused is None


@settings(max_examples=300, deadline=None)
@given(
    frame_id=st.sampled_from(sorted(CODEC.by_id) + [0x7FF]),
    data=st.binary(min_size=0, max_size=8),
    side=st.sampled_from(["computer", "vehicle"]),
)
def test_random_bytes_never_raise(frame_id, data, side):
    result = CanDecoder(CODEC, side).decode(can.Message(arbitration_id=frame_id, is_extended_id=False, data=data), 0.0)
    assert result.message is None or result.refused is None
    if result.refused is None and result.skipped is None and result.message is None:
        assert CODEC.by_id[frame_id].sample is not None  # a part of a sample, kept for its closing frame
