"""Velodyne LiDAR data packets: decoding, rotation assembly and (for the simulator) encoding.

A Velodyne sends each firing's returns as UDP data packets (port 2368) of 1206 bytes: 12 blocks of
100 bytes — a flag (0xFF 0xEE; the HDL-64E's lower block 0xFF 0xDD), the azimuth in 0.01° and 32
× (distance in 2 mm, intensity byte) — then a timestamp in µs past the UTC hour, a return-mode
byte (0x37 strongest, 0x38 last, 0x39 dual) and a product byte (0x22 VLP-16; the HDL-64E S3 puts
its rotating status bytes there). Distance 0 means no return.

- VLP-16: a block holds two firing sequences of the 16 lasers; only the first carries an
  azimuth. In dual-return mode a pair of blocks (last, then strongest) holds the same firings.
- HDL-64E (S3): an upper block (lasers 0..31) and a lower block (32..63) fire together; in
  dual-return mode blocks i, i+1 (upper, lower) hold the strongest returns and i+2, i+3 the last.

Each laser fires a little after its block's azimuth was read; its azimuth is the block's plus
the packet's rotation rate times that delay, by the firing-time tables of Velodyne's manuals
(VLP-16: 2.304 µs per laser, 55.296 µs per sequence; HDL-64E S3: 7.2 µs per group of four
lasers, 57.6 µs per firing), rounded to 0.01° as the reference decoders (ROS
velodyne_pointcloud, velodyne_decoder) do. A point is then placed by the unit's calibration (the
ROS velodyne_pointcloud YAML format; `load_calibration`) in the sensor frame x forward, y left,
z up, rings numbered from the lowest laser. Decoding is numpy over many packets at once.

`RotationAssembler` cuts the packet stream into rotations at 0° azimuth and counts what goes
wrong (malformed packets by cause, lost packets, truncated rotations, the rotation rate).
`firing_pattern` and `encode_rotation` are the other direction, for the simulator: the rays of
every firing exactly as the decoder will reconstruct them, and the packets of one rotation.
"""

from __future__ import annotations

import struct
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import cache, cached_property
from pathlib import Path

import numpy as np
import yaml

PACKET_SIZE = 1206
BLOCKS = 12
CHANNELS = 32
HOUR_US = 3_600_000_000
RETURN_MODES = {"strongest": 0x37, "last": 0x38, "dual": 0x39}
MODE_NAMES = {code: name for name, code in RETURN_MODES.items()}
# which return a point is (Points.returns)
STRONGEST, LAST, BOTH = 1, 2, 3  # BOTH: in dual mode the strongest return was also the last

CALIBRATION_DIR = Path(__file__).parent / "calibrations"

CHANNEL = np.dtype([("distance", "<u2"), ("intensity", "u1")])
BLOCK = np.dtype([("flag", ">u2"), ("azimuth", "<u2"), ("channels", CHANNEL, (CHANNELS,))])
PACKET = np.dtype([("blocks", BLOCK, (BLOCKS,)), ("timestamp", "<u4"), ("mode", "u1"), ("product", "u1")])
assert PACKET.itemsize == PACKET_SIZE
_HEADER = struct.Struct("<" + "2sH96x" * BLOCKS + "IBB")  # flags and azimuths, timestamp, mode, product

STALL_US = 500_000  # a gap this long is the stream stopping and resuming, not lost packets
GAP_PERIODS = 1.5  # a timestamp or azimuth gap beyond this many packets' worth means packets were lost


# ---- calibration ---------------------------------------------------------------------------------


@dataclass(frozen=True)
class Calibration:
    """One unit's laser corrections (ROS velodyne_pointcloud YAML), per laser id; radians, metres."""

    model: str
    rot_correction: np.ndarray
    vert_correction: np.ndarray
    dist_correction: np.ndarray
    dist_correction_x: np.ndarray
    dist_correction_y: np.ndarray
    vert_offset: np.ndarray
    horiz_offset: np.ndarray
    distance_resolution: float
    path: str

    @property
    def lasers(self) -> int:
        return len(self.vert_correction)

    @cached_property
    def trig(self) -> dict[str, np.ndarray]:
        """Per laser: cos and sin of its rotational and vertical corrections."""
        return {
            "cos_rot": np.cos(self.rot_correction),
            "sin_rot": np.sin(self.rot_correction),
            "cos_vert": np.cos(self.vert_correction),
            "sin_vert": np.sin(self.vert_correction),
        }

    @cached_property
    def ring(self) -> np.ndarray:
        """Each laser's ring: 0 the lowest by vertical angle (a stable sort, as velodyne_decoder)."""
        ring = np.empty(self.lasers, dtype=np.uint8)
        ring[np.argsort(self.vert_correction, kind="stable")] = np.arange(self.lasers, dtype=np.uint8)
        return ring

    @property
    def advanced(self) -> bool:
        """Whether distance or horizontal offset corrections apply (a factory-calibrated HDL-64E)."""
        return bool(
            np.any(self.dist_correction) or np.any(self.dist_correction_x) or np.any(self.dist_correction_y)
        ) or bool(np.any(self.horiz_offset))


def default_calibration_path(model: str) -> Path:
    if model not in MODELS:
        raise ValueError(f"unknown Velodyne model {model!r}: expected one of {', '.join(MODELS)}")
    return CALIBRATION_DIR / f"{model}.yaml"


def load_calibration(model: str, path: str | Path | None = None) -> Calibration:
    """A calibration file in the ROS velodyne_pointcloud format; `path` None: the model's default."""
    path = Path(path) if path is not None else default_calibration_path(model)
    lasers_expected = MODEL_SPECS[model].lasers if model in MODEL_SPECS else 0
    try:
        data = yaml.safe_load(path.read_text())
    except FileNotFoundError:
        raise ValueError(f"no such Velodyne calibration file: {path}") from None
    except yaml.YAMLError as exc:
        raise ValueError(f"{path}: not YAML: {exc}") from None
    lasers = data.get("lasers") if isinstance(data, dict) else None
    if not isinstance(lasers, list):
        raise ValueError(f"{path}: no `lasers` list (expected the ROS velodyne_pointcloud format)")
    n = int(data.get("num_lasers", len(lasers)))
    if n != lasers_expected:
        raise ValueError(f"{path}: {n} lasers, but a {model} has {lasers_expected}")
    columns = {
        key: np.zeros(n)
        for key in (
            "rot_correction",
            "vert_correction",
            "dist_correction",
            "dist_correction_x",
            "dist_correction_y",
            "vert_offset_correction",
            "horiz_offset_correction",
        )
    }
    seen = set()
    for laser in lasers:
        i = int(laser["laser_id"])
        if not 0 <= i < n or i in seen:
            raise ValueError(f"{path}: laser_id {i} out of range or repeated")
        seen.add(i)
        for key, values in columns.items():
            values[i] = float(laser.get(key, 0.0))
    if len(seen) != n:
        raise ValueError(f"{path}: {n} lasers announced, {len(seen)} given")
    return Calibration(
        model=model,
        rot_correction=columns["rot_correction"],
        vert_correction=columns["vert_correction"],
        dist_correction=columns["dist_correction"],
        dist_correction_x=columns["dist_correction_x"],
        dist_correction_y=columns["dist_correction_y"],
        vert_offset=columns["vert_offset_correction"],
        horiz_offset=columns["horiz_offset_correction"],
        distance_resolution=float(data.get("distance_resolution", 0.002)),
        path=str(path),
    )


