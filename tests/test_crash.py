"""SIGKILL `signpose serve` in the middle of a burst of saves, restart it on the same state
directory, and find every state file whole and every acknowledged change there."""

from __future__ import annotations

import random
import signal
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import httpx
import pytest

from signpose.app.state import TMP_SUFFIX, StateDir
from signpose.pipeline.image import decode_image
from signpose.pipeline.library import load_library
from tests.support.scene_images import block_sign, tiny_photo
from tests.support.serving import TIMEOUT_S, start_serve, stop_serve

# Kills and restarts a real `signpose serve`.
pytestmark = pytest.mark.server

KILLS = 3
SIGN_SIZE_M = {"width_m": "0.6", "height_m": "0.24"}


@dataclass
class Acknowledged:
    """What the server said it had done, and what it may have done when it died."""

    ratio: float | None = None
    ratio_in_flight: float | None = None
    images: set[str] = field(default_factory=set)
    signs: set[str] = field(default_factory=set)
    camera_fx: float | None = None
    camera_in_flight: float | None = None

    def of_every_kind(self) -> bool:
        """Whether the server has acknowledged at least one change of each kind that
        `check_state_files` reads back: before that there is nothing of that kind to find whole."""
        return self.ratio is not None and bool(self.images) and bool(self.signs) and self.camera_fx is not None


def tune(url: str, ack: Acknowledged, start: int) -> None:
    """Settings changes, one after another, until the server dies."""
    with httpx.Client(base_url=url, timeout=TIMEOUT_S) as c:
        for step in range(start, start + 10_000):
            ack.ratio_in_flight = round(0.6 + step / 100_000, 5)
            try:
                c.put("/api/settings", json={"ratio": ack.ratio_in_flight}).raise_for_status()
            except httpx.TransportError:
                return
            ack.ratio = ack.ratio_in_flight


def add(url: str, ack: Acknowledged, start: int) -> None:
    """Uploads, new signs and camera changes in turn, until the server dies."""
    with httpx.Client(base_url=url, timeout=TIMEOUT_S) as c:
        for step in range(start, start + 10_000):
            try:
                if step % 3 == 0:
                    r = c.post("/api/images", files={"files": (f"{step}.jpg", tiny_photo(), "image/jpeg")})
                    r.raise_for_status()
                    ack.images.add(r.json()["images"][0]["id"])
                elif step % 3 == 1:
                    c.post("/api/library", files={"file": ("s.png", block_sign(step), "image/png")},
                           data={"id": f"sign-{step}", **SIGN_SIZE_M}).raise_for_status()
                    ack.signs.add(f"sign-{step}")
                else:
                    ack.camera_in_flight = 500.0 + step
                    fx = ack.camera_in_flight  # square pixels: fx/fy far from 1 is refused
                    c.put("/api/camera", json={"fx": fx, "fy": fx, "cx": 32, "cy": 24}).raise_for_status()
                    ack.camera_fx = ack.camera_in_flight
            except httpx.TransportError:
                return


def check_state_files(state_dir: Path, ack: Acknowledged) -> None:
    """Every state file parses, and holds the last acknowledged change (or the one in flight)."""
    state = StateDir(state_dir)
    assert state.load_settings().ratio in (ack.ratio, ack.ratio_in_flight)
    assert state.load_camera().K[0, 0] in (ack.camera_fx, ack.camera_in_flight)
    assert ack.signs <= set(load_library(state.library_dir).ids)
    stored = {entry.id: entry for entry in state.load_images()}
    assert ack.images <= set(stored)
    for entry in stored.values():  # the index never names a missing or torn file
        decode_image(state.read_image(entry.file), entry.name)


def test_sigkill_during_saves_loses_no_acknowledged_change(tmp_path):
    state_dir = tmp_path / "state"
    ack = Acknowledged()
    rng = random.Random(7)
    for kill in range(KILLS):
        proc, url = start_serve(state_dir)
        workers = [threading.Thread(target=fn, args=(url.rstrip("/"), ack, kill * 10_000)) for fn in (tune, add)]
        for worker in workers:
            worker.start()
        time.sleep(rng.uniform(0.3, 1.2))  # some dozens of saves in, at no moment in particular
        deadline = time.monotonic() + TIMEOUT_S  # a slow machine may not have saved a camera yet
        while not ack.of_every_kind() and time.monotonic() < deadline and all(w.is_alive() for w in workers):
            time.sleep(0.01)
        proc.send_signal(signal.SIGKILL)
        proc.wait(TIMEOUT_S)
        proc.stdout.close()
        proc.stderr.close()
        for worker in workers:
            worker.join(TIMEOUT_S)
        assert ack.of_every_kind(), f"the burst made no change of some kind before the kill: {ack}"
        check_state_files(state_dir, ack)

    proc, url = start_serve(state_dir)  # the next start sweeps what the kills left half-written
    try:
        with httpx.Client(base_url=url.rstrip("/"), timeout=TIMEOUT_S) as c:
            assert c.get("/api/settings").json()["settings"]["ratio"] in (ack.ratio, ack.ratio_in_flight)
            assert ack.images <= {i["id"] for i in c.get("/api/images").json()["images"]}
            assert ack.signs <= {s["id"] for s in c.get("/api/library").json()}
            assert c.get("/api/camera").json()["camera"]["fx"] in (ack.camera_fx, ack.camera_in_flight)
        assert not list(state_dir.rglob(f"*{TMP_SUFFIX}"))
    finally:
        stop_serve(proc)
