"""Airframes as data: mass, inertia, rotor list, motor map; the allocation matrix is derived.

An airframe YAML (config/*.yaml) is validated strictly: an unknown key, a missing field, a key with
another unit suffix than ours, a non-finite or non-physical number, or a rotor layout whose allocation
matrix cannot produce every thrust/torque direction raises :class:`AirframeError` naming the file and
the key. Frames and units: shared/spec/conventions.md (body FLU, SI, rotor speeds in rad/s).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import numpy as np
import yaml

from multirotor_ros.model.rotation import BoolArray, FloatArray
from multirotor_ros.model.rotors import rotor_signatures
from multirotor_ros.resources import config_directory

GRAVITY_M_S2 = 9.81
# A rotor farther from the centre is a typo or a unit error (mm for m), and its torques overflow later.
LARGEST_ROTOR_DISTANCE_M = 100.0
Spin = Literal["ccw", "cw"]


class AirframeError(ValueError):
    """An airframe description that cannot be used; the message names the file and the key."""


@dataclass(frozen=True)
class Rotor:
    """One rotor: where it is (body FLU, m), how it spins (seen from above), its coaxial role."""

    number: int
    position_m: tuple[float, float, float]
    spin: Spin
    pair: int | None = None
    level: Literal["upper", "lower"] | None = None

    @property
    def spin_sign(self) -> float:
        """Sign of the rotor's reaction torque about body +z: -1 for ccw, +1 for cw (conventions.md)."""
        return -1.0 if self.spin == "ccw" else 1.0


@dataclass(frozen=True)
class MotorMap:
    """Actuator command -> rotor speed, as identified on a bench (seed 2 eqs. 23-28).

    ``law`` 'linear': speed is affine in the normalised command x = (u - input_min)/(input_max - input_min);
    'quadratic': speed squared (so thrust) is affine in x, as a thrust-linearised ESC behaves.
    Commands outside [input_min, input_max] are clamped: the ESC saturates.
    """

    input_unit: Literal["pwm_us", "normalized"]
    input_min: float
    input_max: float
    speed_min_rad_s: float
    speed_max_rad_s: float
    law: Literal["linear", "quadratic"] = "linear"

    def speed_from_command(self, command: Any) -> FloatArray:
        """Rotor speed [rad/s] for actuator commands in ``input_unit``."""
        u = np.asarray(command, dtype=float)
        x = np.clip((u - self.input_min) / (self.input_max - self.input_min), 0.0, 1.0)
        lo, hi = self.speed_min_rad_s, self.speed_max_rad_s
        if self.law == "linear":
            return lo + (hi - lo) * x
        return np.sqrt(lo * lo + (hi * hi - lo * lo) * x)

    def command_from_speed(self, omega_rad_s: Any) -> FloatArray:
        """Inverse of :meth:`speed_from_command` (speeds clamped to the map's range)."""
        w = np.clip(np.asarray(omega_rad_s, dtype=float), self.speed_min_rad_s, self.speed_max_rad_s)
        lo, hi = self.speed_min_rad_s, self.speed_max_rad_s
        x = (w - lo) / (hi - lo) if self.law == "linear" else (w * w - lo * lo) / (hi * hi - lo * lo)
        return self.input_min + (self.input_max - self.input_min) * x

    def describe(self) -> str:
        """One line for log metadata."""
        return (
            f"{self.law} {self.input_unit} [{self.input_min:g}, {self.input_max:g}] -> "
            f"[{self.speed_min_rad_s:g}, {self.speed_max_rad_s:g}] rad/s"
        )


