"""The map file: every library sign's pose in one building frame.

    frame: map                          # optional, default "map"
    signs:
      - id: security_compound           # a library sign id
        position_m: [x, y, z]           # the sign frame's origin in the map frame, metres
        orientation_wxyz: [w, x, y, z]  # the sign frame's rotation in the map frame
        covariance: null                # optional 6x6, ROS order (x, y, z, rotation about x, y, z)

so that X_map = R(orientation_wxyz)·X_sign + position_m. `yaw_pitch_roll_deg: [y, p, r]` may stand
instead of `orientation_wxyz`, with R = Rz(yaw)·Ry(pitch)·Rx(roll) as the pose output's Euler angles.
A sign's covariance is that of its position (metres) and of a small rotation about the map's axes
(radians) applied on the left: R_true = exp([δθ]×)·R. JSON is read too (YAML holds JSON).
"""

from __future__ import annotations

import math
import reprlib
from collections.abc import Collection, Iterable
from dataclasses import dataclass
from numbers import Real
from pathlib import Path

import numpy as np
import yaml

from .camera import GuardedYamlLoader
from .jsonfile import EMPTY_FILE
from .pose import euler_zyx_deg, quaternion_wxyz, rotation_from_euler_zyx_deg, rotation_from_quaternion_wxyz

# A map of some hundred signs is some tens of kB; a file past these limits is not a map.
MAX_MAP_FILE_BYTES, MAX_MAP_NODES = 5_000_000, 200_000
# How far from 1 a written quaternion's norm may be (six printed digits) before it is taken for a typo.
QUATERNION_NORM_TOLERANCE = 1e-3
DEFAULT_FRAME = "map"
# Metres from the map's origin past which a sign is a slip of units (millimetres) or a typo, not a building: a
# campus 10 km across stays within; 1e300 m made every fit in the map frame singular.
MAX_POSITION_M = 10_000.0
_SIGN_KEYS = ("id", "position_m", "orientation_wxyz", "yaw_pitch_roll_deg", "covariance")


class MapError(ValueError):
    """A map file that cannot be used; the message names the file and the field and says why."""


class _MapYamlLoader(GuardedYamlLoader):
    error = MapError
    what = "map file"
    most_nodes = MAX_MAP_NODES
    too_many = "a map has about twenty a sign"


@dataclass(frozen=True)
class MappedSign:
    """One sign's pose in the map frame: X_map = R·X_sign + position_m.

    R: (3, 3) rotation, sign frame to map frame. position_m: (3,) metres. covariance: (6, 6) or None,
    ROS order (x, y, z, rotation about the map's x, y, z), metres and radians.
    """

    sign_id: str
    R: np.ndarray
    position_m: np.ndarray
    covariance: np.ndarray | None = None

    def to_map(self, points_sign: np.ndarray) -> np.ndarray:
        """(N, 3) points in the map frame of (N, 3) points in this sign's frame (metres)."""
        return np.asarray(points_sign, dtype=np.float64) @ self.R.T + self.position_m

    def worst_sigma(self) -> tuple[float, float] | None:
        """1-sigma along the worst direction of the position (m) and of the rotation (rad); None
        without a covariance."""
        if self.covariance is None:
            return None
        return tuple(math.sqrt(max(float(np.linalg.eigvalsh(block).max()), 0.0))  # type: ignore[return-value]
                     for block in (self.covariance[:3, :3], self.covariance[3:, 3:]))


@dataclass(frozen=True)
class SignMap:
    """The signs of one building in the map frame `frame` (a ROS frame id), keyed by library sign id."""

    signs: dict[str, MappedSign]
    frame: str = DEFAULT_FRAME

    def to_json(self) -> dict:
        """The map file's document (orientation as a quaternion)."""
        return {"frame": self.frame, "signs": [_sign_json(s) for s in self.signs.values()]}


def _sign_json(sign: MappedSign) -> dict:
    return {"id": sign.sign_id, "position_m": [float(v) for v in sign.position_m],
            "orientation_wxyz": [float(v) for v in quaternion_wxyz(sign.R)],
            "covariance": None if sign.covariance is None else sign.covariance.tolist()}


def load_sign_map(path: str | Path, library_ids: Collection[str] | None = None) -> SignMap:
    """The map file at `path`; with `library_ids`, a sign id not among them is refused. MapError
    naming the file and the field for anything that is not a valid map (see `read_sign_map`)."""
    path = Path(path)
    try:
        with path.open("rb") as file:
            data = file.read(MAX_MAP_FILE_BYTES + 1)
    except FileNotFoundError:
        raise MapError(f"map file not found: {path}") from None
    except IsADirectoryError:
        raise MapError(f"map file {path} is a folder: give the map's .yaml or .json file") from None
    return read_sign_map(data, str(path), library_ids)


