"""The map file: round trip, the Euler form, and every kind of bad map refused in one line naming the field."""

import json
from pathlib import Path

import numpy as np
import pytest

from signpose.pipeline.pose import rotation_error_deg, rotation_from_euler_zyx_deg
from signpose.pipeline.sign_map import MapError, MappedSign, SignMap, load_sign_map, save_sign_map

IDS = ("security_compound", "ministry_of_torture", "chief_of_security")

MAP = """frame: building
signs:
  - id: security_compound
    position_m: [0, 0, 0]
    orientation_wxyz: [1, 0, 0, 0]
  - id: ministry_of_torture
    position_m: [4.5, 0.0, 0.1]
    yaw_pitch_roll_deg: [90, 0, 0]
    covariance: null
"""


def write(tmp_path: Path, text: str, name: str = "map.yaml") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def test_map_file_reads_quaternion_and_euler_forms(tmp_path):
    sign_map = load_sign_map(write(tmp_path, MAP), IDS)
    assert sign_map.frame == "building" and list(sign_map.signs) == ["security_compound", "ministry_of_torture"]
    ministry = sign_map.signs["ministry_of_torture"]
    # yaw 90 degrees about the map's z: the sign's x axis points along the map's y
    np.testing.assert_allclose(ministry.to_map(np.array([[1.0, 0.0, 0.0]])), [[4.5, 1.0, 0.1]], atol=1e-12)
    assert ministry.covariance is None


def test_map_file_round_trips_with_covariance(tmp_path):
    rng = np.random.default_rng(3)
    A = rng.normal(size=(6, 6))
    sign_map = SignMap(frame="map", signs={
        "chief_of_security": MappedSign(sign_id="chief_of_security", R=rotation_from_euler_zyx_deg(-30.5, 12.25, 179.0),
                                        position_m=np.array([1.0 / 3, -2.0, 7.125]), covariance=A @ A.T * 1e-6)})
    path = tmp_path / "out.yaml"
    save_sign_map(sign_map, path, comments={"chief_of_security": ["seen in 12 images"]})
    back = load_sign_map(path, IDS).signs["chief_of_security"]
    original = sign_map.signs["chief_of_security"]
    assert rotation_error_deg(back.R, original.R) < 1e-9
    np.testing.assert_array_equal(back.position_m, original.position_m)
    np.testing.assert_array_equal(back.covariance, original.covariance)
    assert "# seen in 12 images" in path.read_text()
    # and JSON, as to_json writes it
    json_path = write(tmp_path, json.dumps(sign_map.to_json()), "map.json")
    assert rotation_error_deg(load_sign_map(json_path).signs["chief_of_security"].R, original.R) < 1e-9


def covariance_text(diagonal: list[int], corner: int = 0) -> str:
    """A 6x6 covariance in rows, `diagonal` on the diagonal and `corner` at (0, 1) only (not symmetric unless 0)."""
    rows = [[diagonal[i] if i == j else 0 for j in range(6)] for i in range(6)]
    rows[0][1] = corner
    return json.dumps(rows)