@dataclass(frozen=True)
class Airframe:
    """A rigid multirotor: everything the physics needs that is not an effect."""

    name: str
    mass_kg: float
    inertia_kg_m2: FloatArray
    k_f_N_s2: float
    k_t_N_m_s2: float
    rotors: tuple[Rotor, ...]
    rotor_speed_min_rad_s: float
    rotor_speed_max_rad_s: float
    motor_time_constant_s: float
    rotor_radius_m: float
    motor_map: MotorMap
    effects: tuple[Mapping[str, Any], ...] = ()
    sections: Mapping[str, Mapping[str, Any]] = field(default_factory=dict)
    description: str = ""
    source_path: Path | None = None

    @property
    def n_rotors(self) -> int:
        """Number of rotors."""
        return len(self.rotors)

    @property
    def rotor_positions_m(self) -> FloatArray:
        """(N, 3) rotor positions in body FLU [m]."""
        return np.array([r.position_m for r in self.rotors], dtype=float)

    @property
    def spin_signs(self) -> FloatArray:
        """(N,) reaction-torque sign about body +z: -1 ccw, +1 cw."""
        return np.array([r.spin_sign for r in self.rotors])

    @property
    def lower_rotor_mask(self) -> BoolArray:
        """(N,) booleans: the lower rotor of a coaxial pair."""
        return np.array([r.level == "lower" for r in self.rotors])

    @property
    def allocation(self) -> FloatArray:
        """4xN matrix: (thrust, tau_x, tau_y, tau_z) in body FLU per unit omega_i^2 [rad^2/s^2].

        Column i: thrust k_f along +z at p_i gives torque p_i x (0, 0, k_f) = (k_f y_i, -k_f x_i, 0);
        the rotor's drag adds spin_sign * k_t about z.
        """
        ones = np.ones(self.n_rotors)
        return rotor_signatures(self, self.k_f_N_s2 * ones, self.k_t_N_m_s2 * ones)

    def effect_specs(self) -> list[dict[str, Any]]:
        """The airframe's own effect list, as plain dicts (``id`` plus parameters)."""
        return [dict(spec) for spec in self.effects]


# ----------------------------------------------------------------------------------------------
# YAML loading

_TOP_LEVEL_KEYS = {
    "name": "str",
    "description": "str",
    "mass_kg": "positive",
    "inertia_kg_m2": "inertia",
    "k_f_N_s2": "positive",
    "k_t_N_m_s2": "positive",
    "arm_length_m": "positive",
    "rotor_speed_min_rad_s": "nonnegative",
    "rotor_speed_max_rad_s": "positive",
    "motor_time_constant_s": "positive",
    "rotor_radius_m": "positive",
    "rotors": "rotors",
    "motor_map": "motor_map",
    "effects": "effects",
    "controller": "section",
    "sensors": "section",
    "rotor_balance": "rotor_balance",
}
_REQUIRED_KEYS = ("mass_kg", "inertia_kg_m2", "k_f_N_s2", "k_t_N_m_s2", "rotors", "rotor_speed_max_rad_s")
_ROTOR_KEYS = {"number", "position_m", "angle_deg", "spin", "pair", "level"}
_MOTOR_MAP_KEYS = {"input_unit", "input_min", "input_max", "speed_min_rad_s", "speed_max_rad_s", "law"}
_ROTOR_BALANCE_KEYS = {"thrust_N", "scatter_N", "flights", "sources"}
# Unit suffixes this project does not use, so that `mass_g` or `arm_length_cm` says "wrong unit".
_FOREIGN_UNIT_SUFFIXES = (
    "_g",
    "_mg",
    "_lb",
    "_cm",
    "_mm",
    "_in",
    "_ft",
    "_rpm",
    "_deg_s",
    "_ms",
    "_us",
    "_kgf",
)


def _similar_key(key: str, known: Sequence[str]) -> str:
    stem = key.rsplit("_", 1)[0]
    matches = [k for k in known if k.startswith(stem)]
    return f" (did you mean {matches[0]!r}? units are SI: kg, m, s, rad/s)" if matches else ""


