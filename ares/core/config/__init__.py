"""Typed configuration: one model per section, its defaults in one place, unknown keys refused.

Every section of a run's configuration is a pydantic model (`Params`) whose fields carry their
default, unit, range and meaning (`param(...)`). The core's own sections live here, split by
domain; each node defines its own section next to its code (`Node.Params`), and the composition
layer (ares.app.run_config) assembles the whole model from the process table. Nothing else holds
defaults: no YAML file of defaults, no `dict.get(key, default)` in code.

    base.py       Params, param, ConfigError; YAML files, merging, validation errors as sentences
    run.py        the core sections (vehicle id, bus, heartbeat, lockstep, replay, the local
                  frame's origin) and the run's whole configuration: build, current, core, section
    vehicle.py    vehicle profiles (vehicles/*.yaml), their actuators, gains and LiDARs
    tour.py       tours (tours/*.yaml): corners, widths, verges, POIs, zones
    vehicle_io.py the vehicle's devices that the drivers read (GNSS, Velodyne LiDARs, CAN)

A user's run configuration is a YAML file of overrides (`ares run --config FILE`). Each file is
validated on its own, so an error names the file, the key and what is allowed; `ConfigError`
carries that sentence. A run's effective configuration (validated, every default filled in) is
written once by `ares run` to a JSON file whose path reaches every child process through
ARES_RUN_CONFIG, so all processes of a run agree on it; a node validates its own section again
on start.
"""

from ares.core.config.base import (
    CONFIG_DIR,
    ConfigError,
    Params,
    deep_merge,
    describe_errors,
    error_line,
    load_yaml,
    model_in,
    named_file,
    packaged_file,
    param,
    read_secret,
    sentence,
    validated,
)
from ares.core.config.run import (
    COMMAND_LINE,
    CORE_SECTIONS,
    RUN_CONFIG_ENV,
    VEHICLE_ID_PATTERN,
    BusSettings,
    CommandSettings,
    CoreConfig,
    CpuSettings,
    HeartbeatSettings,
    LockstepSettings,
    RecordingSettings,
    ReplaySettings,
    SnapshotSettings,
    SnapshotTrigger,
    UtmOrigin,
    build,
    core,
    core_defaults,
    current,
    section,
    write_run_config,
)
from ares.core.config.tour import (
    POI_ACTIONS,
    VERGE_KINDS,
    PoiAction,
    TourCorner,
    TourDescription,
    TourElevation,
    TourPoi,
    TourStretch,
    TourVerge,
    TourZone,
    VergeKind,
    load_tour,
)
from ares.core.config.vehicle import (
    LIDAR_MODELS,
    LIDAR_NAMES,
    ActuatorParams,
    DbwPidParams,
    LidarLayers,
    LidarModel,
    LidarMount,
    PidGains,
    SteeringActuatorParams,
    TractionActuatorParams,
    VehicleProfile,
    load_vehicle,
)
from ares.core.config.vehicle_io import CanDevice, GnssDevice, NtripCaster, VehicleIo, VelodyneDevice

__all__ = [
    "CanDevice",
    "GnssDevice",
    "NtripCaster",
    "VehicleIo",
    "VelodyneDevice",
    "model_in",
    "CONFIG_DIR",
    "ConfigError",
    "Params",
    "param",
    "load_yaml",
    "packaged_file",
    "named_file",
    "deep_merge",
    "validated",
    "describe_errors",
    "sentence",
    "error_line",
    "read_secret",
    "SteeringActuatorParams",
    "TractionActuatorParams",
    "ActuatorParams",
    "PidGains",
    "DbwPidParams",
    "LidarLayers",
    "LidarModel",
    "LIDAR_MODELS",
    "LIDAR_NAMES",
    "LidarMount",
    "VehicleProfile",
    "load_vehicle",
    "TourCorner",
    "TourElevation",
    "TourStretch",
    "TourPoi",
    "PoiAction",
    "POI_ACTIONS",
    "TourZone",
    "VergeKind",
    "VERGE_KINDS",
    "TourVerge",
    "TourDescription",
    "load_tour",
    "RUN_CONFIG_ENV",
    "VEHICLE_ID_PATTERN",
    "BusSettings",
    "CommandSettings",
    "HeartbeatSettings",
    "LockstepSettings",
    "RecordingSettings",
    "SnapshotSettings",
    "SnapshotTrigger",
    "ReplaySettings",
    "CpuSettings",
    "UtmOrigin",
    "CoreConfig",
    "CORE_SECTIONS",
    "COMMAND_LINE",
    "build",
    "core_defaults",
    "write_run_config",
    "current",
    "core",
    "section",
]
