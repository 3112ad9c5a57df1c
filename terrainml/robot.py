"""Robot specification (design §3): every geometric and physical constant of a robot in one YAML file.

A spec describes any number of wheels, each steerable or fixed, with or without a tracking camera,
so the swerve-drive reference robot (``agrimaro``) and a skid-steer robot (``husky``) share one
code path. Loading validates every field and names the offending one in the error.

Units are SI; positions are in the ``body`` frame (x forward, y left, z up, origin at the IMU).
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import asdict, dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from terrainml._yaml_checks import read_yaml_file
from terrainml.robots import BUILTIN_ROBOTS, REFERENCE_ROBOT


class RobotSpecError(ValueError):
    """A robot spec file is missing a field or has an invalid value (the message names it)."""


@dataclass(frozen=True)
class WheelSpec:
    """One wheel: position of its contact centre in the body frame and whether it steers."""

    name: str
    x_m: float
    y_m: float
    steerable: bool


@dataclass(frozen=True)
class CameraSpec:
    """Tracking camera (Intel T265-like) mount position in the body frame."""

    x_m: float
    y_m: float
    z_m: float = 0.0
    model: str = "t265"


@dataclass(frozen=True)
class ImuSpec:
    """IMU mount: rotation from the IMU's own axes to body axes (extrinsic xyz Euler, rad)."""

    roll_rad: float = 0.0
    pitch_rad: float = 0.0
    yaw_rad: float = 0.0
    x_m: float = 0.0
    y_m: float = 0.0
    z_m: float = 0.0


@dataclass(frozen=True)
class MotorSpec:
    """Wheel drive losses for battery energy (design §6): copper loss (tau / k_t)^2 R_ph, a driver
    efficiency when motoring, and the share of negative electrical power returned when braking."""

    phase_resistance_ohm: float = 0.25
    driver_efficiency: float = 0.95
    regen_efficiency: float = 0.65


@dataclass(frozen=True)
class RobotSpec:
    """A validated robot description. Build with :meth:`from_yaml` or :func:`load_robot`."""

    name: str
    drive: str  # "swerve" | "skid" | "differential"
    wheels: tuple[WheelSpec, ...]
    wheel_radius_m: float
    wheel_width_m: float
    mass_kg: float
    com_x_m: float
    com_y_m: float
    com_height_m: float
    yaw_inertia_kgm2: float
    wheel_inertia_kgm2: float
    torque_constant_nm_per_a: float
    max_wheel_torque_nm: float
    steering_rate_max_radps: float
    steering_deadband_rad: float
    tyre: str = "pneumatic"  # "pneumatic" | "rigid"
    tyre_flat_m: float = 0.0
    camera: CameraSpec | None = None
    imu: ImuSpec = field(default_factory=ImuSpec)
    track_width_range_m: tuple[float, float] | None = None
    description: str = ""
    # optional; None = the documented default (MotorSpec(), ground clearance 0.10 m) and
    # left out of to_dict(), so specs without them keep their hash
    ground_clearance_m: float | None = None
    motor: MotorSpec | None = None

    @property
    def motor_or_default(self) -> MotorSpec:
        return self.motor if self.motor is not None else MotorSpec()

    @property
    def ground_clearance_or_default_m(self) -> float:
        return self.ground_clearance_m if self.ground_clearance_m is not None else 0.10

    # ----------------------------------------------------------------- derived
    @property
    def n_wheels(self) -> int:
        return len(self.wheels)

    @property
    def has_camera(self) -> bool:
        return self.camera is not None

    @property
    def has_steering(self) -> bool:
        return any(w.steerable for w in self.wheels)

    @property
    def wheel_xy_m(self) -> list[tuple[float, float]]:
        return [(w.x_m, w.y_m) for w in self.wheels]

    @property
    def weight_n(self) -> float:
        return self.mass_kg * 9.81

    def static_wheel_loads_n(self) -> list[float]:
        """Static normal load per wheel from the CoM position (N).

        Least-norm solution of the moment balance (sum F = W, sum F x = W x_c, sum F y = W y_c);
        exact for three non-collinear wheels, the symmetric split for four.
        """
        xs = np.array([w.x_m for w in self.wheels])
        ys = np.array([w.y_m for w in self.wheels])
        a = np.vstack([np.ones_like(xs), xs, ys])
        b = self.weight_n * np.array([1.0, self.com_x_m, self.com_y_m])
        loads, *_ = np.linalg.lstsq(a, b, rcond=None)
        return [float(v) for v in loads]

    # ----------------------------------------------------------------- io
    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["wheels"] = [asdict(w) for w in self.wheels]
        if self.track_width_range_m is not None:
            d["track_width_range_m"] = list(self.track_width_range_m)
        for key in ("ground_clearance_m", "motor"):
            if d[key] is None:
                del d[key]
        return d

    def to_yaml(self) -> str:
        return yaml.safe_dump(self.to_dict(), sort_keys=False)

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), sort_keys=True)

    def sha256(self) -> str:
        """Content hash of the validated spec (key order and formatting independent)."""
        return hashlib.sha256(self.to_json().encode()).hexdigest()

    @classmethod
    def from_dict(cls, data: Any, source: str = "<dict>") -> "RobotSpec":
        return _parse_spec(data, source)

    @classmethod
    def from_json(cls, text: str, source: str = "<json>") -> "RobotSpec":
        return _parse_spec(json.loads(text), source)

    @classmethod
    def from_yaml(cls, path: str | Path) -> "RobotSpec":
        path = Path(path)
        data = read_yaml_file(path, RobotSpecError, f"{path}: robot spec file not found")
        return _parse_spec(data, str(path))