class _Reader:
    """Validates one YAML document and names the file and key in every error."""

    def __init__(self, origin: str):
        self.origin = origin

    def fail(self, key: str, message: str) -> AirframeError:
        return AirframeError(f"{self.origin}: {key}: {message}")

    def number(self, key: str, value: Any, kind: str = "finite") -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.fail(key, f"expected a number, got {value!r}")
        number = float(value)
        if not math.isfinite(number):
            raise self.fail(key, f"must be finite, got {value!r}")
        if kind == "positive" and number <= 0:
            raise self.fail(key, f"must be > 0, got {number:g}")
        if kind == "nonnegative" and number < 0:
            raise self.fail(key, f"must be >= 0, got {number:g}")
        return number

    def check_keys(
        self, where: str, mapping: Any, allowed: Sequence[str], required: Sequence[str] = ()
    ) -> None:
        if not isinstance(mapping, Mapping):
            raise self.fail(where or "(document)", f"expected a mapping, got {type(mapping).__name__}")
        for key in mapping:
            if key not in allowed:
                prefix = f"{where}." if where else ""
                hint = _similar_key(str(key), list(allowed))
                if not hint and str(key).endswith(_FOREIGN_UNIT_SUFFIXES):
                    hint = " (wrong unit: this project uses SI units, kg, m, s, rad, rad/s)"
                raise self.fail(f"{prefix}{key}", f"unknown key{hint}")
        for key in required:
            if key not in mapping:
                prefix = f"{where}." if where else ""
                raise self.fail(f"{prefix}{key}", "missing")

    def inertia(self, value: Any) -> FloatArray:
        key = "inertia_kg_m2"
        if not isinstance(value, list):
            raise self.fail(key, "expected [Ixx, Iyy, Izz] or a 3x3 list")
        if len(value) == 3 and all(not isinstance(v, list) for v in value):
            matrix = np.diag([self.number(f"{key}[{i}]", v, "positive") for i, v in enumerate(value)])
        elif len(value) == 3 and all(isinstance(row, list) and len(row) == 3 for row in value):
            matrix = np.array(
                [
                    [self.number(f"{key}[{i}][{j}]", v) for j, v in enumerate(row)]
                    for i, row in enumerate(value)
                ]
            )
        else:
            raise self.fail(key, "expected [Ixx, Iyy, Izz] or a 3x3 list")
        if not np.allclose(matrix, matrix.T) or np.any(np.linalg.eigvalsh(matrix) <= 0):
            raise self.fail(key, "must be symmetric positive definite")
        return matrix

    def rotors(self, value: Any, arm_length_m: float | None) -> tuple[Rotor, ...]:
        if not isinstance(value, list) or len(value) < 4:
            raise self.fail("rotors", "expected a list of at least 4 rotors")
        rotors = []
        for index, entry in enumerate(value):
            where = f"rotors[{index}]"
            self.check_keys(where, entry, sorted(_ROTOR_KEYS), required=("spin",))
            number = int(self.number(f"{where}.number", entry.get("number", index + 1)))
            if number != index + 1:
                raise self.fail(f"{where}.number", f"rotors must be numbered 1..N in order, got {number}")
            if ("position_m" in entry) == ("angle_deg" in entry):
                raise self.fail(
                    where, "give exactly one of position_m [x, y, z] or angle_deg (with arm_length_m)"
                )
            if "position_m" in entry:
                raw = entry["position_m"]
                if not isinstance(raw, list) or len(raw) != 3:
                    raise self.fail(f"{where}.position_m", "expected [x, y, z] in body FLU [m]")
                x, y, z = (self.number(f"{where}.position_m[{i}]", v) for i, v in enumerate(raw))
                position = (x, y, z)
            else:
                if arm_length_m is None:
                    raise self.fail(f"{where}.angle_deg", "needs arm_length_m at the top level")
                # angle_deg runs from the nose (+x) towards the left (+y): counter-clockwise from above.
                angle = math.radians(self.number(f"{where}.angle_deg", entry["angle_deg"]))
                position = (arm_length_m * math.cos(angle), arm_length_m * math.sin(angle), 0.0)
            largest = max(abs(c) for c in position)
            if largest > LARGEST_ROTOR_DISTANCE_M:
                key = f"{where}.position_m" if "position_m" in entry else "arm_length_m"
                limit = LARGEST_ROTOR_DISTANCE_M
                raise self.fail(
                    key, f"{largest:g} m from the centre: no multirotor is larger than {limit:g} m"
                )
            spin = entry["spin"]
            if spin not in ("ccw", "cw"):
                raise self.fail(f"{where}.spin", f"expected 'ccw' or 'cw', got {spin!r}")
            level = entry.get("level")
            if level not in (None, "upper", "lower"):
                raise self.fail(f"{where}.level", f"expected 'upper' or 'lower', got {level!r}")
            pair = entry.get("pair")
            if pair is not None:
                pair = int(self.number(f"{where}.pair", pair, "positive"))
            rotors.append(Rotor(number, position, spin, pair, level))
        return tuple(rotors)

    def motor_map(self, value: Any, speed_min: float, speed_max: float) -> MotorMap:
        where = "motor_map"
        self.check_keys(
            where, value, sorted(_MOTOR_MAP_KEYS), required=("input_unit", "input_min", "input_max")
        )
        unit = value["input_unit"]
        if unit not in ("pwm_us", "normalized"):
            raise self.fail(f"{where}.input_unit", f"expected 'pwm_us' or 'normalized', got {unit!r}")
        law = value.get("law", "linear")
        if law not in ("linear", "quadratic"):
            raise self.fail(f"{where}.law", f"expected 'linear' or 'quadratic', got {law!r}")
        lo = self.number(f"{where}.input_min", value["input_min"])
        hi = self.number(f"{where}.input_max", value["input_max"])
        if hi <= lo:
            raise self.fail(f"{where}.input_max", f"must exceed input_min ({lo:g}), got {hi:g}")
        w_lo = self.number(f"{where}.speed_min_rad_s", value.get("speed_min_rad_s", speed_min), "nonnegative")
        w_hi = self.number(f"{where}.speed_max_rad_s", value.get("speed_max_rad_s", speed_max), "positive")
        if w_hi <= w_lo:
            raise self.fail(f"{where}.speed_max_rad_s", f"must exceed speed_min_rad_s ({w_lo:g})")
        return MotorMap(unit, lo, hi, w_lo, w_hi, law)

    def rotor_balance(self, value: Any, n_rotors: int) -> dict[str, Any]:
        """The rotor balance ``multirotor identify`` writes (multirotor_ros.ident.rotor_balance)."""
        where = "rotor_balance"
        self.check_keys(
            where, value, sorted(_ROTOR_BALANCE_KEYS), required=("thrust_N", "scatter_N", "flights")
        )
        lists = {}
        for key, kind in (("thrust_N", "positive"), ("scatter_N", "nonnegative")):
            entries = value[key]
            if not isinstance(entries, list) or len(entries) != n_rotors:
                raise self.fail(f"{where}.{key}", f"expected a list of {n_rotors} numbers, one per rotor")
            lists[key] = [self.number(f"{where}.{key}[{i}]", v, kind) for i, v in enumerate(entries)]
        flights = self.number(f"{where}.flights", value["flights"], "positive")
        if flights != int(flights):
            raise self.fail(f"{where}.flights", f"expected a whole number of flights, got {flights:g}")
        sources = value.get("sources", [])
        if not isinstance(sources, list):
            raise self.fail(f"{where}.sources", "expected a list of log names")
        return {**lists, "flights": int(flights), "sources": [str(s) for s in sources]}

    def effects(self, value: Any) -> tuple[dict[str, Any], ...]:
        # Imported here: effects import this module for the Airframe type.
        from multirotor_ros.model.effects import validate_effect_spec

        if value is None:
            return ()
        if not isinstance(value, list):
            raise self.fail("effects", "expected a list of {id: ..., parameters...}")
        try:
            return tuple(
                validate_effect_spec(spec, f"{self.origin}: effects[{i}]") for i, spec in enumerate(value)
            )
        except ValueError as error:
            raise AirframeError(str(error)) from error


