"""Where the project's shared data lies: SIGNPOSE_SHARED, else `shared` beside the checkout."""

from __future__ import annotations

import os
from pathlib import Path


def shared_folder() -> Path:
    override = os.environ.get("SIGNPOSE_SHARED")
    return Path(override) if override else Path(__file__).resolve().parents[2].parent / "shared"
