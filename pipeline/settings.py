"""Every tunable parameter of the pipeline, in one typed model.

The same `Settings` serves the CLI (`--settings FILE`, `--preset`), the HTTP API
(`GET/PUT /api/settings`), the web form and the viser sliders: each field carries
its group, range or choices and a one-line help text in its metadata, and
`settings_schema()` exposes them so no front end keeps its own copy. The metadata
also names the pipeline stages the field feeds ("stages", names of `stages.ALL_STAGES`),
from which the stage cache keys are made; it is the pipeline's own, not in the schema.
"""

from __future__ import annotations

import dataclasses
import json
import math
import reprlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .jsonfile import read_json


class SettingsError(ValueError):
    """A settings value or file that cannot be used; the message says which and why."""


def _num(default, lo, hi, group, help, step=None, nullable=False, *, stages: tuple[str, ...]):
    return field(
        default=default,
        metadata={"group": group, "min": lo, "max": hi, "step": step, "help": help, "nullable": nullable,
                  "stages": stages},
    )


def _choice(default, choices, group, help, *, stages: tuple[str, ...]):
    return field(default=default, metadata={"group": group, "choices": tuple(choices), "help": help, "stages": stages})


def _flag(default, group, help, *, stages: tuple[str, ...]):
    return field(default=default, metadata={"group": group, "help": help, "stages": stages})


SEGMENT_MODES = ("threshold", "none")
NORMALIZATIONS = ("scale", "minmax")
DETECTORS = ("sift", "orb")
RANSAC_METHODS = ("own", "cv2_ransac", "usac_magsac", "usac_accurate")
POSE_METHODS = ("paper", "ippe", "ippe_lm")
REFINE_METHODS = ("auto", "ecc", "none")


