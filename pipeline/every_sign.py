"""Every library sign in one image: `recognize` again with the signs already found masked out;
and one sign where it is expected: `recognize` of its neighbourhood alone (`recognize_near`).

`recognize` answers with the one region that decides. A photo or frame with two signs in view
holds two answers: after each sign found, the image is searched again with its quad (and any
quads the caller already knows, such as tracked signs) filled with the image's median gray, so
the next search finds another sign or none.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass

import cv2
import numpy as np

from .camera import Camera, CameraError
from .image import to_gray
from .outline import Outline
from .library import Library
from .pose import Pose
from .recognize import Recognition, recognize
from .settings import Settings

# A quad masked out for the next search is grown about its centre by this fraction, so that the
# plaque's rim and its edge features do not make a blob of their own.
MASK_GROWTH = 0.15
# Searches of one image: its signs plus the one that finds no more. A building's door shows one
# sign, a corridor view two or three.
MAX_SEARCHES = 4
# `recognize_near` cuts out the box of the quad grown by this fraction of its size on every side: room
# for a sign that moved a little since the quad was seen, and for the wall around its plaque.
NEAR_MARGIN = 0.5


@dataclass(frozen=True, eq=False)
class SignSeen:
    """A sign found in an image as a map needs it (`map_build.observations_of`, `localise.locate_in_map`),
    without the recognition's intermediates: its `label` (None: no sign), `corners` (4, 2) image px
    (TL, TR, BR, BL) and measured `pose` (None where there is none)."""

    label: str | None
    corners: np.ndarray | None
    pose: Pose | None

    @classmethod
    def of(cls, recognition: Recognition) -> SignSeen:
        return cls(recognition.label, recognition.corners, recognition.pose)

    def to_json(self) -> dict:
        """One entry of the JSON's `signs` (`signpose recognize --json`): {"label", "corners", "pose"}."""
        return {"label": self.label, "corners": None if self.corners is None else np.asarray(self.corners, float).tolist(),
                "pose": None if self.pose is None else self.pose.to_json()}


def mask_quads(gray: np.ndarray, quads: Sequence[np.ndarray]) -> np.ndarray:
    """A copy of (H, W) uint8 `gray` with each (4, 2) image px quad, grown by MASK_GROWTH, filled
    with the image's median gray: flat, neither a white blob nor a dark frame around one."""
    if not quads:
        return gray
    out = gray.copy()
    fill = int(np.median(gray[::4, ::4]))
    for quad in quads:
        centre = quad.mean(axis=0)
        grown = centre + (quad - centre) * (1 + MASK_GROWTH)
        cv2.fillConvexPoly(out, np.round(grown).astype(np.int32), fill)
    return out


def recognize_every_sign(image: np.ndarray, library: Library, settings: Settings, camera: Camera | None = None, *,
                         known: Sequence[np.ndarray] = (), most: int = MAX_SEARCHES,
                         plaque_search_shrink: int = 1) -> list[Recognition]:
    """The recognitions of `image` ((H, W, 3) BGR or (H, W) gray uint8), one a search: each search
    masks out the quads ((4, 2) image px, TL TR BR BL) of the signs found before it and of `known`.
    Stops at the first search that finds no sign, or after `most` searches; the last recognition is
    then the one without a sign (the list is never empty). A search beside found or known signs
    leaves out the full-frame fallback: a further sign is a plaque of its own, found among the
    blobs, and the fallback is the costliest part of a search that finds nothing.

    Each recognition's image px are those of `image` (masking keeps the size); `plaque_search_shrink`
    as for `recognize`."""
    gray = to_gray(image)
    beside = dataclasses.replace(settings, full_frame_fallback=False)
    hidden = list(known)
    recognitions: list[Recognition] = []
    for _ in range(most):
        rec = recognize(mask_quads(gray, hidden) if hidden else image, library, beside if hidden else settings, camera,
                        plaque_search_shrink=plaque_search_shrink)
        recognitions.append(rec)
        if rec.label is None or rec.corners is None:
            break
        hidden.append(rec.corners)
    return recognitions


@dataclass(frozen=True, eq=False)
class Nearby:
    """What `recognize_near` found: the `recognition` of the neighbourhood cut from the image (its
    image px are the cut's) and `offset`, the cut's top-left corner (x0, y0) in the image's px."""

    recognition: Recognition
    offset: tuple[int, int]

    @property
    def shift(self) -> np.ndarray:
        """(3, 3) the cut's px -> the image's px."""
        return np.array([[1.0, 0, self.offset[0]], [0, 1, self.offset[1]], [0, 0, 1]])

    @property
    def H(self) -> np.ndarray | None:
        """(3, 3) library px -> the image's px, or None."""
        H = self.recognition.H
        return None if H is None else self.shift @ H

    @property
    def outline(self) -> Outline | None:
        """The plaque outline that placed the sign, in the image's px, or None."""
        outline = self.recognition.outline
        return None if outline is None else outline.moved(self.shift)

    @property
    def corners(self) -> np.ndarray | None:
        """(4, 2) the image's px of the sign's TL, TR, BR, BL, or None."""
        corners = self.recognition.corners
        return None if corners is None else corners + self.offset


def recognize_near(image: np.ndarray, library: Library, settings: Settings, camera: Camera, *,
                   quad: np.ndarray, with_pose: bool = True) -> Nearby:
    """`recognize` of the neighbourhood of `quad` ((4, 2) image px, TL TR BR BL: where a sign was
    last seen) in `image` ((H, W, 3) BGR or (H, W) gray uint8, `camera`'s): the quad's box grown
    by NEAR_MARGIN of its size on every side is cut out and searched with the camera of the cut (its
    principal point moved with it), without the full-frame fallback (a library of pictures alone, which
    is not segmented, has the whole cut searched). A check of a known sign costing a fraction of a search of the whole
    frame (the same text check; the affine fallback as `settings` say, for a sign turned steeply
    away), its pose in `camera`'s frame (None without `with_pose`, as for `recognize`)."""
    gray = to_gray(image)
    height, width = gray.shape
    low, high = quad.min(axis=0), quad.max(axis=0)
    grow = (high - low) * NEAR_MARGIN
    x0, y0 = np.clip(np.floor(low - grow).astype(int), 0, [width - 1, height - 1])
    x1, y1 = np.clip(np.ceil(high + grow).astype(int) + 1, [x0 + 1, y0 + 1], [width, height])
    cut = gray[y0:y1, x0:x1]
    K = camera.K.copy()
    K[:2, 2] -= (x0, y0)
    try:
        cut_camera = Camera(K, camera.dist, width=int(x1 - x0), height=int(y1 - y0), source=camera.source)
    except CameraError:
        # A cut the camera checks refuse (a lens whose distortion is bounded over the whole frame
        # only): the whole frame is searched, flat outside the cut.
        flat = np.full_like(gray, int(np.median(gray[::4, ::4])))
        flat[y0:y1, x0:x1] = cut
        cut, cut_camera, x0, y0 = flat, camera, 0, 0
    local = dataclasses.replace(settings, full_frame_fallback=False)
    return Nearby(recognize(cut, library, local, cut_camera, with_pose=with_pose), (int(x0), int(y0)))
