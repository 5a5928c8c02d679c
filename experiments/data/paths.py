"""Where the real measured data lives: ``../shared/data`` beside the project root."""

from __future__ import annotations

import os
from pathlib import Path

PROJECT_ROOT = Path(__file__).resolve().parents[2]


def shared_data_dir() -> Path:
    """Directory of the real data sets (override with the ``DVS_SHARED_DATA`` variable)."""
    override = os.environ.get("DVS_SHARED_DATA")
    return Path(override) if override else PROJECT_ROOT.parent / "shared" / "data"
