"""Shared fixtures.

Real scans live outside the project (``../shared/scans``); tests that need them
read the folder from ``EYERIG_EXTRA_SCANS`` and skip cleanly when it is unset.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def extra_scans_dir() -> Path | None:
    value = os.environ.get("EYERIG_EXTRA_SCANS")
    return Path(value) if value else None


@pytest.fixture
def extra_scan():
    """``extra_scan("james")`` -> path of that real scan folder, or skip."""

    def get(name: str) -> Path:
        base = extra_scans_dir()
        if base is None:
            pytest.skip("EYERIG_EXTRA_SCANS is not set")
        folder = base / name
        if not folder.is_dir():
            pytest.skip(f"{folder} not found")
        return folder

    return get
