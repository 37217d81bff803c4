"""The camera calibration session of `signpose serve`: chessboard photos, the board found in each
and the intrinsics fitted to them (pipeline/calibrate.py does the work; docs/calibration.md says how
to take the photos).

One session per server, shared by everyone using it, like the Workspace. It lives in memory only:
the photos are a means to a camera, and the camera, once applied, is kept by the Workspace.
Detection and fitting run in the caller's thread (a request worker, off the event loop). Every change
is published (`CalibrationSession(publish=...)`), so that a client showing the session sees what
another one did.
"""

from __future__ import annotations

import dataclasses
import secrets
import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import numpy as np

from signpose.pipeline.calibrate import (MIN_VIEWS, BoardView, Calibration, CalibrationError, calibrate,
                                check_board, check_square, drop_outliers, find_board, other_sizes, outlier_advice,
                                reference_size, size_mismatch, too_few_boards_advice)
from signpose.pipeline.camera import Camera
from signpose.pipeline.evaluate import CORES
from signpose.pipeline.image import ImageError, decode_image, to_gray

from .figures import fit
from .image_store import Conflict, Slot, check_image_header, read_each, refused_together, slot_for

# Figures of calibration photos are drawn from a copy this size: enough for a full-width preview.
PREVIEW_MAX_SIDE = 1280
MAX_PHOTOS = 60  # 15-20 make a good calibration; the encoded photos are held in memory
DEFAULT_BOARD = (9, 6)
DEFAULT_SQUARE_M = 0.025


@dataclass(frozen=True, eq=False)
class CalibrationPhoto:
    """One uploaded photo.

    data: its encoded bytes, decoded again at full resolution to search for a new board size.
    preview: (h, w) uint8 gray copy, at most PREVIEW_MAX_SIDE px a side, for figures.
    view: the board found in it, corners in full-resolution px.
    slot: where it is listed.
    """

    id: str
    name: str
    data: bytes = field(repr=False)
    preview: np.ndarray = field(repr=False)
    view: BoardView
    slot: Slot


@dataclass(frozen=True)
class FitRecipe:
    """How the photos were last fitted, to fit those left again as photos are removed (`refit`).

    left_out: ids of the photos left out of the fit (dropped as outliers), which stay out.
    fix_k3: whether k3 was held at 0.
    """

    left_out: frozenset[str]
    fix_k3: bool