@dataclass(frozen=True)
class Settings:
    """All pipeline parameters. Pixel values are in the input image unless stated."""

    # Segmentation
    segment_mode: str = _choice("threshold", SEGMENT_MODES, "Segmentation",
                                "threshold: find bright plaques first; none: search the full frame",
                                # the full frame keeps its size when it is the search itself (full_frame_scale)
                                stages=("segment", "features", "refine"))
    normalization: str = _choice("minmax", NORMALIZATIONS, "Segmentation",
                                 "Grayscale to [0,1]: scale divides by 255, minmax stretches min..max (the paper)",
                                 stages=("segment",))
    threshold: float = _num(0.75, 0.0, 1.0, "Segmentation",
                            "Normalised gray level above which a pixel counts as white", step=0.01,
                            stages=("segment", "quads"))
    high_threshold: float | None = _num(None, 0.0, 1.0, "Segmentation",
                                        "Optional upper gate: pixels brighter than this are not sign (glare)",
                                        step=0.01, nullable=True, stages=("segment",))
    candidates: int = _num(3, 1, 10, "Segmentation", "How many of the largest white blobs to try, largest first",
                           step=1, stages=("segment",))
    crop_margin: float = _num(0.15, 0.0, 1.0, "Segmentation",
                              "Margin added around a blob's bounding box, as a fraction of its size", step=0.01,
                              stages=("segment", "regions"))
    min_blob_area: float = _num(0.0005, 0.0, 0.5, "Segmentation",
                                "Smallest blob worth trying, as a fraction of the image area", step=0.0001,
                                stages=("segment",))
    plaque_candidates: int = _num(2, 0, 10, "Segmentation",
                                  "Then search this many plaque-shaped regions found at lower gray levels, best "
                                  "correlation with a sign first (one crop instead of the full frame when a lamp "
                                  "pushed the sign below the threshold); with any, a largest blob that reads as "
                                  "no sign (no text in it, or a plaque of other words) is searched after them",
                                  step=1, stages=("regions",))
    full_frame_fallback: bool = _flag(True, "Segmentation",
                                      "Search the full frame when no candidate blob yields a sign", stages=("regions",))
    zoom_fallback: bool = _flag(True, "Segmentation",
                                "When the full frame names no sign, search again, at twice its resolution, the "
                                "window where its matches crowd most (a small or dim sign whose plaque no "
                                "threshold cuts out)", stages=("regions",))

    # Features
    detector: str = _choice("sift", DETECTORS, "Features", "Local feature detector and descriptor",
                            stages=("library features", "features"))
    max_features: int = _num(2000, 50, 20000, "Features", "Most keypoints kept per image (strongest first)", step=50,
                             stages=("library features", "features"))
    min_crop_size: int = _num(128, 0, 2000, "Features",
                              "Crops whose longer side is below this many px are upscaled to it before detection",
                              step=10, stages=("features",))
    max_crop_size: int = _num(160, 0, 8000, "Features",
                              "Crops (not the full frame) whose longer side is above this many px are downscaled "
                              "to it before detection; 0: never", step=10, stages=("features",))
    max_search_size: int = _num(2048, 0, 20000, "Features",
                                "Any region, the full frame included, whose longer side is above this many px is "
                                "downscaled to it before detection (SIFT on a 12 MP frame took 2.8 GB and 8 s); "
                                "0: never", step=64, stages=("features",))
    full_frame_scale: float = _num(1.0, 0.1, 1.0, "Features",
                                   "The full-frame fallback (after the candidate regions) searches the frame shrunk by "
                                   "this factor (SIFT's first octave doubles it again); searched without segmentation, "
                                   "or for a library holding a picture, it keeps its size; 1: never shrunk (0.75 halves what a frame "
                                   "without a sign costs, and misses some small, dim and steep signs)", step=0.05,
                                   stages=("features",))
    contrast_threshold: float = _num(0.03, 0.001, 0.2, "Features",
                                     "SIFT contrast threshold: lower finds more, weaker keypoints", step=0.001,
                                     stages=("library features", "features"))

    affine_fallback: bool = _flag(True, "Features",
                                  "When neither features nor the plaque fallback name a sign, match the regions' "
                                  "features with simulated steep views of each sign (ASIFT tilts 2-4: 60-76 degrees "
                                  "off its normal), computed once per library", stages=("affine match",))

    # Matching
    ratio: float = _num(0.75, 0.3, 1.0, "Matching",
                        "Lowe's distance-ratio test: keep a match when best < ratio x second best", step=0.01,
                        stages=("match", "affine match"))

    # RANSAC
    ransac_method: str = _choice("own", RANSAC_METHODS, "RANSAC",
                                 "own: the paper's fixed-iteration RANSAC on 4-point DLT; others: OpenCV backends",
                                 stages=("ransac",))
    ransac_iterations: int = _num(500, 1, 100000, "RANSAC", "Hypotheses drawn (own RANSAC: exactly this many)", step=1,
                                  stages=("ransac",))
    ransac_threshold_px: float = _num(4.0, 0.1, 50.0, "RANSAC",
                                      "Reprojection distance in image px under which a match is an inlier", step=0.1,
                                      stages=("ransac",))
    ransac_confidence: float = _num(0.999, 0.5, 0.999999, "RANSAC",
                                    "Confidence for adaptive stopping (OpenCV backends, and own with ransac_adaptive)",
                                    step=0.001, stages=("ransac",))
    ransac_adaptive: bool = _flag(True, "RANSAC",
                                  "Own RANSAC: stop before ransac_iterations once ransac_confidence is reached",
                                  stages=("ransac",))
    seed: int = _num(0, 0, 2**31 - 1, "RANSAC", "Random seed: the same seed gives the same answer", step=1,
                     stages=("ransac", "refine"))

    # Decision
    min_matches: int = _num(8, 4, 1000, "Decision", "A sign with fewer ratio-test matches is rejected", step=1,
                            stages=("ransac", "decide"))
    min_inliers: int = _num(10, 4, 1000, "Decision", "A sign with fewer RANSAC inliers is rejected", step=1,
                            stages=("decide",))
    min_margin: int = _num(5, 0, 1000, "Decision",
                           "The winner needs this many more inliers than the runner-up", step=1,
                           stages=("ransac", "decide"))
    min_text_correlation: float = _num(0.75, 0.0, 1.0, "Decision",
                                       "The winner's text, rectified, must correlate with its sign's this much in "
                                       "each of 6 strips across it (turns down other signs sharing a word); "
                                       "0: no check", step=0.01, stages=("text check",))
    min_picture_correlation: float = _num(0.5, 0.0, 1.0, "Decision",
                                          "The same for a landmark of kind picture (a poster, a box, a photo), its "
                                          "light evened out: the median of its 6 strips must reach this; a library "
                                          "entry's own min_text_correlation replaces either", step=0.01,
                                          stages=("text check",))

    # Plaque fallback
    plaque_fallback: bool = _flag(True, "Plaque",
                                  "When features fail, read white quad blobs as plaques: outline, correlation, ECC",
                                  stages=("plaque",))
    min_plaque_ncc: float = _num(0.6, 0.0, 1.0, "Plaque",
                                 "Least correlation between a rectified blob and a library sign to accept it",
                                 step=0.01, stages=("plaque",))
    plaque_margin: float = _num(0.15, 0.0, 1.0, "Plaque",
                                "The best sign's correlation must beat the runner-up's by this much", step=0.01,
                                stages=("plaque",))

    plaque_search: bool = _flag(True, "Plaque",
                                "When the plaque fallback finds nothing, look for quadrilateral plaques at lower gray "
                                "levels too and accept one only after dense (ECC) alignment with a sign, or where "
                                "that falls short (shadow, glare, a steep view) when its outline is found and its text "
                                "passes the check",
                                stages=("plaque",))
    min_plaque_ecc: float = _num(0.85, 0.0, 1.0, "Plaque",
                                 "Plaque fallback and search: least correlation after dense alignment to accept a "
                                 "sign (plaques under 60 x 60 px need more)", step=0.01, stages=("plaque",))
    plaque_ecc_margin: float = _num(0.1, 0.0, 1.0, "Plaque",
                                    "Plaque search: the sign's aligned correlation must beat the next sign's by this "
                                    "much", step=0.01, stages=("plaque",))

    # Pose
    refine: str = _choice("auto", REFINE_METHODS, "Pose",
                          "ecc: align the sign densely to refine H; auto: only when the winner has few inliers "
                          "(there it beats the points; with many it is slightly worse), and with many only to look "
                          "again for outline edges missed; the plaque fallback always refines", stages=("refine",))
    refine_outline: bool = _flag(True, "Pose",
                                 "Refine the winner's homography from the plaque's four straight edges (needs a "
                                 "library image cropped to the sign's edges); falls back to refine when an edge "
                                 "is not found; not used with segment_mode none", stages=("refine",))
    edge_gamma: float = _num(2.2, 1.0, 3.0, "Pose",
                             "The images' encoding gamma (2.2: sRGB cameras, JPEG and video; 1: linear data such as "
                             "mono16 or raw frames): the plaque's edges are read in linear light, where a blurred "
                             "edge is symmetric about its place",
                             step=0.1, stages=("refine",))
    pose_method: str = _choice("ippe_lm", POSE_METHODS, "Pose",
                               "paper: decompose H; ippe: planar PnP on all inliers; ippe_lm: ippe refined by LM",
                               stages=("pose",))
    ambiguity_ratio: float = _num(0.8, 0.0, 1.0, "Pose",
                                  "Flag ambiguous when best / second IPPE error exceeds this", step=0.01,
                                  stages=("pose",))

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            # Frozen, so set through object: a whole number written as 2.0 (JSON writers, sliders)
            # is stored as the int 2, which the pipeline slices and counts with.
            object.__setattr__(self, f.name, _check_field(f, getattr(self, f.name)))
        if self.high_threshold is not None and self.high_threshold <= self.threshold:
            raise SettingsError(
                f"high_threshold ({self.high_threshold}) must be above threshold ({self.threshold}), or null"
            )
        # A crop below min_crop_size is upscaled to it, and one above max_crop_size downscaled: both at once say
        # nothing of the size detection runs at.
        if 0 < self.max_crop_size < self.min_crop_size:
            raise SettingsError(f"min_crop_size ({self.min_crop_size}) must be at most max_crop_size "
                                f"({self.max_crop_size}), or max_crop_size 0 (never downscale)")

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    def replace(self, **changes: Any) -> Settings:
        """A copy with `changes` applied and validated; unknown keys are an error."""
        return Settings.from_dict({**self.to_dict(), **changes})

    @classmethod
    def from_dict(cls, data: dict[str, Any], base: Settings | None = None) -> Settings:
        """Build from a full or partial dict; missing keys come from `base` (default: `Settings()`)."""
        if not isinstance(data, dict):
            raise SettingsError(f"settings must be a JSON object, got {shown(data)}")
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - known)
        if unknown:
            raise SettingsError(f"unknown setting(s): {shown(unknown)[1:-1]}; known: {', '.join(sorted(known))}")
        merged = {**(base or cls()).to_dict(), **data}
        return cls(**merged)