def airframe_from_dict(
    document: Any, origin: str = "<airframe>", source_path: Path | None = None
) -> Airframe:
    """Validate a parsed YAML document and build the :class:`Airframe`."""
    reader = _Reader(origin)
    reader.check_keys("", document, list(_TOP_LEVEL_KEYS), required=_REQUIRED_KEYS)
    numbers = {
        key: reader.number(key, document[key], kind)
        for key, kind in _TOP_LEVEL_KEYS.items()
        if kind in ("positive", "nonnegative") and key in document
    }
    speed_min = numbers.get("rotor_speed_min_rad_s", 0.0)
    speed_max = numbers["rotor_speed_max_rad_s"]
    if speed_max <= speed_min:
        raise reader.fail("rotor_speed_max_rad_s", f"must exceed rotor_speed_min_rad_s ({speed_min:g})")
    rotors = reader.rotors(document["rotors"], numbers.get("arm_length_m"))
    motor_map = (
        reader.motor_map(document["motor_map"], speed_min, speed_max)
        if "motor_map" in document
        else MotorMap("normalized", 0.0, 1.0, speed_min, speed_max)
    )
    sections = {}
    for key in ("controller", "sensors"):
        if key in document:
            if not isinstance(document[key], Mapping):
                raise reader.fail(key, "expected a mapping")
            sections[key] = dict(document[key])
    if "rotor_balance" in document:
        sections["rotor_balance"] = reader.rotor_balance(document["rotor_balance"], len(rotors))
    airframe = Airframe(
        name=str(document.get("name") or (source_path.stem if source_path else "airframe")),
        mass_kg=numbers["mass_kg"],
        inertia_kg_m2=reader.inertia(document["inertia_kg_m2"]),
        k_f_N_s2=numbers["k_f_N_s2"],
        k_t_N_m_s2=numbers["k_t_N_m_s2"],
        rotors=rotors,
        rotor_speed_min_rad_s=speed_min,
        rotor_speed_max_rad_s=speed_max,
        motor_time_constant_s=numbers.get("motor_time_constant_s", 0.02),
        rotor_radius_m=numbers.get("rotor_radius_m", 0.1),
        motor_map=motor_map,
        effects=reader.effects(document.get("effects")),
        sections=sections,
        description=str(document.get("description", "")),
        source_path=source_path,
    )
    _check_allocation(airframe.allocation, reader)
    return airframe