# ---- the packet layouts ----------------------------------------------------------------------------


@dataclass(frozen=True)
class ModelSpec:
    """What a model's packets look like, from its manual."""

    lasers: int
    product: int | None  # the factory byte a unit of the model writes (None: the HDL-64E's status bytes there)
    banks: int  # blocks that fire together (one per 32 lasers; VLP-16: a block holds two 16-laser sequences)
    cycle_us: float  # one firing sequence, every laser once (the VLS-128's: see VLS128_CHANNEL_US)
    mode_byte: bool  # the return mode is in the packet's mode byte (the HDL-64E: by equal azimuths)


MODEL_SPECS = {
    "VLP-16": ModelSpec(lasers=16, product=0x22, banks=1, cycle_us=55.296, mode_byte=True),
    "HDL-32E": ModelSpec(lasers=32, product=0x21, banks=1, cycle_us=46.080, mode_byte=True),
    "VLP-32C": ModelSpec(lasers=32, product=0x28, banks=1, cycle_us=55.296, mode_byte=True),
    "HDL-64E": ModelSpec(lasers=64, product=None, banks=2, cycle_us=57.6, mode_byte=False),
    "VLS-128": ModelSpec(lasers=128, product=0xA1, banks=4, cycle_us=20 * 8 / 3, mode_byte=True),
}
MODELS: tuple[str, ...] = tuple(MODEL_SPECS)
# factory bytes seen in the field and the model each names (the manuals' table; Puck LITE sends 0x22 too)
PRODUCT_NAMES = {0x21: "HDL-32E", 0x22: "VLP-16", 0x23: "VLP-32A/B", 0x24: "Puck Hi-Res", 0x28: "VLP-32C"}
PRODUCT_NAMES |= {0x31: "Velarray", 0xA1: "VLS-128"}
BANK_FLAGS = (0xFFEE, 0xFFDD, 0xFFCC, 0xFFBB)  # lasers 0..31, 32..63, 64..95, 96..127
# The VLS-128 fires a group of 8 lasers per channel slot, 20 slots a sequence: 8/3 µs a slot up to
# firmware 5.1 (manual rev 3), 2.89 µs since 5.2 (rev 4). Which one a stream uses shows in its
# packet period (3 sequences a packet): under VLS128_PERIOD_SPLIT_US, the older.
VLS128_CHANNEL_US = (8 / 3, 2.89)
VLS128_PERIOD_SPLIT_US = 167.0
VLS128_TOH_US = 7.0  # its packet's timestamp is the fourth group's firing, not the first's


@dataclass(frozen=True)
class Layout:
    """Where one model's returns sit in a packet, in one return mode. Index arrays are (S, 32):
    S source blocks (12, or fewer in dual mode) by 32 channels."""

    model: str
    dual: bool
    block: np.ndarray  # (S,) the block holding the (strongest or only) return
    other: np.ndarray | None  # (S,) dual: the block of the last return (`block`: the strongest)
    bank: np.ndarray  # (12,) which 32 lasers each block carries (its flag: BANK_FLAGS[bank]); -1: unused
    time_s: np.ndarray  # (S, 32) float32: each channel's firing time after the packet's timestamp
    dt_s: np.ndarray  # (S, 32) float32: ... after its own block's azimuth was read
    duration_s: np.float32  # from block 0's azimuth to the last used block's (0: one firing a packet)
    firing: np.ndarray  # (S, 32) the firing (a sequence of every laser) within the packet
    laser_in_block: np.ndarray  # (S, 32) laser id, before the bank's offset (32 × bank)
    firings_per_packet: int
    last_block_firing: int  # the firing the last used block's azimuth belongs to
    last_block: int  # the last block that carries data (11, or 7 for the VLS-128 in dual mode)
    rate_between_packets: bool  # the rotation rate from packet to packet (the VLS-128), not within one
    step_pairs: tuple[
        np.ndarray, np.ndarray, np.ndarray
    ]  # (block a, block b, firings between): consecutive firings' blocks
    cycle_us: float  # one firing (all lasers once)


FIRING_CYCLE_US = {model: spec.cycle_us for model, spec in MODEL_SPECS.items()}
_HDL64_PATTERN = (0.0, 1.3, 2.5, 3.7)


