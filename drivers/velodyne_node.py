"""The Velodyne LiDAR driver: UDP data packets in, one PointCloud per rotation out.

Each LiDAR of `vehicle_io.lidars` sends its data packets to a UDP port of this computer; the
driver binds one socket per sensor (an 8 MiB receive buffer: an HDL-64E sends 3.5 MB/s, and a
step of the stack must not lose a burst), drains it without blocking every step, cuts the
packets into rotations and decodes them (ares/core/wire/velodyne.py), and publishes each
finished rotation on `lidar/<name>/points` as the simulator does. A rotation is stamped with its
first packet's timestamp (µs past the UTC hour) by the stamp rule, so it carries the time the
sensor fired, not the time it arrived. Truncated rotations (start-up, a stalled stream) are
counted and not published. The latency is from the kernel's receive time of a rotation's last
packet (SO_TIMESTAMPNS) to the put.

The configured model decides the decoding: a factory byte that names another model (early VLP-16s
write the HDL-32E's 0x21) is counted and reported once, never obeyed. Packets from any sender but
the sensor's `source` address (when set) are refused. A sensor whose azimuth stops advancing has
its rotations cut by packet count (memory stays bounded) and the stall reported. With `pcap: FILE`
a capture plays in place of the socket, by its capture times on the stack clock; its rotations
are stamped on that clock too (a capture's own hour is long past).

Unless `recording.driver_lidar` is `clouds`, each step's packets (the ones given to the decoder,
with their receive times) also go out on `lidar/<name>/packets`, before the clouds they finish,
so a recording keeps the packets as received and rebuilds the clouds through the same decoder
(ares/core/wire/velodyne_packets.py).
"""

from __future__ import annotations

import socket
import struct
import time

from ares.core.config import Params, param
from ares.core.config.vehicle_io import VelodyneDevice
from ares.core.driver import DriverNode
from ares.core.node import Output
from ares.core.wire.pcap import CapturePlayer
from ares.core.wire.velodyne import HOUR_US, Rotation
from ares.core.wire.velodyne_packets import assembler_for, packets_message, rotation_cloud

SO_TIMESTAMPNS = getattr(socket, "SO_TIMESTAMPNS", 35)  # Linux; Python names it only on some builds
SO_RCVBUFFORCE = getattr(socket, "SO_RCVBUFFORCE", 33)
RECEIVE_BUFFER = 8 * 1024 * 1024
_TIMESPEC = struct.Struct("@qq")
HOUR_S = HOUR_US / 1e6
NAMES = ("roof", "front_left", "front_right")


class VelodyneDriverParams(Params):
    """The Velodyne driver (drivers/velodyne_node.py)."""

    rate_hz: float = param(50.0, "steps per second: each drains the sockets", unit="Hz", gt=0)
    reopen_s: float = param(
        0.5, "a socket that cannot be bound, or a silent sensor, is reopened this often", unit="s", gt=0
    )
    silent_after_s: float = param(1.0, "no packet for this long (wall): the sensor counts as silent", unit="s", gt=0)
    truncated_below_deg: float = param(
        300.0,
        "a rotation covering less azimuth than this is truncated: counted, not published",
        unit="deg",
        gt=0,
        le=360,
    )
    rate_tolerance: float = param(
        0.1, "a measured rotation rate further than this share from the configured one is reported", gt=0
    )
    max_packets_per_step: int = param(20000, "at most this many packets read per sensor and step", ge=1)


class _Sensor:
    def __init__(self, name: str, device: VelodyneDevice, params: VelodyneDriverParams):
        self.name = name
        self.device = device
        self.assembler = assembler_for(device, params.truncated_below_deg)
        self.sock: socket.socket | None = None
        self.player: CapturePlayer | None = None  # a capture in place of the socket (device.pcap)
        self.last_player: CapturePlayer | None = None  # ... kept for its counts once closed
        self.played_from = 0.0  # the stack time the capture started playing at
        self.capture_epoch = 0.0  # the capture's stamp rule: its first packet's µs past the hour at played_from
        self.retry_at = 0.0  # wall
        self.last_packet_wall = 0.0
        self.opened_wall = 0.0
        self.silent = False
        self.capture_done = False  # a capture played to its end (without pcap_loop): not opened again
        self.loops_seen = 0
        self.step_packets: list[tuple[bytes, float]] = []  # this step's packets given to the assembler
        self.step_flushed = False  # ... after which the rotation under way was finished (the stream stopped)

    @property
    def is_open(self) -> bool:
        return self.sock is not None or self.player is not None


