"""The iris a scanify head shows, rebuilt from ICT-FaceKit (``fixtures.unseen.iris_truth``): the
placement benchmark scores the asset against it beside scanify's own axis. Needs
``EYERIG_EXTRA_SCANS`` with ``ict_neutral``, ``ict_facekit`` and ``../tools/scanify`` beside it."""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest

from fixtures.unseen.iris_truth import visible_iris

pytestmark = pytest.mark.slow      # rebuilds an ICT-FaceKit head (2 s)


@pytest.fixture
def ict(extra_scan):
    base = extra_scan("ict_neutral").parent
    tool = base.parent / "tools" / "scanify" / "scanify.py"
    if not tool.is_file() or not (base / "ict_facekit").is_dir():
        pytest.skip(f"scanify or ICT-FaceKit not found beside {base}")
    doc = json.loads((base / "ict_neutral" / "ground_truth.json").read_text())
    return doc, tool, base / "ict_facekit"


def test_the_rebuilt_iris_disc_sits_in_front_of_its_eye(ict):
    doc, tool, ict_dir = ict
    iris = visible_iris(doc, tool, ict_dir)          # raises unless the limbus is reproduced to 1e-3 mm
    for side in ("left", "right"):
        g = doc["eyes"][side]
        v = iris[side]
        assert abs(np.linalg.norm(v["normal"]) - 1.0) < 1e-9
        # ICT's neutral iris disc stands 2.8 deg off scanify's axis (iris_bound: 0.2-4 deg over identities)
        assert 2.0 < v["normal_vs_axis_deg"] < 4.0
        lt = np.asarray(g["limbus"]["center_mm"])
        assert abs(float((v["limbus_center"] - lt) @ np.asarray(g["gaze_direction"]))) < 0.05   # same depth
        assert np.linalg.norm(v["limbus_center"] - lt) < 1.0
        # the disc lies inside the limbus circle's cone, about where the limbus is
        assert np.linalg.norm(v["center"] - lt) < 3.0


def test_another_identity_is_refused_rather_than_misread(ict):
    doc, tool, ict_dir = ict
    other = copy.deepcopy(doc)
    other["source"]["identity_seed"] = 5          # not the head the truth describes
    with pytest.raises(ValueError, match="misses the truth's limbus"):
        visible_iris(other, tool, ict_dir)