# --------------------------------------------------------------------- parsing
def _num(data: dict, key: str, source: str, *, positive: bool = False, nonneg: bool = False,
         default: Any = ...) -> float:
    if key not in data:
        if default is ...:
            raise RobotSpecError(f"{source}: missing field '{key}'")
        return default
    value = data[key]
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise RobotSpecError(f"{source}: field '{key}' must be a finite number, got {value!r}")
    if positive and value <= 0:
        raise RobotSpecError(f"{source}: field '{key}' must be > 0, got {value!r}")
    if nonneg and value < 0:
        raise RobotSpecError(f"{source}: field '{key}' must be >= 0, got {value!r}")
    return float(value)


def _pair(data: dict, key: str, source: str, default: Any = ...) -> tuple[float, float]:
    if key not in data:
        if default is ...:
            raise RobotSpecError(f"{source}: missing field '{key}'")
        return default
    value = data[key]
    if not isinstance(value, (list, tuple)) or len(value) != 2:
        raise RobotSpecError(f"{source}: field '{key}' must be a list of two numbers, got {value!r}")
    return (_num({"v": value[0]}, "v", f"{source}: field '{key}'"),
            _num({"v": value[1]}, "v", f"{source}: field '{key}'"))


_KNOWN = {
    "name", "description", "drive", "wheels", "wheel_radius_m", "wheel_width_m", "mass_kg",
    "com_xy_m", "com_height_m", "yaw_inertia_kgm2", "wheel_inertia_kgm2",
    "torque_constant_nm_per_a", "max_wheel_torque_nm", "steering_rate_max_radps",
    "steering_deadband_rad", "tyre", "tyre_flat_m", "camera", "imu", "track_width_range_m",
    "ground_clearance_m", "motor",
    # accept the flat keys produced by to_dict() too
    "com_x_m", "com_y_m",
}