_ALLOCATION_ROWS = ("thrust", "roll torque (tau_x)", "pitch torque (tau_y)", "yaw torque (tau_z)")


def _check_allocation(allocation: FloatArray, reader: _Reader) -> None:
    """Refuse a rotor layout that cannot produce every thrust/torque direction, saying which it lacks."""
    if not np.all(np.isfinite(allocation)):
        raise reader.fail(
            "rotors", "positions and coefficients give a non-finite allocation matrix (too large)"
        )
    # Rows in different units (N, N m): scale each to 1 before asking for the rank.
    row_scale = np.abs(allocation).max(axis=1)
    missing = [name for name, scale in zip(_ALLOCATION_ROWS, row_scale, strict=True) if scale == 0.0]
    if missing:
        raise reader.fail(
            "rotors",
            f"no rotor produces any {' or '.join(missing)}: the rotors sit on one line through the centre "
            "(all at the same angle_deg?) and cannot produce every thrust/torque direction",
        )
    singular = np.linalg.svd(allocation / row_scale[:, np.newaxis], compute_uv=False)
    if singular.min() < 1e-9:
        raise reader.fail(
            "rotors",
            "the allocation matrix has rank < 4: this layout cannot produce every thrust/torque direction",
        )


def resolve_airframe_path(name_or_path: str | Path) -> Path:
    """A config name (``x8_octorotor``) or a YAML path -> an existing path."""
    candidate = Path(name_or_path)
    if candidate.suffix in (".yaml", ".yml") or candidate.exists():
        if not candidate.is_file():
            raise AirframeError(f"{candidate}: no such airframe file")
        return candidate
    directory = config_directory()
    path = directory / f"{name_or_path}.yaml"
    if not path.is_file():
        names = ", ".join(sorted(p.stem for p in directory.glob("*.yaml")))
        raise AirframeError(f"unknown airframe {str(name_or_path)!r}; known: {names} (or give a YAML path)")
    return path


def load_airframe(name_or_path: str | Path) -> Airframe:
    """Load and validate an airframe by config name or YAML path."""
    path = resolve_airframe_path(name_or_path)
    try:
        document = yaml.safe_load(path.read_text(encoding="utf-8"))
    except yaml.YAMLError as error:
        raise AirframeError(f"{path}: not valid YAML: {error}") from error
    except UnicodeDecodeError as error:
        raise AirframeError(f"{path}: not UTF-8 text: {error}") from error
    return airframe_from_dict(document, origin=str(path), source_path=path)