def _timing(model: str, channel_us: float) -> np.ndarray:
    """(12, 32) float32 seconds: each (block, channel)'s firing time in single-return mode after
    the packet's timestamp, by the manuals' firing-time tables, computed as velodyne_decoder does
    (double, then float32)."""
    timing = np.empty((BLOCKS, CHANNELS), dtype=np.float32)
    for i in range(BLOCKS):
        for c in range(CHANNELS):
            if model == "VLP-16":  # 2.304 µs a laser, two 16-laser sequences a block
                us = 55.296 * (2 * i + c // 16) + 2.304 * (c % 16)
            elif model == "HDL-32E":  # 1.152 µs a laser, 46.08 µs a sequence
                us = 46.080 * i + 1.152 * c
            elif model == "VLP-32C":  # two lasers at once, 2.304 µs a pair
                us = 55.296 * i + 2.304 * (c // 2)
            elif model == "HDL-64E":  # S3: groups of four lasers, upper and lower blocks together
                us = 57.6 * (i // 2) + 7.2 * (c // 4) + _HDL64_PATTERN[c % 4]
            else:  # VLS-128: 8 lasers a slot, a pause of 2 slots after 64, 20 slots a sequence
                dsr = 32 * (i % 4) + c
                us = (i // 4) * 20 * channel_us + (dsr // 8 + dsr // 64 * 2) * channel_us - VLS128_TOH_US
            timing[i, c] = us * 1e-6
    return timing


@cache
def layout(model: str, dual: bool, channel_us: float = VLS128_CHANNEL_US[0]) -> Layout:
    """The model's layout; `channel_us`: the VLS-128's channel slot (see VLS128_CHANNEL_US)."""
    if model not in MODEL_SPECS:
        raise ValueError(f"unknown Velodyne model {model!r}: expected one of {', '.join(MODELS)}")
    spec = MODEL_SPECS[model]
    j = np.arange(CHANNELS)
    timing = _timing(model, channel_us)
    sequences = BLOCKS // spec.banks  # firings a packet holds in single-return mode (VLP-16: twice that)
    bank = np.arange(BLOCKS) % spec.banks
    if not dual:
        block, other, rows = np.arange(BLOCKS), None, np.arange(BLOCKS)
        firing_of_block = block // spec.banks
    elif spec.banks == 1:  # pairs (last, strongest): pair k is single mode's block k
        block = np.arange(1, BLOCKS, 2)
        other = block - 1
        rows = block // 2
        firing_of_block = rows
    elif model == "HDL-64E":  # (upper, lower) strongest, then (upper, lower) last, per firing
        block = np.array([i for i in range(BLOCKS) if i % 4 < 2])
        other = block + 2
        rows = (block // 4) * 2 + block % 2
        firing_of_block = block // 4
        bank = np.arange(BLOCKS) % 2
    else:  # VLS-128: one sequence, pairs (last, strongest) bank by bank; blocks 8..11 carry nothing
        block = np.arange(1, 8, 2)
        other = block - 1
        rows = block // 2
        firing_of_block = np.zeros(len(block), dtype=int)
        bank = np.array([k // 2 for k in range(8)] + [-1] * 4)
    time = timing[rows]
    read = timing[rows // spec.banks * spec.banks, 0] if model != "VLP-16" else timing[rows, 0]
    if model == "VLP-16":
        firing = 2 * firing_of_block[:, None] + j[None, :] // 16
        laser = np.broadcast_to(j % 16, time.shape)
        per_packet = 2 * sequences if not dual else sequences
    else:
        firing = np.broadcast_to(firing_of_block[:, None], (len(block), CHANNELS))
        laser = np.broadcast_to(j, time.shape)
        per_packet = sequences if not dual else max(sequences // 2, 1)
    used = np.flatnonzero(bank >= 0)
    last_block = int(used[-1])
    last_source = int(np.flatnonzero((block == last_block) | (other == last_block if other is not None else False))[0])
    last_firing = int(firing[last_source, 0])
    duration = np.float32(read[last_source] - read[0])
    cycle = 20 * channel_us if model == "VLS-128" else spec.cycle_us
    return Layout(
        model=model,
        dual=dual,
        block=block,
        other=other,
        bank=bank,
        time_s=time,
        dt_s=(time - read[:, None]).astype(np.float32),
        duration_s=duration,
        firing=np.ascontiguousarray(firing),
        laser_in_block=np.ascontiguousarray(laser),
        firings_per_packet=per_packet,
        last_block_firing=last_firing,
        last_block=last_block,
        rate_between_packets=model == "VLS-128",
        step_pairs=_step_pairs(block, firing[:, 0]),
        cycle_us=cycle,
    )


def _step_pairs(block: np.ndarray, firing: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Blocks of consecutive firings (one block each) and the firings between them."""
    first_of: dict[int, int] = {}
    for b, f in zip(block.tolist(), firing.tolist(), strict=True):
        first_of.setdefault(f, b)
    fired = sorted(first_of)
    a = np.array([first_of[f] for f in fired[:-1]], dtype=np.int64)
    b = np.array([first_of[f] for f in fired[1:]], dtype=np.int64)
    return a, b, np.diff(np.array(fired, dtype=np.int64))


def vls128_channel_us(packet_period_us: float | None) -> float:
    """The VLS-128's channel slot from its single-return packet period (None: the newer firmware's,
    as velodyne_decoder assumes before it has seen two packets)."""
    if packet_period_us is None:
        return VLS128_CHANNEL_US[1]
    return VLS128_CHANNEL_US[0] if packet_period_us < VLS128_PERIOD_SPLIT_US else VLS128_CHANNEL_US[1]


def packet_period_us(model: str, dual: bool) -> float:
    """The nominal time from one packet to the next (the manual's firing cycle)."""
    lay = layout(model, dual)
    return lay.firings_per_packet * lay.cycle_us


def rotation_rates(lay: Layout, block_azimuth: np.ndarray, timestamps_us: np.ndarray) -> np.ndarray:
    """(P,) float32 each packet's rotation rate in 0.01° per second, as velodyne_decoder computes it:
    from its first block's azimuth to its last used block's over the firing time between them; for
    the VLS-128, from the packet before (its first packet: to the next) over the packets' firing
    time (as many packet periods as the timestamps say passed: a lost packet is not a faster turn)."""
    az = block_azimuth.astype(np.int64)
    if not lay.rate_between_packets:
        rate: np.ndarray = ((az[:, lay.last_block] - az[:, 0]) % 36000).astype(np.float32) / lay.duration_s
        jumped = _jumped(lay, az)
        if jumped.any():  # a packet across a field of view's hidden arc: the rate of its firings
            rate[jumped] = (_median_step(lay, az[jumped]) / (lay.cycle_us * 1e-6)).astype(np.float32)
        return rate
    if len(az) < 2:
        return np.zeros(len(az), dtype=np.float32)
    period_us = lay.firings_per_packet * lay.cycle_us
    gaps_us: np.ndarray = np.mod(np.diff(timestamps_us.astype(np.int64)), HOUR_US)
    periods = np.maximum(np.round(gaps_us / period_us), 1)
    step = (np.diff(az[:, 0]) % 36000).astype(np.float32)
    between = (step / (periods * period_us * 1e-6)).astype(np.float32)
    return np.concatenate([between[:1], between]).astype(np.float32)


def _block_steps(lay: Layout, az: np.ndarray) -> np.ndarray:
    """(P, pairs) 0.01° per firing between the blocks of consecutive firings."""
    a, b, between = lay.step_pairs
    steps: np.ndarray = ((az[:, b] - az[:, a]) % 36000) / between
    return steps


def _median_step(lay: Layout, az: np.ndarray) -> np.ndarray:
    median: np.ndarray = np.median(_block_steps(lay, az), axis=1)
    return median


def _jumped(lay: Layout, az: np.ndarray) -> np.ndarray:
    """(P,) packets whose blocks jump (a step over twice their median): a field of view's end."""
    if len(lay.step_pairs[0]) < 2:
        return np.zeros(len(az), dtype=bool)
    steps = _block_steps(lay, az)
    jumped: np.ndarray = (steps > 2 * np.median(steps, axis=1)[:, None] + 1).any(axis=1)
    return jumped


def point_azimuth(lay: Layout, block_azimuth: np.ndarray, rate: np.ndarray) -> np.ndarray:
    """(P, S, 32) each return's azimuth in 0.01°, from the packets' (P, 12) block azimuths: the
    block's azimuth plus the packet's rotation rate (`rotation_rates`) times the laser's delay,
    rounded, in float32 exactly as velodyne_decoder computes it (so both decoders agree to the bit)."""
    base = block_azimuth[:, lay.block].astype(np.float32)
    value = base[:, :, None] + rate[:, None, None] * lay.dt_s[None]
    value = value + np.float32(36000)  # float32, as the reference does before rounding
    rounded: np.ndarray = (np.floor(value.astype(np.float64) + 0.5).astype(np.int64) % 36000).astype(np.int32)
    return rounded


# ---- decoding ----------------------------------------------------------------------------------------


@dataclass
class Points:
    """Decoded returns, one entry per point (sensor frame: x forward, y left, z up; metres)."""

    x: np.ndarray  # float32
    y: np.ndarray
    z: np.ndarray
    intensity: np.ndarray  # float32, 0..1 (the byte / 255)
    ring: np.ndarray  # uint8, 0 = the lowest laser
    laser: np.ndarray  # uint8, the laser id of the calibration
    azimuth: np.ndarray  # float32, degrees (Velodyne's: clockwise seen from above, 0 = forward)
    returns: np.ndarray  # uint8: STRONGEST, LAST or BOTH
    time: np.ndarray  # float32, seconds after the first packet's timestamp
    firing: np.ndarray  # int32, the firing's index among the decoded packets' firings

    @property
    def size(self) -> int:
        return len(self.x)

    @classmethod
    def empty(cls) -> Points:
        f, u = np.zeros(0, np.float32), np.zeros(0, np.uint8)
        return cls(f, f, f, f, u, u, f, u, f, np.zeros(0, np.int32))


@cache
def _trig_table() -> tuple[np.ndarray, np.ndarray]:
    angle = np.radians(np.arange(36000) / 100.0)
    return np.cos(angle), np.sin(angle)


def is_dual(model: str, packet: np.ndarray) -> np.ndarray:
    """Per packet: dual-return mode (its mode byte; the HDL-64E's: equal azimuths in blocks 0, 2)."""
    if MODEL_SPECS[model].mode_byte:
        dual: np.ndarray = packet["mode"] == RETURN_MODES["dual"]
        return dual
    az = packet["blocks"]["azimuth"]
    same: np.ndarray = az[:, 0] == az[:, 2]
    return same


def decode_layout(model: str, dual: bool, timestamps_us: np.ndarray) -> Layout:
    """The layout packets decode by: the VLS-128's channel slot told from their period."""
    if model != "VLS-128":
        return layout(model, dual)
    period = None
    if len(timestamps_us) > 1:
        gaps_us: np.ndarray = np.mod(np.diff(timestamps_us.astype(np.int64)), HOUR_US)
        period = float(np.median(gaps_us)) * (3 if dual else 1)
    return layout(model, dual, vls128_channel_us(period))


def decode(calibration: Calibration, payloads: Sequence[bytes] | bytes) -> Points:
    """The points of whole, valid packets (all in one return mode; see RotationAssembler, which
    checks them). `payloads`: the packets, or their bytes joined."""
    data = payloads if isinstance(payloads, (bytes, bytearray, memoryview)) else b"".join(payloads)
    packet = np.frombuffer(data, dtype=PACKET)
    if len(packet) == 0:
        return Points.empty()
    model = calibration.model
    dual = is_dual(model, packet)
    if dual.any() != dual.all():
        raise ValueError("packets in more than one return mode: decode them separately")
    stamp = packet["timestamp"].astype(np.int64)
    lay = decode_layout(model, bool(dual[0]), stamp)
    raw = np.frombuffer(data, dtype=np.uint8).reshape(len(packet), PACKET_SIZE)
    per_packet = lay.time_s.size  # S × 32 source positions

    # the measurements by byte offsets: a gather from contiguous bytes beats the 3-byte records
    def offsets_of(blocks: np.ndarray) -> np.ndarray:
        return (BLOCK.itemsize * blocks[:, None] + 4 + CHANNEL.itemsize * np.arange(CHANNELS)).ravel()

    # where each measurement's bytes are: [the strongest (or only) return, the last (dual)]
    where = [offsets_of(lay.block)] + ([offsets_of(lay.other)] if lay.other is not None else [])
    # a gather from contiguous bytes: much faster than reading the 3-byte records' fields
    distances = [raw[:, w].astype(np.uint16) | (raw[:, w + 1].astype(np.uint16) << 8) for w in where]
    if not lay.dual:
        mode = int(packet["mode"][0]) if MODEL_SPECS[model].mode_byte else RETURN_MODES["strongest"]
        picks = [(np.flatnonzero(distances[0]), 0, LAST if mode == RETURN_MODES["last"] else STRONGEST)]
    else:
        strongest, last = distances
        same = strongest == last
        both = np.flatnonzero((strongest > 0) & same)
        picks = [
            (both, 0, BOTH),
            (np.flatnonzero((strongest > 0) & ~same), 0, STRONGEST),
            (np.flatnonzero((last > 0) & ~same), 1, LAST),
        ]
    index = np.concatenate([i for i, _, _ in picks])
    source = np.concatenate([np.full(len(i), c, np.uint8) for i, c, _ in picks])
    kind = np.concatenate([np.full(len(i), k, np.uint8) for i, _, k in picks])
    p, sj = np.divmod(index, per_packet)
    raw_distance = np.where(source == 0, distances[0].ravel()[index], distances[-1].ravel()[index])
    offsets = np.where(source == 0, where[0][sj], where[-1][sj])
    intensity = raw[p, offsets + 2]
    # each return's azimuth (0.01°), only for the returns kept
    block_azimuth = packet["blocks"]["azimuth"]
    rate = rotation_rates(lay, block_azimuth, stamp)
    s_index = sj // CHANNELS
    base = block_azimuth[p, lay.block[s_index]].astype(np.float32)
    value = base + rate[p] * lay.dt_s.ravel()[sj] + np.float32(36000)
    azimuth = (np.floor(value.astype(np.float64) + 0.5).astype(np.int64) % 36000).astype(np.int32)
    laser = lay.laser_in_block.ravel()[sj]
    if MODEL_SPECS[model].banks > 1:  # the bank the block's flag names (0xFF 0xEE, 0xDD, 0xCC, 0xBB)
        flag_low = raw[p, BLOCK.itemsize * lay.block[s_index] + 1]
        laser = laser + 32 * ((0xEE - flag_low.astype(np.int64)) // 0x11)
    since_first = ((stamp - stamp[0]) % HOUR_US).astype(np.float64) * 1e-6
    x, y, z = _place(calibration, raw_distance, azimuth, laser)
    return Points(
        x=x,
        y=y,
        z=z,
        intensity=intensity.astype(np.float32) / np.float32(255.0),
        ring=calibration.ring[laser],
        laser=laser.astype(np.uint8),
        azimuth=azimuth.astype(np.float32) / np.float32(100.0),
        returns=kind,
        time=(since_first[p] + lay.time_s.ravel()[sj]).astype(np.float32),
        firing=(p * lay.firings_per_packet + lay.firing.ravel()[sj]).astype(np.int32),
    )


def _place(
    cal: Calibration, raw: np.ndarray, azimuth: np.ndarray, laser: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points from raw distances, azimuths (0.01°) and laser ids by the calibration, in the ROS
    frame (x forward, y left, z up): Velodyne's azimuth turns clockwise, hence y = -sin."""
    cos_t, sin_t = _trig_table()
    # cos/sin(azimuth - rot_correction) from the table of the 36000 azimuths and the laser's
    ca, sa = cos_t[azimuth], sin_t[azimuth]
    cr, sr = cal.trig["cos_rot"][laser], cal.trig["sin_rot"][laser]
    cos_rot, sin_rot = ca * cr + sa * sr, sa * cr - ca * sr
    cos_v, sin_v = cal.trig["cos_vert"][laser], cal.trig["sin_vert"][laser]
    d = raw * cal.distance_resolution
    if not cal.advanced:
        xy = d * cos_v
        x, y, z = xy * cos_rot, -xy * sin_rot, d * sin_v + cal.vert_offset[laser]
    else:
        # the HDL-64E S3 manual's corrections, as velodyne_decoder applies them
        dc = cal.dist_correction[laser]
        dcx, dcy, dcz = dc, dc, dc
        two_point = (cal.dist_correction_x[laser] != 0) & (cal.dist_correction_y[laser] != 0) & (d < 25.04)
        if two_point.any():
            xy = (d + dc) * cos_v
            x_coeff = (np.abs(xy * sin_rot) - 2.40) / (25.04 - 2.40)
            y_coeff = (np.abs(xy * cos_rot) - 1.93) / (25.04 - 1.93)
            cx = x_coeff * dc + (1 - x_coeff) * cal.dist_correction_x[laser]
            cy = y_coeff * dc + (1 - y_coeff) * cal.dist_correction_y[laser]
            dcx = np.where(two_point, cx, dc)
            dcy = np.where(two_point, cy, dc)
            dcz = np.where(two_point, (cx + cy) / 2, dc)
        horiz = cal.horiz_offset[laser]
        right = (d + dcx) * cos_v * sin_rot - horiz * cos_rot  # the manual's x: to the right
        forward = (d + dcy) * cos_v * cos_rot + horiz * sin_rot
        x, y, z = forward, -right, (d + dcz) * sin_v + cal.vert_offset[laser]
    return x.astype(np.float32), y.astype(np.float32), z.astype(np.float32)


# ---- checking and assembling ---------------------------------------------------------------------


@dataclass(frozen=True)
class PacketHeader:
    timestamp_us: int
    first_azimuth: int  # block 0's, 0.01°
    last_azimuth: int  # the last used block's
    dual: bool
    mode: int
    product: int  # the factory byte as sent (the HDL-64E: a status byte)
    azimuths: tuple[int, ...]  # every block's, 0.01°


def check_packet(model: str, payload: bytes) -> tuple[PacketHeader | None, str, str]:
    """(header, "", "") for a well-formed packet, else (None, cause, detail).

    The configured model decides the layout: a factory byte that names another model is the
    caller's to report (`factory_mismatch`), not a reason to refuse (early units write bytes the
    manuals do not list). An azimuth of 36000, which real units write now and then, is 0°."""
    if len(payload) != PACKET_SIZE:
        return None, "wrong size", f"{len(payload)} bytes, expected {PACKET_SIZE}"
    spec = MODEL_SPECS[model]
    fields = _HEADER.unpack_from(payload)
    flags, azimuths = fields[0 : 2 * BLOCKS : 2], fields[1 : 2 * BLOCKS : 2]
    timestamp, mode, product = fields[2 * BLOCKS :]
    allowed = {flag.to_bytes(2, "big") for flag in BANK_FLAGS[: spec.banks]}
    dual = mode == RETURN_MODES["dual"] if spec.mode_byte else azimuths[0] == azimuths[2]
    used = BLOCKS if not (dual and model == "VLS-128") else 8  # its dual packets fill 8 blocks
    for i, flag in enumerate(flags[:used]):
        if flag not in allowed:
            return None, "bad block flag", f"block {i}: {flag.hex()}"
    if max(azimuths[:used]) > 36000:
        return None, "azimuth > 36000", f"azimuth {max(azimuths[:used])}"
    if timestamp >= HOUR_US:
        return None, "timestamp past the hour", f"{timestamp} µs"
    if spec.mode_byte:
        if mode not in MODE_NAMES:
            if model != "HDL-32E":
                return None, "unknown return mode", f"0x{mode:02x}"
            mode = RETURN_MODES["strongest"]  # HDL-32E firmware before 2.2.20 leaves the byte unset
    else:
        mode = RETURN_MODES["dual"] if dual else RETURN_MODES["strongest"]
    first, last = azimuths[0] % 36000, azimuths[used - 1] % 36000
    return PacketHeader(timestamp, first, last, dual, mode, product, azimuths), "", ""


def factory_mismatch(model: str, product: int) -> str | None:
    """What to report when a packet's factory byte names another model than the configured one."""
    expected = MODEL_SPECS[model].product
    if expected is None or product == expected:
        return None
    if model == "VLP-16" and product == 0x24:  # the Puck Hi-Res: a VLP-16 with other angles
        said = "Puck Hi-Res (check the calibration: its vertical angles differ)"
    else:
        said = PRODUCT_NAMES.get(product, "no model we know")
    return f"factory byte 0x{product:02x} says {said}; decoding as the configured {model}"


@dataclass
class Rotation:
    """One rotation's packets, decoded."""

    points: Points
    timestamp_us: int  # the first packet's timestamp (µs past the hour)
    first_wall: float  # wall receive time of its first packet
    last_wall: float  # ... of its last
    packets: int
    coverage_deg: float  # azimuth from its first firing to past its last
    rate_hz: float | None  # from the packets' timestamps and azimuths (None: a single packet)
    return_mode: str
    truncated: bool


@dataclass
class _Pending:
    payloads: list[bytes] = field(default_factory=list)
    first: PacketHeader | None = None
    last: PacketHeader | None = None
    first_wall: float = 0.0
    last_wall: float = 0.0
    swept: float = 0.0  # 0.01° from the first packet's block 0 to the last packet's block 0
    step: float = 0.0  # 0.01° per firing, from the latest packet


class RotationAssembler:
    """One sensor's packets in, finished rotations out, with the counts of what went wrong.

    Rotations are whole packets: one ends after the packet at whose end the next packet would
    cross 0° azimuth (so a rotation is out without waiting for the next packet), or at a wrap
    of the azimuth, a change of return mode or a stall of the stream. Lost packets are told by
    gaps in the timestamps or the azimuths beyond 1.5 packets' worth. A sensor whose azimuth
    stops advancing (a stuck motor, an encoder fault) never crosses 0°: a rotation is also cut
    once it holds `stall_factor` times the packets a rotation at `rate_hz` has in dual mode and has
    swept less than half a turn (or four times that many packets, whatever it swept), so memory
    stays bounded; such a cut is counted in `azimuth_stalls` (and comes out truncated). A sensor
    turning slower than configured is not cut: its rate is reported.

    `notices` holds (cause, text) the driver should report once: a factory byte that names another
    model than the configured one (counted per byte in `factory_bytes`), an azimuth stall."""

    def __init__(
        self,
        calibration: Calibration,
        rate_hz: float,
        truncated_below_deg: float = 300.0,
        stall_factor: float = 2.5,
        fov_deg: tuple[float, float] | None = None,
    ):
        self.calibration = calibration
        self.model = calibration.model
        self.rate_hz = rate_hz
        # a sensor set to a field of view sends packets from its start to its end azimuth only:
        # rotations are cut at the start, the arc it hides is no loss, and "whole" is of the view
        self.cut = round(fov_deg[0] * 100) % 36000 if fov_deg is not None else 0
        self.hidden = (self.cut - round(fov_deg[1] * 100)) % 36000 if fov_deg is not None else 0
        self.truncated_below_deg = truncated_below_deg * (36000 - self.hidden) / 36000
        self.max_packets = max(2, int(np.ceil(stall_factor * 1e6 / (rate_hz * packet_period_us(self.model, True)))))
        self.factory_bytes: Counter[int] = Counter()  # factory bytes that disagree with the model
        self.azimuth_stalls = 0
        self.notices: list[tuple[str, str]] = []
        self._stalled = False
        self.packets = 0
        self.lost = 0
        self.malformed: Counter[str] = Counter()
        self.refused: list[tuple[str, str]] = []  # (cause, detail) not yet taken by the driver
        self.rotations = 0
        self.truncated = 0
        self.stalls = 0
        self.measured_rate_hz: float | None = None
        self._pending = _Pending()
        self._previous: PacketHeader | None = None
        self._previous_step = 0.0

    def add(self, payload: bytes, received_wall: float) -> list[Rotation]:
        """One packet as received (its bytes and the wall time it arrived): the rotations it finishes."""
        self.packets += 1
        header = self._checked(payload)
        if header is None:
            return []
        lay = layout(self.model, header.dual)
        step = self._azimuth_step(header, lay)
        done = self._count_gap(header)
        done += self._hold(payload, header, received_wall, step)
        pending = self._pending
        held = len(pending.payloads)
        if (held >= self.max_packets and pending.swept < 18000) or held >= 4 * self.max_packets:
            # the azimuth is not turning (not half a turn in 2.5 rotations' packets): cut, bounded
            self.azimuth_stalls += 1
            if not self._stalled:
                self.notices.append(("azimuth stalled", f"azimuth stalled: {self.max_packets} packets without a turn"))
            self._stalled = True
            self._previous, self._previous_step = header, step
            return done + self._finish()
        self._previous, self._previous_step = header, step
        if self._closes_rotation(header, lay, step, held):
            done += self._finish()
        return done

    def _checked(self, payload: bytes) -> PacketHeader | None:
        """The packet's header, or None (counted and kept for the driver) for a malformed packet; a
        factory byte that disagrees with the model is noted once and counted."""
        header, cause, detail = check_packet(self.model, payload)
        if header is None:
            self.malformed[cause] += 1
            self.refused.append((cause, detail))
            return None
        mismatch = factory_mismatch(self.model, header.product)
        if mismatch is not None:
            if header.product not in self.factory_bytes:
                self.notices.append((f"factory byte 0x{header.product:02x}", mismatch))
            self.factory_bytes[header.product] += 1
        return header

    def _azimuth_step(self, header: PacketHeader, lay: Layout) -> float:
        """The azimuth advance per firing (0.01°), from inside the packet or from the last one."""
        previous = self._previous
        if lay.last_block_firing > 0:
            step = ((header.last_azimuth - header.first_azimuth) % 36000) / lay.last_block_firing
            if step > 2 * self._previous_step + 1 > 1:  # a jump inside: a field of view's end
                a, b, between = lay.step_pairs
                az = header.azimuths
                step = float(np.median([(az[j] - az[i]) % 36000 / n for i, j, n in zip(a, b, between, strict=True)]))
            return step
        if previous is not None and previous.dual == header.dual:  # one firing a packet: from the last
            step = ((header.first_azimuth - previous.first_azimuth) % 36000) / lay.firings_per_packet
            if step > 2 * self._previous_step > 0:  # a lost packet's gap: keep the rate we had
                step = self._previous_step
            return step
        return self._previous_step

    def _count_gap(self, header: PacketHeader) -> list[Rotation]:
        """Since the last packet: a stall (the rotation under way finished, returned) or the packets
        lost, by time and by azimuth, whichever says more."""
        previous = self._previous
        if previous is None:
            return []
        dt: float = (header.timestamp_us - previous.timestamp_us) % HOUR_US
        if dt >= STALL_US:
            self.stalls += 1
            return self._finish()
        period = packet_period_us(self.model, header.dual)
        gap_azimuth: float = (header.first_azimuth - previous.first_azimuth) % 36000
        if self.hidden and self._relative(header.first_azimuth) < self._relative(previous.first_azimuth):
            # across the hidden arc: the time and azimuth it takes are no loss, nor is the
            # packet's worth its edges can fall short by (the view ends and starts mid-packet)
            previous_lay = layout(self.model, previous.dual)
            per_us = self._previous_step / previous_lay.cycle_us
            span_before = self._previous_step * previous_lay.firings_per_packet
            gap_azimuth = max(gap_azimuth - self.hidden - span_before, 0)
            dt = max(dt - (self.hidden / per_us if per_us > 0 else dt) - period, 0)
        lost_time = round(dt / period) - 1 if dt > GAP_PERIODS * period else 0
        expected = self._previous_step * layout(self.model, previous.dual).firings_per_packet
        lost_azimuth = round(gap_azimuth / expected) - 1 if expected > 0 and gap_azimuth > GAP_PERIODS * expected else 0
        self.lost += max(lost_time, lost_azimuth, 0)
        return []

    def _hold(self, payload: bytes, header: PacketHeader, received_wall: float, step: float) -> list[Rotation]:
        """The packet added to the rotation under way, after finishing that one (returned) if the
        azimuth wrapped between packets or the mode changed."""
        done: list[Rotation] = []
        pending = self._pending
        if pending.last is not None:
            last = pending.last
            end_of_last = (
                self._relative(last.first_azimuth)
                + pending.step * (layout(self.model, last.dual).firings_per_packet - 1)
            ) % 36000
            if header.dual != last.dual or self._relative(header.first_azimuth) < end_of_last:
                done += self._finish()
                pending = self._pending
        if pending.first is None:
            pending.first, pending.first_wall = header, received_wall
        else:
            assert pending.last is not None  # set with `first`
            pending.swept += (header.first_azimuth - pending.last.first_azimuth) % 36000
        pending.payloads.append(payload)
        pending.last, pending.last_wall, pending.step = header, received_wall, step
        return done

    def _closes_rotation(self, header: PacketHeader, lay: Layout, step: float, held: int) -> bool:
        """Whether this packet ends the rotation: its own firings wrap past the cut (and it is not
        alone), or the next packet would start past the cut (or past the field of view's end)."""
        span = step * lay.firings_per_packet  # this packet's azimuth advance to the next
        end = self._relative(header.first_azimuth) + step * (lay.firings_per_packet - 1)  # unwrapped
        wrapped_inside = end >= 36000
        if self.hidden:  # a field of view: the last packet is the last to start inside it
            closes = self._relative(header.first_azimuth) + span >= 36000 - self.hidden
        else:  # all round: the next packet would cross the cut
            closes = end + span >= 36000
        return (wrapped_inside and held > 1) or (not wrapped_inside and closes)

    def _relative(self, azimuth: int) -> int:
        """An azimuth from the cut (0°, or the start of the field of view), 0.01°."""
        return (azimuth - self.cut) % 36000

    def flush(self) -> list[Rotation]:
        """The rotation under way, finished as it is (the stream stopped)."""
        return self._finish()

    def _finish(self) -> list[Rotation]:
        pending = self._pending
        self._pending = _Pending()
        if not pending.payloads or pending.first is None or pending.last is None:
            return []
        lay = layout(self.model, pending.last.dual)
        coverage = (pending.swept + pending.step * lay.firings_per_packet) / 100.0
        rate = None
        elapsed_us = (pending.last.timestamp_us - pending.first.timestamp_us) % HOUR_US
        if len(pending.payloads) > 1 and elapsed_us > 0:
            rate = pending.swept / 100.0 / 360.0 / (elapsed_us * 1e-6)
            self.measured_rate_hz = rate
        truncated = coverage < self.truncated_below_deg
        if not truncated:
            self._stalled = False
        self.rotations += 1
        self.truncated += truncated
        return [
            Rotation(
                points=decode(self.calibration, pending.payloads),
                timestamp_us=pending.first.timestamp_us,
                first_wall=pending.first_wall,
                last_wall=pending.last_wall,
                packets=len(pending.payloads),
                coverage_deg=coverage,
                rate_hz=rate,
                return_mode=MODE_NAMES[pending.last.mode],
                truncated=truncated,
            )
        ]


# ---- encoding (the simulator's side) --------------------------------------------------------------


@dataclass(frozen=True)
class FiringPattern:
    """Every firing of one rotation as the packets will carry it, and each (firing, laser) ray
    exactly as the decoder reconstructs it."""

    model: str
    return_mode: str
    rate_hz: float
    packets: int
    firings_per_packet: int
    packet_period_us: float  # the rotation spans packets × this, 1 / rate_hz
    block_azimuth: np.ndarray  # (packets, 12) uint16, 0.01°
    azimuth_cdeg: np.ndarray  # (firings, lasers) int32: each ray's azimuth, 0.01°
    directions: np.ndarray  # (firings, lasers, 3) float32 unit vectors in the sensor frame
    ring: np.ndarray  # (lasers,) uint8
    _slot_block: np.ndarray  # (packets, S, 32) int: block of each source position
    _slot_firing: np.ndarray  # (packets, S, 32) firing of each source position
    _slot_laser: np.ndarray  # (packets, S, 32) laser of each source position

    @property
    def firings(self) -> int:
        return len(self.azimuth_cdeg)

    @property
    def lasers(self) -> int:
        return int(self.azimuth_cdeg.shape[1])

    def timestamps_us(self, first_us: int) -> np.ndarray:
        """The packets' timestamps when the first packet's is `first_us` (µs past the hour)."""
        return (first_us + np.round(np.arange(self.packets) * self.packet_period_us).astype(np.int64)) % HOUR_US


def firing_pattern(
    calibration: Calibration, rate_hz: float, return_mode: str = "strongest", phase_deg: float = 0.0
) -> FiringPattern:
    """One rotation at `rate_hz` from `phase_deg`: a whole number of packets, the firings evenly
    spread over 360° (the firing clock is stretched by under 1 % from the manual's cycle so that
    a rotation is whole packets: one simulated sweep is one rotation)."""
    if return_mode not in RETURN_MODES:
        raise ValueError(f"unknown return mode {return_mode!r}: expected one of {', '.join(RETURN_MODES)}")
    model = calibration.model
    dual = return_mode == "dual"
    lay = layout(model, dual)
    single = layout(model, False)
    packets_single = max(1, round(1e6 / (rate_hz * single.firings_per_packet * single.cycle_us)))
    firings = packets_single * single.firings_per_packet
    packets = firings // lay.firings_per_packet
    step = 36000.0 / firings
    firing_az = (phase_deg * 100.0 + np.arange(firings) * step) % 36000.0
    # the firing each block's azimuth is read at
    of_block = np.zeros(BLOCKS, dtype=int)
    of_block[lay.block] = lay.firing[:, 0]
    if lay.other is not None:
        of_block[lay.other] = lay.firing[:, 0]
    block_az = (
        np.round(firing_az[np.arange(packets)[:, None] * lay.firings_per_packet + of_block[None]]).astype(np.int64)
        % 36000
    )
    block_az = block_az.astype(np.uint16)
    period_us = 1e6 / rate_hz / packets
    stamps = np.round(np.arange(packets) * period_us).astype(np.int64)
    azimuth = point_azimuth(lay, block_az, rotation_rates(lay, block_az, stamps))  # (P, S, 32)
    shape = azimuth.shape
    slot_block = np.broadcast_to(lay.block[None, :, None], shape)
    slot_firing = np.arange(packets)[:, None, None] * lay.firings_per_packet + lay.firing[None]
    slot_laser = np.broadcast_to(lay.laser_in_block, shape)
    slot_laser = slot_laser + 32 * lay.bank[slot_block]  # the encoder's blocks: bank by bank
    az_cdeg = np.zeros((firings, calibration.lasers), dtype=np.int32)
    az_cdeg[slot_firing, slot_laser] = azimuth
    cos_t, sin_t = _trig_table()
    rot = calibration.rot_correction[None, :]
    ca, sa = cos_t[az_cdeg], sin_t[az_cdeg]
    cos_rot = ca * np.cos(rot) + sa * np.sin(rot)
    sin_rot = sa * np.cos(rot) - ca * np.sin(rot)
    cv, sv = np.cos(calibration.vert_correction)[None, :], np.sin(calibration.vert_correction)[None, :]
    directions = np.stack(np.broadcast_arrays(cv * cos_rot, -cv * sin_rot, sv), axis=-1).astype(np.float32)
    return FiringPattern(
        model=model,
        return_mode=return_mode,
        rate_hz=rate_hz,
        packets=packets,
        firings_per_packet=lay.firings_per_packet,
        packet_period_us=period_us,
        block_azimuth=block_az,
        azimuth_cdeg=az_cdeg,
        directions=directions,
        ring=calibration.ring,
        _slot_block=np.ascontiguousarray(slot_block),
        _slot_firing=slot_firing,
        _slot_laser=np.ascontiguousarray(slot_laser),
    )


def _raw(distance_m: np.ndarray, intensity: np.ndarray, resolution: float) -> tuple[np.ndarray, np.ndarray]:
    d = np.nan_to_num(np.asarray(distance_m, dtype=np.float64), nan=0.0, posinf=0.0)
    raw = np.clip(np.round(d / resolution), 0, 65535).astype(np.uint16)
    level = np.clip(np.round(np.nan_to_num(np.asarray(intensity, dtype=np.float64)) * 255.0), 0, 255)
    return raw, level.astype(np.uint8)


def encode_rotation(
    calibration: Calibration,
    pattern: FiringPattern,
    distance_m: np.ndarray,
    intensity: np.ndarray,
    timestamps_us: Sequence[int] | np.ndarray,
    last_distance_m: np.ndarray | None = None,
    last_intensity: np.ndarray | None = None,
) -> list[bytes]:
    """The packets of one rotation. `distance_m`, `intensity` (0..1): (firings, lasers) arrays
    by the pattern's slots, 0 or NaN where there is no return; in dual mode they are the
    strongest returns and `last_*` the last ones (default: the same). Ranges along the pattern's
    directions from the optical centre (calibrations with distance or horizontal offset
    corrections are not encoded)."""
    if calibration.advanced:
        raise ValueError(f"{calibration.path}: distance/offset corrections: the encoder takes plain calibrations")
    if distance_m.shape != (pattern.firings, pattern.lasers):
        raise ValueError(f"distances of shape {distance_m.shape}, expected {(pattern.firings, pattern.lasers)}")
    timestamps = np.asarray(timestamps_us, dtype=np.int64)
    if timestamps.shape != (pattern.packets,):
        raise ValueError(f"{len(timestamps)} timestamps for {pattern.packets} packets")
    dual = pattern.return_mode == "dual"
    lay = layout(pattern.model, dual)
    packet = np.zeros(pattern.packets, dtype=PACKET)
    blocks = packet["blocks"]
    blocks["flag"] = np.array(BANK_FLAGS, dtype=np.uint16)[np.maximum(lay.bank, 0)]
    blocks["azimuth"] = pattern.block_azimuth
    p = np.broadcast_to(np.arange(pattern.packets)[:, None, None], pattern._slot_block.shape)
    j = np.broadcast_to(np.arange(CHANNELS), pattern._slot_block.shape)
    raw, level = _raw(distance_m, intensity, calibration.distance_resolution)
    channels = blocks["channels"]
    channels["distance"][p, pattern._slot_block, j] = raw[pattern._slot_firing, pattern._slot_laser]
    channels["intensity"][p, pattern._slot_block, j] = level[pattern._slot_firing, pattern._slot_laser]
    if dual:
        assert lay.other is not None  # a dual layout has the last return's blocks
        raw2, level2 = _raw(
            distance_m if last_distance_m is None else last_distance_m,
            intensity if last_intensity is None else last_intensity,
            calibration.distance_resolution,
        )
        other = np.broadcast_to(lay.other[None, :, None], pattern._slot_block.shape)
        channels["distance"][p, other, j] = raw2[pattern._slot_firing, pattern._slot_laser]
        channels["intensity"][p, other, j] = level2[pattern._slot_firing, pattern._slot_laser]
    packet["timestamp"] = timestamps % HOUR_US
    spec = MODEL_SPECS[pattern.model]
    if spec.mode_byte:
        packet["mode"] = RETURN_MODES[pattern.return_mode]
    if spec.product is not None:
        packet["product"] = spec.product
    # the HDL-64E S3's two status bytes stay 0 (no status cycle is simulated)
    data = packet.tobytes()
    return [data[i : i + PACKET_SIZE] for i in range(0, len(data), PACKET_SIZE)]