class _JsonRepr(reprlib.Repr):
    """reprlib's shortening in JSON's words (true, null, "text", Infinity): settings files and requests are
    JSON, and Python's True or ['a'] is not what their author wrote."""

    def repr_bool(self, x: bool, level: int) -> str:
        return "true" if x else "false"

    def repr_NoneType(self, x: None, level: int) -> str:  # noqa: N802 (reprlib's name for it)
        return "null"

    def repr_str(self, x: str, level: int) -> str:
        return '"' + super().repr_str(x, level)[1:-1] + '"'

    def repr_float(self, x: float, level: int) -> str:
        return repr(x) if math.isfinite(x) else "NaN" if math.isnan(x) else "Infinity" if x > 0 else "-Infinity"


shown = _JsonRepr().repr


def check_setting(name: str, value: Any) -> Any:
    """`value` as setting `name` holds it, checked on its own, not against the other settings; SettingsError if
    invalid (KeyError for no setting)."""
    return _check_field({f.name: f for f in dataclasses.fields(Settings)}[name], value)


def _is_int_field(f: dataclasses.Field) -> bool:
    """Whether the setting `f` takes whole numbers (bool is an int subclass, but a flag)."""
    return isinstance(f.default, int) and not isinstance(f.default, bool)


def _check_field(f: dataclasses.Field, value: Any) -> Any:
    """`value` as setting `f` holds it (an int field's integral float as an int); SettingsError if invalid."""
    meta = f.metadata
    name = f.name
    if value is None:
        if meta.get("nullable"):
            return value
        raise SettingsError(f"{name} must not be null")
    if "choices" in meta:
        if value not in meta["choices"]:
            raise SettingsError(f"{name} must be one of {', '.join(meta['choices'])}; got {shown(value)}")
        return value
    if isinstance(f.default, bool):
        if not isinstance(value, bool):
            raise SettingsError(f"{name} must be true or false; got {shown(value)}")
        return value
    is_int = _is_int_field(f)
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise SettingsError(f"{name} must be a number; got {shown(value)}")
    # Only floats can be non-finite or fractional; float() of a huge JSON integer would overflow.
    if isinstance(value, float) and not math.isfinite(value):
        raise SettingsError(f"{name} must be finite; got {shown(value)}")
    if is_int and isinstance(value, float) and not value.is_integer():
        raise SettingsError(f"{name} must be a whole number; got {shown(value)}")
    if not meta["min"] <= value <= meta["max"]:
        raise SettingsError(f"{name} must be between {meta['min']} and {meta['max']}; got {shown(value)}")
    return int(value) if is_int else value