@dataclass(frozen=True)
class CalibrationState:
    """The session at one moment, replaced as a whole on every change (`revision` + 1).

    board: (cols, rows) inner corners; square_m: side of a printed square, metres.
    result: the calibration of `photos` (views in this order) under this board, or None when
    nothing has been fitted since the last change.
    unfitted: why `photos` gave no result when fitted again after a photo was removed (`refit`);
    None otherwise.
    recipe: how the last run fitted the photos, kept as photos are removed, whether or not those
    left still give a result: each removal fits them again the same way and says anew why they
    give none (it was lost with the result, and the next removal said nothing, or worse). None
    before a run, and once photos are added or the board changes.
    """

    revision: int = 0
    board: tuple[int, int] = DEFAULT_BOARD
    square_m: float = DEFAULT_SQUARE_M
    photos: tuple[CalibrationPhoto, ...] = ()
    result: Calibration | None = None
    unfitted: str | None = None
    recipe: FitRecipe | None = None

    @property
    def found(self) -> int:
        """How many of the photos show the board."""
        return sum(p.view.found for p in self.photos)

    @property
    def few_boards_advice(self) -> str | None:
        """What to do when the board is found in too few of the photos to calibrate (add photos, or
        check its size); None with enough, or no photos."""
        if not self.photos or self.found >= MIN_VIEWS:
            return None
        return too_few_boards_advice(self.board, self.found, len(self.photos))

    @cached_property
    def _sizes(self) -> tuple[tuple[BoardView, ...], list[int], tuple[int, int] | None]:
        """(the photos' views, the indices of those with the board, the size (width, height) px most of
        those share, `reference_size`, or None without any): what `size_mismatch` and `other_sizes`,
        both in every response, measure against, worked out once per state (which never changes)."""
        views = tuple(p.view for p in self.photos)
        found = [i for i, v in enumerate(views) if v.found]
        return views, found, reference_size(views, found) if found else None

    @property
    def size_mismatch(self) -> str | None:
        """Why the photos with the board cannot be calibrated together (which are which other size than
        most, and what to do), as the run refuses; None when they are all one size."""
        views, found, size = self._sizes
        return size_mismatch(views, found, size) if size else None

    @property
    def other_sizes(self) -> dict[str, str]:
        """{photo id: "640x480, the others 1280x960"} for each photo with the board of another size than
        most (`size_mismatch` says what to do), shown on its card before any run: such photos were
        marked "found", and the summary said to run the calibration, which every run refused."""
        views, found, size = self._sizes
        return {self.photos[i].id: note for i, note in other_sizes(views, found, size).items()} if size else {}

    @property
    def why_no_result(self) -> str:
        """Why there is no `result`, in terms of the photos held, and what to do; for a request that
        needs one. It said "add photos of the board" to someone holding 19 after one was removed."""
        if not self.photos:
            return "no calibration yet: add photos of the board, then run the calibration"
        if self.unfitted:
            return f"no calibration: the {len(self.photos)} photos left could not be fitted again: {self.unfitted}"
        held = len(self.photos)
        if advice := self.few_boards_advice:
            return (f"no calibration: the {self.board[0]}x{self.board[1]} board is found in {self.found} of the "
                    f"{held} photos held, and a calibration needs at least {MIN_VIEWS} (15-20 recommended): {advice}")
        if mismatch := self.size_mismatch:
            return f"no calibration: {mismatch}"
        return (f"no calibration of the {held} photos held (none is kept when photos are added or the board changes): "
                "run the calibration")

    def photo(self, photo_id: str) -> CalibrationPhoto:
        """The photo with `photo_id`; KeyError when there is none."""
        for photo in self.photos:
            if photo.id == photo_id:
                return photo
        raise KeyError(photo_id)


@dataclass(frozen=True)
class BoardSearch:
    """The photos being searched again for a new `board` ((cols, rows) inner corners): `done` of `total`."""

    board: tuple[int, int]
    done: int
    total: int

    def to_json(self) -> dict:
        """{"cols", "rows", "done", "total"}, as the API says it."""
        return {"cols": self.board[0], "rows": self.board[1], "done": self.done, "total": self.total}


def read_gray(name: str, data: bytes, max_pixels: int) -> np.ndarray:
    """An uploaded photo as (H, W) uint8 gray, its pixels as the camera stored them; ImageError /
    ImageTooLarge as for any upload (checked and decoded as `decode_upload` does, without its EXIF
    camera: a board fixes the intrinsics). Not turned by its EXIF orientation: the camera file
    describes the pixels as stored, and each photo recognised turns it as that photo's orientation
    says (`pipeline.exif.turned_camera`), so photos taken held either way calibrate together."""
    check_image_header(data, name, max_pixels)
    return to_gray(decode_image(data, name, as_stored=True))