class VelodyneDriver(DriverNode):
    """Reads the Velodyne LiDARs' UDP data packets and publishes a point cloud per rotation."""

    name = "lidar_driver"
    Params = VelodyneDriverParams
    wire_inputs = ("wire/lidar",)
    # a rotation goes out when it is complete: at the sensor's rate, not the loop's
    roof = Output("lidar/roof/points", doc="the roof LiDAR's rotations")
    front_left = Output("lidar/front_left/points", doc="the front-left LiDAR's rotations")
    front_right = Output("lidar/front_right/points", doc="the front-right LiDAR's rotations")
    roof_packets = Output("lidar/roof/packets", doc="the roof LiDAR's packets of each step, as received")
    front_left_packets = Output("lidar/front_left/packets", doc="the front-left LiDAR's packets, as received")
    front_right_packets = Output("lidar/front_right/packets", doc="the front-right LiDAR's packets, as received")

    def setup(self) -> None:
        self.sensors: dict[str, _Sensor] = {}
        self.outputs_by_sensor = {"roof": self.roof, "front_left": self.front_left, "front_right": self.front_right}
        self.packet_outputs = {
            "roof": self.roof_packets,
            "front_left": self.front_left_packets,
            "front_right": self.front_right_packets,
        }
        self.publish_packets = self.core.recording.driver_lidar != "clouds"
        for name, device in self.core.vehicle_io.lidars.items():
            if name not in NAMES:
                self.log.warning("vehicle_io lidar %r: not one of %s, not read", name, ", ".join(NAMES))
                continue
            self.sensors[name] = _Sensor(name, device, self.params)
            self.wire(f"lidar/{name}")
        if not self.sensors:
            self.log.warning("vehicle_io has no lidars: nothing to read")

    def teardown(self) -> None:
        for sensor in self.sensors.values():
            self._close(sensor)

    # ---- sockets and captures ------------------------------------------------------------------
    def _open(self, sensor: _Sensor, wall: float) -> None:
        counters = self.wire(f"lidar/{sensor.name}")
        if sensor.device.pcap is not None:
            self._open_capture(sensor, wall)
            return
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            try:  # beyond net.core.rmem_max when privileged
                sock.setsockopt(socket.SOL_SOCKET, SO_RCVBUFFORCE, RECEIVE_BUFFER)
            except OSError:
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, RECEIVE_BUFFER)
            sock.setsockopt(socket.SOL_SOCKET, SO_TIMESTAMPNS, 1)
            sock.bind((sensor.device.address, sensor.device.port))
            sock.setblocking(False)
        except OSError as exc:
            sock.close()
            counters.connected = False
            counters.problem("cannot open", f"{sensor.device.address}:{sensor.device.port}: {exc.strerror or exc}")
            sensor.retry_at = wall + self.params.reopen_s
            return
        sensor.sock = sock
        sensor.opened_wall = wall
        sensor.silent = False
        self.log.info(
            "%s: %s on udp %s:%d (calibration %s)",
            sensor.name,
            sensor.device.model,
            sensor.device.address,
            sensor.device.port,
            sensor.assembler.calibration.path,
        )

    def _open_capture(self, sensor: _Sensor, wall: float) -> None:
        counters = self.wire(f"lidar/{sensor.name}")
        device = sensor.device
        assert device.pcap is not None  # only for a capture
        try:  # the player opens the file at once: a missing or bad one fails here, not mid-run
            sensor.player = CapturePlayer(device.pcap, port=device.port, source=device.source, loop=device.pcap_loop)
        except ValueError as exc:
            counters.connected = False
            counters.problem("cannot open", str(exc))
            sensor.player = None
            sensor.retry_at = wall + self.params.reopen_s
            return
        sensor.played_from = self.clock.now()
        sensor.opened_wall = wall
        sensor.silent = False
        self.log.info("%s: %s from the capture %s (port %d)", sensor.name, device.model, device.pcap, device.port)

    def _close(self, sensor: _Sensor) -> None:
        if sensor.sock is not None:
            sensor.sock.close()
            sensor.sock = None
        if sensor.player is not None:
            sensor.last_player = sensor.player
        sensor.player = None

    def _drain(self, sensor: _Sensor) -> list[Rotation]:
        """Everything queued on the socket, without blocking: the rotations it finishes."""
        assert sensor.sock is not None
        done: list[Rotation] = []
        cmsg_space = socket.CMSG_SPACE(_TIMESPEC.size)
        for _ in range(self.params.max_packets_per_step):
            try:
                data, ancillary, _flags, addr = sensor.sock.recvmsg(2048, cmsg_space)
            except (BlockingIOError, InterruptedError):
                break
            except OSError as exc:  # the interface went away: reopen
                self.wire(f"lidar/{sensor.name}").problem("read failed", str(exc))
                self._close(sensor)
                sensor.retry_at = time.time() + self.params.reopen_s
                break
            wall = time.time()
            for level, kind, value in ancillary:
                if level == socket.SOL_SOCKET and kind == SO_TIMESTAMPNS and len(value) >= _TIMESPEC.size:
                    seconds, nanos = _TIMESPEC.unpack_from(value)
                    wall = seconds + nanos * 1e-9
            sensor.last_packet_wall = wall
            if sensor.device.source is not None and addr[0] != sensor.device.source:
                sensor.assembler.packets += 1
                self.wire(f"lidar/{sensor.name}").refuse("wrong source", f"from {addr[0]}:{addr[1]}")
                continue
            done += self._decode(sensor, data, wall)
        return done

    def _play(self, sensor: _Sensor, now: float) -> list[Rotation]:
        """The capture's datagrams due by the stack clock: the rotations they finish."""
        player = sensor.player
        assert player is not None
        done: list[Rotation] = []
        wall = time.time()
        try:
            datagrams = player.due(now - sensor.played_from, limit=self.params.max_packets_per_step)
        except ValueError as exc:  # the file gone or broken under a loop's restart
            self.wire(f"lidar/{sensor.name}").problem("cannot read", str(exc))
            self._close(sensor)
            sensor.retry_at = wall + self.params.reopen_s
            return []
        for datagram in datagrams:
            if player.loops != sensor.loops_seen or sensor.assembler.packets == 0:
                # the capture's hour on the stack clock, anew at each pass: a packet's own time
                # maps to the stack time it plays at (the stamp rule then gives its rotation's age)
                sensor.loops_seen = player.loops
                device_s = int.from_bytes(datagram.payload[1200:1204], "little") / 1e6
                sensor.capture_epoch = (device_s - sensor.played_from - player.play_time(datagram)) % HOUR_S
            sensor.last_packet_wall = wall
            done += self._decode(sensor, datagram.payload, wall)
        if player.finished:
            done += self._flush(sensor)
            sensor.capture_done = True
            self.log.info("%s: the capture %s played to its end", sensor.name, sensor.device.pcap)
            self._close(sensor)
        return done

    def _decode(self, sensor: _Sensor, data: bytes, wall: float) -> list[Rotation]:
        if self.publish_packets:
            sensor.step_packets.append((data, wall))
        return sensor.assembler.add(data, wall)

    def _flush(self, sensor: _Sensor) -> list[Rotation]:
        sensor.step_flushed = True
        return sensor.assembler.flush()

    def _capture_over(self, sensor: _Sensor) -> bool:
        return sensor.device.pcap is not None and sensor.capture_done

    # ---- the step ------------------------------------------------------------------------------
    def step(self, now: float) -> None:
        wall = time.time()
        for sensor in self.sensors.values():
            counters = self.wire(f"lidar/{sensor.name}")
            if not sensor.is_open:
                if wall >= sensor.retry_at and not self._capture_over(sensor):
                    self._open(sensor, wall)
                if not sensor.is_open:
                    continue
            asm = sensor.assembler
            before = asm.packets, asm.lost
            rotations = self._play(sensor, now) if sensor.player is not None else self._drain(sensor)
            counters.got(asm.packets - before[0])
            counters.missing(asm.lost - before[1], "gaps in the packets' timestamps or azimuths")
            for cause, detail in asm.refused:
                counters.refuse(cause, detail)
            asm.refused.clear()
            for cause, text in asm.notices:
                counters.problem(cause, text)
            asm.notices.clear()
            rotations += self._silence(sensor, counters, wall)
            self._publish_packets(sensor, now)
            for rotation in rotations:
                self._publish(sensor, rotation, now)
            self._watch(sensor, counters, wall)
        self.report(now)

    def _publish_packets(self, sensor: _Sensor, now: float) -> None:
        """The step's packets, before the clouds they finish (a replay rebuilds those from these)."""
        if self.publish_packets and (sensor.step_packets or sensor.step_flushed):
            self.packet_outputs[sensor.name].put(
                packets_message(now, sensor.name, self._epoch(sensor), sensor.step_packets, sensor.step_flushed)
            )
        sensor.step_packets = []
        sensor.step_flushed = False

    def _publish(self, sensor: _Sensor, rotation: Rotation, now: float) -> None:
        counters = self.wire(f"lidar/{sensor.name}")
        if rotation.truncated:
            counters.skip("truncated rotation")
            return
        self.outputs_by_sensor[sensor.name].put(rotation_cloud(sensor.name, rotation, now, self._epoch(sensor)))
        counters.put(rotation.last_wall)
        configured = sensor.device.rate_hz
        if (
            rotation.rate_hz is not None
            and abs(rotation.rate_hz - configured) > self.params.rate_tolerance * configured
        ):
            counters.problem("rotation rate", f"{rotation.rate_hz:.2f} Hz measured, {configured:g} Hz configured")

    def _epoch(self, sensor: _Sensor) -> float:
        """The calendar time of stack time 0 by which the sensor's packet times are read."""
        return sensor.capture_epoch if sensor.device.pcap is not None else self.clock.utc_epoch

    def _silence(self, sensor: _Sensor, counters, wall: float) -> list[Rotation]:
        """A sensor that fell silent this step: the rotation under way, which will not be completed."""
        if self._capture_over(sensor):
            return []
        heard = max(sensor.last_packet_wall, sensor.opened_wall)
        silent = wall - heard > self.params.silent_after_s
        fell_silent = silent and not sensor.silent
        sensor.silent = silent
        if not fell_silent:
            return []
        counters.problem("silent", f"no packet for {self.params.silent_after_s:g} s")
        return self._flush(sensor)

    def _watch(self, sensor: _Sensor, counters, wall: float) -> None:
        if self._capture_over(sensor):
            counters.connected = False
            counters.detail = f"{self._summary(sensor)}; the capture {sensor.device.pcap} played to its end"
            return
        heard = max(sensor.last_packet_wall, sensor.opened_wall)
        silent = sensor.silent
        counters.connected = sensor.is_open and sensor.last_packet_wall >= sensor.opened_wall and not silent
        if silent and sensor.player is None and wall - heard > self.params.reopen_s + self.params.silent_after_s:
            self._close(sensor)  # a fresh socket: an interface that came back, a rebound address
            sensor.retry_at = wall  # (a capture plays on the stack clock: a pause in it is no dead socket)
        counters.detail = self._summary(sensor)

    def _summary(self, sensor: _Sensor) -> str:
        asm = sensor.assembler
        rate = f"{asm.measured_rate_hz:.2f} Hz" if asm.measured_rate_hz is not None else "no rate yet"
        where = f"capture {sensor.device.pcap}" if sensor.device.pcap is not None else f"port {sensor.device.port}"
        text = (
            f"{sensor.device.model} {where}: {asm.rotations} rotations, {asm.truncated} truncated, "
            f"{rate} (set {sensor.device.rate_hz:g} Hz)"
        )
        player = sensor.player or sensor.last_player
        if player is not None and (player.other or player.counts.skipped):
            others = sum(player.other.values())
            text += f"; the capture's other datagrams: {others} not to port {sensor.device.port} or not from the source"
            text += "".join(f", {n} {cause}" for cause, n in player.counts.skipped.items())
        for product, n in asm.factory_bytes.items():
            text += f"; factory byte 0x{product:02x} in {n} packets: decoded as the configured {sensor.device.model}"
        if asm.azimuth_stalls:
            text += f"; azimuth stalled: {asm.azimuth_stalls} rotations cut at {asm.max_packets} packets"
        return text
