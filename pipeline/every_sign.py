"""Every library sign in one image: `recognize` again with the signs already found masked out.

`recognize` answers with the one region that decides. A photo or frame with two signs in view
holds two answers: after each sign found, the image is searched again with its quad (and any
quads the caller already knows, such as tracked signs) filled with the image's median gray, so
the next search finds another sign or none.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import cv2
import numpy as np

from .camera import Camera
from .image import to_gray
from .library import Library
from .recognize import Recognition, recognize
from .settings import Settings

# A quad masked out for the next search is grown about its centre by this fraction, so that the
# plaque's rim and its edge features do not make a blob of their own.
MASK_GROWTH = 0.15
# Searches of one image: its signs plus the one that finds no more. A building's door shows one
# sign, a corridor view two or three.
MAX_SEARCHES = 4
# `recognize_near` keeps the box of the quad grown by this fraction of its size on every side: room
# for a sign that moved a little since the quad was seen, and for the wall around its plaque.
NEAR_MARGIN = 0.5


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
                         known: Sequence[np.ndarray] = (), most: int = MAX_SEARCHES) -> list[Recognition]:
    """The recognitions of `image` ((H, W, 3) BGR or (H, W) gray uint8), one a search: each search
    masks out the quads ((4, 2) image px, TL TR BR BL) of the signs found before it and of `known`.
    Stops at the first search that finds no sign, or after `most` searches; the last recognition is
    then the one without a sign (the list is never empty). A search beside found or known signs
    leaves out the full-frame fallback: a further sign is a plaque of its own, found among the
    blobs, and the fallback is the costliest part of a search that finds nothing.

    Each recognition's image px are those of `image` (masking keeps the size)."""
    gray = to_gray(image)
    beside = dataclasses.replace(settings, full_frame_fallback=False)
    hidden = list(known)
    recognitions: list[Recognition] = []
    for _ in range(most):
        rec = recognize(mask_quads(gray, hidden) if hidden else image, library, beside if hidden else settings, camera)
        recognitions.append(rec)
        if rec.label is None or rec.corners is None:
            break
        hidden.append(rec.corners)
    return recognitions


def recognize_near(image: np.ndarray, library: Library, settings: Settings, camera: Camera | None, *,
                   quad: np.ndarray) -> Recognition:
    """`recognize` of the neighbourhood of `quad` ((4, 2) image px, TL TR BR BL: where a sign was
    last seen) in `image` ((H, W, 3) BGR or (H, W) gray uint8): the image outside the quad's box,
    grown by NEAR_MARGIN, is filled with its median gray, and the search leaves out the full-frame
    and affine fallbacks, which look for a sign anywhere. A check of a known sign costing a
    fraction of a search of the whole frame, with the same text check; its image px are `image`'s."""
    gray = to_gray(image)
    height, width = gray.shape
    centre, half = (quad.max(axis=0) + quad.min(axis=0)) / 2, (quad.max(axis=0) - quad.min(axis=0)) / 2
    x0, y0 = np.maximum(np.floor(centre - half * (1 + 2 * NEAR_MARGIN)).astype(int), 0)
    x1, y1 = np.minimum(np.ceil(centre + half * (1 + 2 * NEAR_MARGIN)).astype(int) + 1, [width, height])
    near = np.full_like(gray, int(np.median(gray[::4, ::4])))
    near[y0:y1, x0:x1] = gray[y0:y1, x0:x1]
    local = dataclasses.replace(settings, full_frame_fallback=False, affine_fallback=False)
    return recognize(near, library, local, camera)
