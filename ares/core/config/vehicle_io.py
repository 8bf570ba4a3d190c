"""The vehicle's devices (`vehicle_io`): where each driver reads its device and how.

On a shuttle this section describes the real devices (`ares run --vehicle-io FILE`, a YAML file of
this section: serial ports, UDP ports, the CAN channel and its DBC); with `ares run --wire` it is
filled in by `ares run` with the simulator's own wires (a pseudo-terminal, loopback UDP ports, a
python-can `udp_multicast` group), so the simulator writes exactly where the drivers read. A
device left out has no driver: `simulate: false` then refuses to start while a running node
needs what that device would publish.
"""

from __future__ import annotations

import ipaddress
from typing import Literal

from pydantic import field_validator, model_validator

from ares.core.config.base import Params, param


class GnssDevice(Params):
    """The GNSS receiver: NMEA 0183 (UBX frames on the same stream are skipped and counted)."""

    source: Literal["serial", "tcp", "gpsd"] = param(
        doc="serial: a serial port or pseudo-terminal; tcp: a receiver's NMEA server; gpsd: a gpsd "
        "daemon's JSON protocol (WATCH with raw NMEA)"
    )
    device: str | None = param(None, "serial: the port (/dev/ttyACM0, a pty); gpsd: the receiver it serves (all: null)")
    baud: int = param(115200, "serial: line speed", unit="bit/s", gt=0)
    host: str = param("127.0.0.1", "tcp and gpsd: the server's address")
    port: int | None = param(None, "tcp: the receiver's NMEA port; gpsd: its port (null: 2947)", gt=0, lt=65536)
    silent_after_s: float = param(
        1.0, "no byte for this long (wall): the device counts as silent, and is reopened", unit="s", gt=0
    )

    @model_validator(mode="after")
    def _where(self) -> GnssDevice:
        if self.source == "serial" and not self.device:
            raise ValueError("a serial GNSS receiver needs its `device` (a serial port such as /dev/ttyACM0)")
        if self.source == "tcp" and self.port is None:
            raise ValueError("a TCP GNSS receiver needs its `port`")
        return self


class VelodyneDevice(Params):
    """One Velodyne LiDAR sending its UDP data packets to this computer."""

    model: Literal["VLP-16", "HDL-32E", "VLP-32C", "HDL-64E", "VLS-128"] = param(
        doc="the sensor's model: it decides the packet layout and the default calibration (a factory "
        "byte in the packets that names another model is reported, not obeyed)"
    )
    address: str = param("0.0.0.0", "the address the data packets are received on")
    port: int = param(2368, "the data packets' UDP port (Velodyne's default: 2368)", gt=0, lt=65536)
    source: str | None = param(
        None,
        "the sensor's own IP address: packets from any other sender are refused and counted (null: any; "
        "set it when two sensors or a stray sender can reach the port)",
    )
    pcap: str | None = param(
        None,
        "a capture file (.pcap or .pcapng, as tcpdump or Wireshark write it) read in place of the socket: "
        "its datagrams to `port` (and from `source`, if set) played by their capture times on the stack "
        "clock, so at --speed max as fast as the stack steps",
    )
    pcap_loop: bool = param(False, "pcap: play the capture again from its start when it ends")

    @field_validator("source")
    @classmethod
    def _an_address(cls, value: str | None) -> str | None:
        if value is not None:
            try:
                return str(ipaddress.ip_address(value))
            except ValueError:
                raise ValueError(f"{value!r} is not an IP address (the sensor's, e.g. 192.168.1.201)") from None
        return value

    calibration: str | None = param(
        None,
        "the unit's calibration (a ROS velodyne_pointcloud YAML file); null: the model's default "
        "calibration shipped with ARES (ares/core/wire/calibrations)",
    )
    rate_hz: float = param(10.0, "rotations per second the sensor is set to", unit="Hz", gt=0)
    fov_deg: tuple[float, float] | None = param(
        None,
        "the field of view the sensor is set to send (its FOV start and end azimuths, Velodyne's: "
        "clockwise from forward): rotations are cut at the start and the hidden arc is no loss "
        "(null: all round, cut at 0°)",
        unit="deg",
    )


class CanDevice(Params):
    """The drive-by-wire board's and the body's CAN bus, through python-can."""

    interface: str = param("socketcan", "python-can interface: socketcan on a vehicle; udp_multicast in simulation")
    channel: str = param("can0", "python-can channel: can0 (socketcan), a multicast group (udp_multicast)")
    port: int | None = param(None, "udp_multicast: the group's UDP port (null: python-can's default)", gt=0, lt=65536)
    dbc: str | None = param(None, "the frames' DBC file; null: the project's (ares/core/wire/ares.dbc)")


class NtripCaster(Params):
    """The NTRIP caster the RTK corrections come from (ARES §3.1: over the vehicle's 4G link)."""

    host: str = param(doc="the caster's host name or address")
    port: int = param(2101, "its port (NTRIP's default: 2101)", gt=0, lt=65536)
    mountpoint: str = param(doc="the mount point (a base station, or a network's VRS stream)", min_length=1)
    user: str | None = param(None, "basic authentication's user (null: none)")
    password: str | None = param(None, "... and password")
    version: Literal[1, 2] = param(2, "NTRIP revision of the request (a rev 1 caster's answer is taken either way)")
    gga_interval_s: float = param(
        10.0, "the receiver's GGA sent upstream this often, for VRS mount points (0: never)", unit="s", ge=0
    )
    connect_timeout_s: float = param(5.0, "connecting and the caster's answer may take this long", unit="s", gt=0)
    silent_after_s: float = param(5.0, "streaming, no byte for this long: the link is gone, reconnect", unit="s", gt=0)
    backoff_min_s: float = param(1.0, "after a failure, wait this long before trying again ...", unit="s", gt=0)
    backoff_max_s: float = param(30.0, "... doubling up to this", unit="s", gt=0)


class VehicleIo(Params):
    """The vehicle's devices, read by the drivers (`ares run --vehicle-io FILE`)."""

    gnss: GnssDevice | None = param(None, "the GNSS receiver (null: none)")
    lidars: dict[str, VelodyneDevice] = param(
        doc="each LiDAR by its name on the vehicle (roof, front_left, front_right)", factory=dict
    )
    can: CanDevice | None = param(None, "the CAN bus of the drive-by-wire board and the body (null: none)")
    ntrip: NtripCaster | None = param(
        None, "the RTK corrections' caster; its RTCM goes to the receiver through the GNSS driver's port (null: none)"
    )
