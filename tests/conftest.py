"""pytest's shared fixtures. The builders tests and benchmarks share live in tests/fixtures/
(``from fixtures import make_scan, ...``).

Real scans live outside the project (``../shared/scans``); tests that need them read the folder
from ``EYERIG_EXTRA_SCANS`` (:func:`fixtures.extra_scans_dir`) and skip cleanly when it is unset.
"""

from __future__ import annotations

import pytest

from fixtures import ROOT, extra_scans_dir  # noqa: F401 (tests that take them from here)


@pytest.fixture
def extra_scan():
    """``extra_scan("james")`` -> path of that real scan folder, or skip."""

    def get(name: str):
        base = extra_scans_dir()
        if base is None:
            pytest.skip("EYERIG_EXTRA_SCANS is not set")
        folder = base / name
        if not folder.is_dir():
            pytest.skip(f"{folder} not found")
        return folder

    return get


@pytest.fixture(scope="module")
def region():
    """Both constructed eyes (fixtures.rig.two_eye_region) and their lid shapes: the rig tests'
    sealed eye region, ``(V, F, eyes, LidRig)``."""
    from fixtures.rig import two_eye_region
    from pipeline.rig.lid_shapes import build_lid_shapes

    V, F, eyes = two_eye_region()
    return V, F, eyes, build_lid_shapes(V, F, eyes)