def _parse_spec(data: Any, source: str) -> RobotSpec:
    if not isinstance(data, dict):
        raise RobotSpecError(f"{source}: a robot spec must be a mapping of fields, got {type(data).__name__}")
    unknown = sorted(set(data) - _KNOWN)
    if unknown:
        raise RobotSpecError(f"{source}: unknown field(s) {', '.join(unknown)}")
    name = data.get("name")
    if not isinstance(name, str) or not name:
        raise RobotSpecError(f"{source}: field 'name' must be a non-empty string")
    drive = data.get("drive", "swerve")
    if drive not in ("swerve", "skid", "differential"):
        raise RobotSpecError(f"{source}: field 'drive' must be swerve, skid or differential, got {drive!r}")

    wheels = _parse_wheels(data.get("wheels"), drive, source)

    if "com_xy_m" in data:
        com_x, com_y = _pair(data, "com_xy_m", source)
    else:
        com_x, com_y = _num(data, "com_x_m", source, default=0.0), _num(data, "com_y_m", source, default=0.0)

    camera = _parse_camera(data.get("camera"), source)
    imu = _parse_imu(data.get("imu") or {}, source)

    tyre = data.get("tyre", "pneumatic")
    if tyre not in ("pneumatic", "rigid"):
        raise RobotSpecError(f"{source}: field 'tyre' must be pneumatic or rigid, got {tyre!r}")
    track = None
    if data.get("track_width_range_m") is not None:
        track = _pair(data, "track_width_range_m", source)

    motor = _parse_motor(data["motor"], source) if data.get("motor") is not None else None
    clearance = None
    if data.get("ground_clearance_m") is not None:
        clearance = _num(data, "ground_clearance_m", source, positive=True)

    spec = RobotSpec(
        name=name,
        description=str(data.get("description", "")),
        drive=drive,
        wheels=tuple(wheels),
        wheel_radius_m=_num(data, "wheel_radius_m", source, positive=True),
        wheel_width_m=_num(data, "wheel_width_m", source, positive=True),
        mass_kg=_num(data, "mass_kg", source, positive=True),
        com_x_m=com_x,
        com_y_m=com_y,
        com_height_m=_num(data, "com_height_m", source, nonneg=True, default=0.3),
        yaw_inertia_kgm2=_num(data, "yaw_inertia_kgm2", source, positive=True),
        wheel_inertia_kgm2=_num(data, "wheel_inertia_kgm2", source, positive=True),
        torque_constant_nm_per_a=_num(data, "torque_constant_nm_per_a", source, positive=True),
        max_wheel_torque_nm=_num(data, "max_wheel_torque_nm", source, positive=True),
        steering_rate_max_radps=_num(data, "steering_rate_max_radps", source, positive=True, default=2.1),
        steering_deadband_rad=_num(data, "steering_deadband_rad", source, nonneg=True, default=0.0),
        tyre=tyre,
        tyre_flat_m=_num(data, "tyre_flat_m", source, nonneg=True, default=0.0),
        camera=camera,
        imu=imu,
        track_width_range_m=track,
        ground_clearance_m=clearance,
        motor=motor,
    )
    if drive == "swerve" and not spec.has_steering:
        raise RobotSpecError(f"{source}: field 'drive' is swerve but no wheel is steerable")
    if drive != "swerve" and spec.has_steering:
        raise RobotSpecError(f"{source}: field 'wheels': a {drive}-drive robot cannot have steerable wheels")
    return spec


def _parse_wheels(wheels_raw: Any, drive: str, source: str) -> list[WheelSpec]:
    """The ``wheels`` list: position (``x_m, y_m`` or ``xy_m``), ``steerable`` (default: swerve), name."""
    if not isinstance(wheels_raw, list) or not wheels_raw:
        raise RobotSpecError(f"{source}: field 'wheels' must be a non-empty list")
    wheels = []
    for i, w in enumerate(wheels_raw):
        where = f"{source}: wheels[{i}]"
        if not isinstance(w, dict):
            raise RobotSpecError(f"{where} must be a mapping with x_m, y_m, steerable")
        if "xy_m" in w:
            x, y = _pair(w, "xy_m", where)
        else:
            x, y = _num(w, "x_m", where), _num(w, "y_m", where)
        steer = w.get("steerable", drive == "swerve")
        if not isinstance(steer, bool):
            raise RobotSpecError(f"{where}: field 'steerable' must be true or false")
        wheels.append(WheelSpec(name=str(w.get("name", f"wheel{i + 1}")), x_m=x, y_m=y, steerable=steer))
    _check_unique_names(wheels, source)
    return wheels


def _parse_camera(c: Any, source: str) -> CameraSpec | None:
    """The ``camera`` mapping (mount position, model), or None for a robot without camera."""
    if c is None:
        return None
    if not isinstance(c, dict):
        raise RobotSpecError(f"{source}: field 'camera' must be a mapping or null")
    return CameraSpec(x_m=_num(c, "x_m", f"{source}: camera"), y_m=_num(c, "y_m", f"{source}: camera"),
                      z_m=_num(c, "z_m", f"{source}: camera", default=0.0), model=str(c.get("model", "t265")))


def _parse_imu(imu_raw: Any, source: str) -> ImuSpec:
    """The ``imu`` mapping: mount rotation (rad) and position (m), every field defaulting to 0."""
    if not isinstance(imu_raw, dict):
        raise RobotSpecError(f"{source}: field 'imu' must be a mapping")
    imu = ImuSpec(**{k: _num(imu_raw, k, f"{source}: imu", default=0.0)
                     for k in ("roll_rad", "pitch_rad", "yaw_rad", "x_m", "y_m", "z_m")})
    bad_imu = sorted(set(imu_raw) - {"roll_rad", "pitch_rad", "yaw_rad", "x_m", "y_m", "z_m"})
    if bad_imu:
        raise RobotSpecError(f"{source}: unknown field(s) imu.{', imu.'.join(bad_imu)}")
    return imu