class CalibrationSession:
    """Thread-safe holder of one CalibrationState. Readers take `state` (never torn); every change
    is serialised by one lock, except the board search of new photos, which runs outside it so
    that uploads sent side by side use every core.

    `publish(payload)` is called on every change of the state or of a board search under way, with
    {"revision", "search": BoardSearch.to_json() | None}: the server sends it to every client as the
    `calibration` event. It is called under the lock, so that changes are published in the order
    made: it must only pass the payload on, never call the session nor wait on what may. The
    server's (Workspace.publish) holds the workspace's lock only to copy its subscriber list, never
    takes this one, and its subscribers only hand the event to the event loop
    (call_soon_threadsafe): it cannot deadlock, nor hold this lock longer than the workspace holds
    its own (writing its index or library), where fits and board searches hold it for seconds.
    """

    def __init__(self, max_pixels: int, max_photos: int = MAX_PHOTOS,
                 publish: Callable[[dict], None] = lambda payload: None) -> None:
        self.max_pixels = max_pixels
        self.max_photos = max_photos
        self._publish = publish
        self._lock = threading.Lock()
        self._state = CalibrationState()
        self._search: BoardSearch | None = None

    @property
    def state(self) -> CalibrationState:
        return self._state

    @property
    def search(self) -> BoardSearch | None:
        """How far the search for a new board size has come (`set_board`), None when none is under way."""
        return self._search

    def _commit(self, **changes: Any) -> CalibrationState:
        """Replace the state by one with `changes` and the next revision (the caller holds the lock).

        Any change but a fit makes the result stale, so it is dropped unless `changes` gives one
        (and with it why a refit gave none, and how the photos were fitted).
        """
        changes = {"result": None, "unfitted": None, "recipe": None, **changes}
        self._state = dataclasses.replace(self._state, revision=self._state.revision + 1, **changes)
        self._published()
        return self._state

    def _published(self) -> None:
        """Publish the revision and the board search now (the caller holds the lock)."""
        search = self._search
        self._publish({"revision": self._state.revision, "search": None if search is None else search.to_json()})

    def _searching(self, search: BoardSearch | None) -> None:
        """Say how far the board search has come (None: it is over), to requests and to `publish`: the
        request that asked for it is answered only once it is over."""
        self._search = search
        self._published()

    def _check_room(self, adding: int) -> None:
        held = len(self._state.photos)
        if held + adding > self.max_photos:
            raise Conflict(f"the calibration holds {held} photos and its limit is {self.max_photos}; "
                           f"delete some before adding {adding} more (15-20 good ones are enough)")

    def add(self, uploads: list[tuple[str, bytes]], batch: str = "",
            position: int = 0) -> tuple[CalibrationState, list[str]]:
        """Add photos (display name, encoded bytes) and search each for the board; they are listed at
        `position` on in `batch` (`Slot`), or after every photo held without one. Returns the state
        and the new photos' ids, in `uploads`' order. All or nothing: ImageError for a file that is
        not a usable image (naming every one), Conflict past the photo limit."""
        self._check_room(len(uploads))
        refused: dict[int, ImageError] = {}
        read = read_each(dict(enumerate(uploads)), lambda u: read_gray(u[0], u[1], self.max_pixels), refused)
        if refused:
            raise refused_together(refused, len(uploads))
        grays = list(read.values())

        previews = [fit(gray, PREVIEW_MAX_SIDE) for gray in grays]  # made once: they do not depend on the board
        names = [name for name, _ in uploads]
        while True:
            board = self._state.board
            with ThreadPoolExecutor(CORES) as pool:  # OpenCV releases the GIL: a photo per core
                views = list(pool.map(lambda gray, name: find_board(gray, board, name), grays, names))
            with self._lock:
                if self._state.board != board:
                    continue  # the board size changed during the search: search for the new one
                self._check_room(len(uploads))
                first = slot_for([p.slot for p in self._state.photos], batch, position)
                photos = [CalibrationPhoto(secrets.token_hex(6), name, data, preview, view,
                                           dataclasses.replace(first, position=position + i))
                          for i, ((name, data), preview, view) in enumerate(zip(uploads, previews, views))]
                state = self._commit(photos=tuple(sorted([*self._state.photos, *photos], key=lambda p: p.slot)))
                return state, [p.id for p in photos]

    def set_board(self, board: tuple[int, int], square_m: float) -> CalibrationState:
        """Use a board of `board` (cols, rows) inner corners and `square_m` metre squares; every photo
        is searched again when the corner counts change. CalibrationError for impossible values."""
        board, square_m = check_board(board), check_square(square_m)
        with self._lock:
            state = self._state
            photos = state.photos
            if board != state.board:
                photos = self._search_again(photos, board)
            return self._commit(board=board, square_m=square_m, photos=photos)

    def _search_again(self, photos: tuple[CalibrationPhoto, ...],
                      board: tuple[int, int]) -> tuple[CalibrationPhoto, ...]:
        """`photos` with the `board` searched for in each, saying how far it has come in `search`
        (18 phone photos take some 10 s on one core; the state keeps the old board until all are
        done). Photos are searched a core each."""
        def search(photo: CalibrationPhoto) -> CalibrationPhoto:
            gray = read_gray(photo.name, photo.data, self.max_pixels)
            return dataclasses.replace(photo, view=find_board(gray, board, photo.name))

        searched: list[CalibrationPhoto] = []
        try:
            self._searching(BoardSearch(board, 0, len(photos)))
            with ThreadPoolExecutor(CORES) as pool:
                for photo in pool.map(search, photos):
                    searched.append(photo)
                    self._searching(BoardSearch(board, len(searched), len(photos)))
            return tuple(searched)
        finally:
            self._searching(None)

    def remove(self, photo_id: str) -> CalibrationState:
        """Forget one photo; KeyError when there is none with `photo_id`. The photos left are fitted
        again as the last run fitted them (`refit`, `recipe`), after every removal, whether or not the
        one before still gave a result: removing a photo, often the outlier, is a step in refining a
        calibration, and dropping the result with it left camera.yaml and apply refusing for want
        of one."""
        with self._lock:
            state = self._state
            state.photo(photo_id)
            photos = tuple(p for p in state.photos if p.id != photo_id)
            if not photos or state.recipe is None:  # no fit to keep up
                return self._commit(photos=photos)
            recipe = dataclasses.replace(state.recipe, left_out=state.recipe.left_out & {p.id for p in photos})
            result, unfitted = refit(state.board, state.square_m, recipe, photos)
            return self._commit(photos=photos, result=result, unfitted=unfitted, recipe=recipe)

    def clear(self) -> CalibrationState:
        """Forget every photo (the board stays)."""
        with self._lock:
            return self._commit(photos=())

    def run(self, without_outliers: bool = False) -> CalibrationState:
        """Fit the intrinsics to the photos where the board was found, then, with `without_outliers`,
        once more without the outliers. CalibrationError when they cannot give a calibration."""
        with self._lock:
            state = self._state
            if not state.photos:
                raise CalibrationError(f"no calibration photos yet: add 15-20 photos of the {state.board[0]}x"
                                       f"{state.board[1]} board (docs/calibration.md says how to take them)")
            result = calibrate([p.view for p in state.photos], state.board, state.square_m)
            if without_outliers:
                result = drop_outliers(result)
            recipe = FitRecipe(frozenset(state.photos[i].id for i in result.excluded), result.fix_k3)
            return self._commit(result=result, recipe=recipe)