def read_sign_map(data: bytes, name: str, library_ids: Collection[str] | None = None) -> SignMap:
    """The map file `name` from its bytes `data`, as `load_sign_map` reads a file. Refused with a
    one-line MapError naming `name` and the field: text that is not YAML or JSON, unknown keys,
    unknown or duplicate sign ids, positions and orientations that are not finite numbers, a
    quaternion whose norm is not 1 (within QUATERNION_NORM_TOLERANCE), both or neither of
    orientation_wxyz and yaw_pitch_roll_deg, a covariance that is not a symmetric positive
    semi-definite 6x6 matrix."""
    try:
        if len(data) > MAX_MAP_FILE_BYTES:
            raise MapError(f"over {MAX_MAP_FILE_BYTES // 1_000_000} MB, which no map of signs is")
        try:
            text = data.decode("utf-8-sig")
        except UnicodeDecodeError:
            raise MapError("not text (UTF-8)") from None
        if not text.strip():
            raise MapError(EMPTY_FILE)
        try:
            document = next((d for d in yaml.load_all(text, _MapYamlLoader) if d is not None), None)
        except yaml.YAMLError as exc:
            problem = " ".join(str(getattr(exc, "problem", "") or exc).split())
            raise MapError(f"neither valid YAML nor JSON ({problem})") from None
        return _sign_map(document, library_ids)
    except MapError as exc:
        raise MapError(f"{name}: {exc}") from None


def _sign_map(document: object, library_ids: Collection[str] | None) -> SignMap:
    if not isinstance(document, dict):
        raise MapError("expected a mapping with `signs:` (a list of signs with id, position_m, orientation_wxyz)")
    _refuse_unknown(document, ("frame", "signs"), "the map")
    frame = document.get("frame", DEFAULT_FRAME)
    if not isinstance(frame, str) or not frame.strip() or any(c.isspace() for c in frame):
        raise MapError(f"frame must be a ROS frame id (text without spaces); got {reprlib.repr(frame)}")
    entries = document.get("signs")
    if not isinstance(entries, list) or not entries:
        raise MapError("signs must be a list of at least one sign")
    signs: dict[str, MappedSign] = {}
    for i, entry in enumerate(entries):
        sign = _mapped_sign(entry, f"signs[{i}]", library_ids)
        if sign.sign_id in signs:
            raise MapError(f"signs[{i}].id: {sign.sign_id!r} is given twice: keep one pose for each sign")
        signs[sign.sign_id] = sign
    return SignMap(signs=signs, frame=frame)


def _mapped_sign(entry: object, where: str, library_ids: Collection[str] | None) -> MappedSign:
    if not isinstance(entry, dict):
        raise MapError(f"{where} must be a mapping with id, position_m and orientation_wxyz")
    _refuse_unknown(entry, _SIGN_KEYS, where)
    sign_id = entry.get("id")
    if not isinstance(sign_id, str) or not sign_id:
        raise MapError(f"{where}.id must be a library sign id (text); got {reprlib.repr(sign_id)}")
    if library_ids is not None and sign_id not in library_ids:
        known = ", ".join(sorted(library_ids)) or "no signs"
        raise MapError(f"{where}.id: {sign_id!r} is not a sign of the library, which has {known}")
    if "position_m" not in entry:
        raise MapError(f"{where} ({sign_id}) has no position_m: give [x, y, z] in metres")
    position = _finite_vector(entry["position_m"], f"{where}.position_m", 3)
    if np.abs(position).max() > MAX_POSITION_M:
        raise MapError(f"{where}.position_m {[float(v) for v in position]} is more than {MAX_POSITION_M:g} m from the "
                       "map's origin: positions are metres (not millimetres)")
    given = [k for k in ("orientation_wxyz", "yaw_pitch_roll_deg") if k in entry]
    if len(given) != 1:
        raise MapError(f"{where} ({sign_id}) needs exactly one of orientation_wxyz and yaw_pitch_roll_deg; "
                       f"got {' and '.join(given) or 'neither'}")
    if given[0] == "orientation_wxyz":
        q = _finite_vector(entry["orientation_wxyz"], f"{where}.orientation_wxyz", 4)
        norm = float(np.linalg.norm(q))
        if abs(norm - 1.0) > QUATERNION_NORM_TOLERANCE:
            raise MapError(f"{where}.orientation_wxyz is not a unit quaternion (norm {norm:.6g}): "
                           "normalise it, or give yaw_pitch_roll_deg")
        R = rotation_from_quaternion_wxyz(q / norm)
    else:
        R = rotation_from_euler_zyx_deg(*_finite_vector(entry["yaw_pitch_roll_deg"], f"{where}.yaw_pitch_roll_deg", 3))
    covariance = entry.get("covariance")
    return MappedSign(sign_id=sign_id, R=R, position_m=position,
                      covariance=None if covariance is None else _covariance(covariance, f"{where}.covariance"))