def _parse_motor(m: Any, source: str) -> MotorSpec:
    """The ``motor`` mapping (phase resistance, driver and regeneration efficiency)."""
    if not isinstance(m, dict):
        raise RobotSpecError(f"{source}: field 'motor' must be a mapping")
    keys = ("phase_resistance_ohm", "driver_efficiency", "regen_efficiency")
    bad = sorted(set(m) - set(keys))
    if bad:
        raise RobotSpecError(f"{source}: unknown field(s) motor.{', motor.'.join(bad)}")
    dflt = MotorSpec()
    motor = MotorSpec(**{k: _num(m, k, f"{source}: motor", nonneg=True, default=getattr(dflt, k)) for k in keys})
    if not (0.0 < motor.driver_efficiency <= 1.0 and 0.0 <= motor.regen_efficiency <= 1.0):
        raise RobotSpecError(f"{source}: motor.driver_efficiency must be in (0, 1] and "
                             "motor.regen_efficiency in [0, 1]")
    return motor


def _check_unique_names(wheels: list[WheelSpec], source: str) -> None:
    # Wheels are addressed by name in messages, plots and the served slip: two of one name
    # would make those ambiguous (an unnamed wheel defaults to wheel{i}, which can collide too).
    seen: dict[str, int] = {}
    for i, w in enumerate(wheels):
        if w.name in seen:
            raise RobotSpecError(f"{source}: field 'wheels': wheels[{seen[w.name]}] and wheels[{i}] "
                                 f"are both named {w.name!r}; wheel names must be unique")
        seen[w.name] = i


def check_wheel_count(spec: RobotSpec, n_wheels_in_log: int, source: str | Path) -> None:
    """Refuse a log or run table whose wheel count differs from the robot spec's.

    Parameters
    ----------
    spec : the robot spec the data is read or estimated with.
    n_wheels_in_log : wheels found in the data (e.g. ``wheel{i}_omega_radps`` columns or
        joint-state names).
    source : the log or table, named in the message.

    Raises
    ------
    RobotSpecError naming ``source``, both counts and the spec.
    """
    if int(n_wheels_in_log) != spec.n_wheels:
        raise RobotSpecError(
            f"{source}: the data has {int(n_wheels_in_log)} wheel(s) but robot spec {spec.name!r} has "
            f"{spec.n_wheels}; pass the robot it was recorded with (--robot NAME or a spec YAML)")


# --------------------------------------------------------------------- loading
def builtin_robot(name: str) -> RobotSpec:
    """A built-in robot spec by name (:data:`BUILTIN_ROBOTS`); RobotSpecError names the known ones."""
    if name not in BUILTIN_ROBOTS:
        raise RobotSpecError(f"{name}: no built-in robot (built-in robots: {', '.join(BUILTIN_ROBOTS)})")
    ref = resources.files("terrainml.robots").joinpath(f"{name}.yaml")
    with resources.as_file(ref) as path:
        return RobotSpec.from_yaml(path)


def reference_robot() -> RobotSpec:
    """The reference robot's spec (``terrainml/robots/agrimaro.yaml``, design §3)."""
    return builtin_robot(REFERENCE_ROBOT)


def load_robot(spec: str | Path | RobotSpec | None = None) -> RobotSpec:
    """Resolve a robot: ``None`` gives the reference robot; a built-in name or a YAML path.

    Called where a name or path enters the package (the CLI, the public entry functions such as
    :func:`terrainml.pipeline.dataset.build_dataset`); everything below takes the
    :class:`RobotSpec` it returns (a spec is returned unchanged).
    """
    if isinstance(spec, RobotSpec):
        return spec
    if spec is None:
        return reference_robot()
    text = str(spec)
    if text in BUILTIN_ROBOTS:
        return builtin_robot(text)
    path = Path(text)
    if not path.exists():
        raise RobotSpecError(
            f"{text}: no such robot spec file (built-in robots: {', '.join(BUILTIN_ROBOTS)})")
    return RobotSpec.from_yaml(path)