@pytest.mark.parametrize("text, message", [
    ("", "an empty file"),
    ("signs: [", "neither valid YAML nor JSON"),
    ("- 1\n- 2\n", "expected a mapping with `signs:`"),
    ("signs: []\n", "signs must be a list of at least one sign"),
    ("frame: my map\nsigns: []\n", "frame must be a ROS frame id"),
    ("signz: []\n", "the map: unknown key 'signz'"),
    ("signs:\n  - id: nowhere\n    position_m: [0, 0, 0]\n    orientation_wxyz: [1, 0, 0, 0]\n",
     "signs[0].id: 'nowhere' is not a sign of the library, which has chief_of_security, ministry_of_torture, "
     "security_compound"),
    ("signs:\n  - {id: security_compound, position_m: [0, 0, 0], orientation_wxyz: [1, 0, 0, 0]}\n"
     "  - {id: security_compound, position_m: [1, 0, 0], orientation_wxyz: [1, 0, 0, 0]}\n",
     "signs[1].id: 'security_compound' is given twice"),
    ("signs:\n  - {id: security_compound, position_m: [0, .nan, 0], orientation_wxyz: [1, 0, 0, 0]}\n",
     "signs[0].position_m must be finite numbers; got nan"),
    ('{"signs": [{"id": "security_compound", "position_m": [0, NaN, 0], "orientation_wxyz": [1, 0, 0, 0]}]}',
     "signs[0].position_m must be finite numbers; got nan"),
    ("signs:\n  - {id: security_compound, position_m: [1e300, 0, 0], orientation_wxyz: [1, 0, 0, 0]}\n",
     "signs[0].position_m [1e+300, 0.0, 0.0] is more than 10000 m from the map's origin"),
    ("signs:\n  - {id: security_compound, position_m: [0, 0], orientation_wxyz: [1, 0, 0, 0]}\n",
     "signs[0].position_m must be a list of 3 numbers"),
    ("signs:\n  - {id: security_compound, position_m: [0, '1', 0], orientation_wxyz: [1, 0, 0, 0]}\n",
     "signs[0].position_m must be 3 numbers; got '1'"),
    ("signs:\n  - {id: security_compound, orientation_wxyz: [1, 0, 0, 0]}\n",
     "signs[0] (security_compound) has no position_m"),
    ("signs:\n  - {id: security_compound, position_m: [0, 0, 0], orientation_wxyz: [0.9, 0, 0, 0]}\n",
     "signs[0].orientation_wxyz is not a unit quaternion (norm 0.9)"),
    ("signs:\n  - {id: security_compound, position_m: [0, 0, 0]}\n",
     "signs[0] (security_compound) needs exactly one of orientation_wxyz and yaw_pitch_roll_deg; got neither"),
    ("signs:\n  - {id: security_compound, position_m: [0, 0, 0], orientation_wxyz: [1, 0, 0, 0], "
     "yaw_pitch_roll_deg: [0, 0, 0]}\n",
     "signs[0] (security_compound) needs exactly one of orientation_wxyz and yaw_pitch_roll_deg; got orientation_wxyz "
     "and yaw_pitch_roll_deg"),
    ("signs:\n  - {id: security_compound, position_m: [0, 0, 0], orientation_wxyz: [1, 0, 0, 0], colour: red}\n",
     "signs[0]: unknown key 'colour'"),
    ("signs:\n  - {id: security_compound, position_m: [0, 0, 0], orientation_wxyz: [1, 0, 0, 0], covariance: [1, 2]}\n",
     "signs[0].covariance must be null, 6 rows of 6 numbers or 36 numbers"),
    ("signs:\n  - {id: security_compound, position_m: [0, 0, 0], orientation_wxyz: [1, 0, 0, 0], covariance: "
     f"{covariance_text([1] * 6, corner=1)}}}\n", "signs[0].covariance is not symmetric"),
    ("signs:\n  - {id: security_compound, position_m: [0, 0, 0], orientation_wxyz: [1, 0, 0, 0], covariance: "
     f"{covariance_text([-1] + [1] * 5)}}}\n", "signs[0].covariance is not positive semi-definite"),
    ("a: &x [1]\nb: *x\n", "line 2, column 4: YAML alias *x: map files are read without anchors"),
])
def test_a_bad_map_file_is_refused_in_one_line_naming_the_field(tmp_path, text, message):
    path = write(tmp_path, text)
    with pytest.raises(MapError) as info:
        load_sign_map(path, IDS)
    assert str(info.value).startswith(f"{path}: {message}"), str(info.value)
    assert "\n" not in str(info.value)


def test_a_missing_map_file_or_a_folder_is_named(tmp_path):
    with pytest.raises(MapError, match="map file not found"):
        load_sign_map(tmp_path / "none.yaml")
    with pytest.raises(MapError, match="is a folder"):
        load_sign_map(tmp_path)