def settings_schema() -> list[dict[str, Any]]:
    """One entry per field: name, type, group, default, min/max/step or choices, help."""
    out = []
    for f in dataclasses.fields(Settings):
        meta = {k: v for k, v in f.metadata.items() if k != "stages"}
        if "choices" in meta:
            kind = "choice"
        elif isinstance(f.default, bool):
            kind = "bool"
        elif f.type in ("int",) or _is_int_field(f):
            kind = "int"
        else:
            kind = "float"
        entry = {"name": f.name, "type": kind, "default": f.default, **meta}
        if "choices" in entry:
            entry["choices"] = list(entry["choices"])
        out.append(entry)
    return out


PRESETS: dict[str, Settings] = {
    # The published method as described: minmax normalisation, threshold 0.75, the largest
    # blob only, ratio 1/1.5 (VLFeat's default), own RANSAC with 50 iterations, H decomposition.
    "paper": Settings(
        normalization="minmax",
        threshold=0.75,
        candidates=1,
        plaque_candidates=0,
        full_frame_fallback=False,
        zoom_fallback=False,
        min_crop_size=0,
        max_crop_size=0,
        affine_fallback=False,
        ratio=0.667,
        ransac_method="own",
        ransac_iterations=50,
        ransac_adaptive=False,
        min_inliers=4,
        min_margin=0,
        min_text_correlation=0.0,
        plaque_fallback=False,
        refine="none",
        refine_outline=False,
        pose_method="paper",
    ),
    "default": Settings(),
}


def preset(name: str) -> Settings:
    try:
        return PRESETS[name]
    except KeyError:
        raise SettingsError(f"unknown preset {name!r}; choose from {', '.join(PRESETS)}") from None


def file_settings(data: Any) -> Any:
    """The settings a file's JSON `data` holds: itself, or, saved from `GET /api/settings`, the "settings"
    of its {"version", "settings"}, which import and --settings refused as two unknown settings."""
    if isinstance(data, dict) and set(data) == {"version", "settings"}:
        return data["settings"]
    return data


def load_settings(path: str | Path, base: Settings | None = None) -> Settings:
    """Read settings JSON (full or partial, or as `GET /api/settings` answers) from `path`; SettingsError
    naming the file."""
    data = file_settings(read_json(Path(path), SettingsError, "settings file"))
    try:
        return Settings.from_dict(data, base=base)
    except SettingsError as exc:
        raise SettingsError(f"{path}: {exc}") from None


def save_settings(settings: Settings, path: str | Path) -> None:
    Path(path).write_text(json.dumps(settings.to_dict(), indent=2) + "\n", encoding="utf-8")