def _refuse_unknown(fields: dict, known: tuple[str, ...], where: str) -> None:
    unknown = [k for k in fields if k not in known]
    if unknown:
        raise MapError(f"{where}: unknown key {reprlib.repr(unknown[0])} (known: {', '.join(known)})")


def _finite_vector(value: object, name: str, size: int) -> np.ndarray:
    """`value` as a (size,) float64 array; MapError naming `name` unless it is a list of `size` finite numbers."""
    if not isinstance(value, list) or len(value) != size:
        raise MapError(f"{name} must be a list of {size} numbers; got {reprlib.repr(value)}")
    for v in value:
        if not isinstance(v, Real) or isinstance(v, bool):
            shown = "null" if v is None else reprlib.repr(v)
            raise MapError(f"{name} must be {size} numbers; got {shown}")
        if not math.isfinite(v):
            raise MapError(f"{name} must be finite numbers; got {v}")
    return np.array(value, dtype=np.float64)


def _covariance(value: object, name: str) -> np.ndarray:
    """`value` as a (6, 6) covariance; MapError naming `name` unless it is a symmetric positive
    semi-definite matrix of finite numbers (rows, or 36 numbers row by row)."""
    if isinstance(value, list) and len(value) == 6 and all(isinstance(row, list) for row in value):
        rows = [_finite_vector(row, f"{name}[{i}]", 6) for i, row in enumerate(value)]
        matrix = np.array(rows)
    elif isinstance(value, list) and len(value) == 36:
        matrix = _finite_vector(value, name, 36).reshape(6, 6)
    else:
        raise MapError(f"{name} must be null, 6 rows of 6 numbers or 36 numbers (ROS order: x, y, z, "
                       "rotation about x, y, z)")
    scale = max(float(np.abs(matrix).max()), 1e-300)
    if np.abs(matrix - matrix.T).max() > 1e-9 * scale:
        raise MapError(f"{name} is not symmetric")
    if np.linalg.eigvalsh(matrix).min() < -1e-9 * scale:
        raise MapError(f"{name} is not positive semi-definite (a variance cannot be negative)")
    return matrix


def sign_map_yaml(sign_map: SignMap, comments: dict[str, Iterable[str]] | None = None) -> str:
    """The map file's YAML text of `sign_map`: orientation as a quaternion, with yaw, pitch and roll in
    a comment for people; `comments` adds lines under a sign (e.g. how a survey saw it)."""
    lines = [f"frame: {sign_map.frame}", "signs:"]
    for sign in sign_map.signs.values():
        yaw, pitch, roll = euler_zyx_deg(sign.R)
        lines += [f"  - id: {yaml.safe_dump(sign.sign_id, default_style=None).splitlines()[0]}",
                  f"    position_m: [{', '.join(_number(v) for v in sign.position_m)}]",
                  f"    orientation_wxyz: [{', '.join(_number(v) for v in quaternion_wxyz(sign.R))}]"
                  f"  # yaw, pitch, roll {yaw:.3f}, {pitch:.3f}, {roll:.3f} degrees"]
        if sign.covariance is None:
            lines.append("    covariance: null")
        else:
            lines.append("    covariance:")
            lines += [f"      - [{', '.join(_number(v) for v in row)}]" for row in sign.covariance]
        lines += [f"    # {line}" for line in (comments or {}).get(sign.sign_id, ())]
    return "\n".join(lines) + "\n"


def _number(value: float) -> str:
    """`value` with the digits that read back as the same float64."""
    return repr(float(value))


def save_sign_map(sign_map: SignMap, path: str | Path, comments: dict[str, Iterable[str]] | None = None) -> None:
    """Write `sign_map` to `path` as YAML (`sign_map_yaml`)."""
    Path(path).write_text(sign_map_yaml(sign_map, comments))
