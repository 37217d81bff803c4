"""Change notices of `signpose serve`: the workspace and the calibration session publish, the
page's event stream and the viser scene subscribe (docs/web-contract.md)."""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from dataclasses import dataclass

log = logging.getLogger(__name__)

EVENT_KINDS = ("settings", "results", "library", "camera", "images", "calibration", "flights", "flight_cursor")


@dataclass(frozen=True)
class Event:
    """A change notice; `kind` is one of EVENT_KINDS, `payload` JSON-ready (see the contract)."""

    kind: str
    payload: dict


class EventBus:
    """Subscribers and the events published to them.

    `_lock` guards `_subscribers` alone; it is never held while a subscriber runs, so a subscriber
    may publish, subscribe or call into whoever publishes.
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._subscribers: list[Callable[[Event], None]] = []

    def subscribe(self, callback: Callable[[Event], None]) -> Callable[[], None]:
        """Call `callback(event)` on every event, from the publisher's thread; returns the unsubscribe function."""
        with self._lock:
            self._subscribers.append(callback)

        def unsubscribe() -> None:
            with self._lock:
                if callback in self._subscribers:
                    self._subscribers.remove(callback)

        return unsubscribe

    def publish(self, kind: str, payload: dict) -> None:
        """Send `Event(kind, payload)` to every subscriber."""
        with self._lock:
            subscribers = list(self._subscribers)
        for callback in subscribers:
            try:
                callback(Event(kind, payload))
            except Exception:  # one broken subscriber must not stop the others or the pipeline
                log.exception("event subscriber failed on %s", kind)