def refit(board: tuple[int, int], square_m: float, recipe: FitRecipe,
          photos: tuple[CalibrationPhoto, ...]) -> tuple[Calibration | None, str | None]:
    """The calibration of `photos` on `board` ((cols, rows) inner corners, `square_m` metre squares),
    fitted as `recipe` says (the photos it left out, dropped outliers, stay out: ids among `photos`),
    or None and why `photos` give none (e.g. too few boards left)."""
    try:
        return calibrate([p.view for p in photos], board, square_m, fix_k3=recipe.fix_k3,
                         exclude=tuple(i for i, p in enumerate(photos) if p.id in recipe.left_out)), None
    except CalibrationError as exc:
        kept_out = len(recipe.left_out)
        return None, str(exc) + (f" (the {kept_out} dropped as outliers stay out)" if kept_out > 1 else
                                 " (the one dropped as an outlier stays out)" if kept_out else "")


def page_outlier_advice(result: Calibration) -> str | None:
    """What to do about `result`'s outliers in the words of the page's Camera dialog (its "drop
    outliers" button and each photo's ×), which shows it as it comes; None without outliers."""
    return outlier_advice(result, drop="drop outliers", leave_out="remove {them} (×)") if result.outliers else None


def calibrated_camera(result: Calibration) -> Camera:
    """The fitted camera, its source naming how it was made (kept with it in the state directory)."""
    return dataclasses.replace(result.camera, source=f"calibration: {len(result.used)} views, "
                                                     f"RMS {result.rms_px:.2f} px")
