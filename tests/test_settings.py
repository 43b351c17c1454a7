"""pipeline/settings.py: the one settings base (types, ranges, unknown keys, one-line errors)."""

from __future__ import annotations

import math
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar, Literal

import pytest

from pipeline.errors import ScanError
from pipeline.settings import SettingError, Settings, SettingsError, setting

ROOT = Path(__file__).resolve().parents[1]


@dataclass(frozen=True)
class Inner(Settings):
    a: float = setting(1.0, gt=0)


@dataclass
class Demo(Settings):
    block: ClassVar[str] = "demo"

    n: int = setting(3, ge=1, le=10)
    x: float = setting(0.5, gt=0, le=100)
    flag: bool = True
    mode: Literal["fast", "slow"] = "fast"
    shape: Literal["round"] | float = "round"
    span: tuple[float, float] = setting((1.0, 2.0), ge=0, ordered=True)
    names: tuple[str, ...] = setting(("a",), min_len=1)
    addr: str | None = None
    inner: Inner = setting(default_factory=Inner)
    table: dict[str, Inner] = setting(default_factory=dict)

    def validate(self):
        if isinstance(self.shape, float) and not 0 <= self.shape <= 1:
            raise SettingError("shape", "must be in [0, 1]")


def refused(params) -> str:
    with pytest.raises(SettingsError) as exc:
        Demo.from_params(params)
    assert isinstance(exc.value, ScanError) and isinstance(exc.value, ValueError)
    return str(exc.value)


def test_defaults_live_in_the_dataclass():
    d = Demo.from_params(None)
    assert d == Demo() and d.n == 3 and d.inner == Inner() and d.table == {}
    assert Demo.from_params({}).to_dict()["span"] == [1.0, 2.0]


def test_values_are_converted_to_the_annotated_types():
    d = Demo.from_params({"n": 4.0, "x": 2, "span": [0, 3], "names": ["p", "q"], "shape": 1,
                          "addr": "tcp://h:1", "inner": {"a": "1e3"}, "table": {"t": {"a": 2}}})
    assert d.n == 4 and isinstance(d.n, int) and d.x == 2.0 and isinstance(d.x, float)
    assert d.span == (0.0, 3.0) and d.names == ("p", "q") and d.shape == 1.0
    assert d.inner == Inner(a=1000.0) and d.table == {"t": Inner(a=2.0)}
    assert Demo.from_params({"n": "1e1"}).n == 10            # YAML 1.2 number text, as DVC reads it


@pytest.mark.parametrize("params, message", [
    ({"x": -4}, "params.yaml: demo.x must be > 0 (got -4)"),
    ({"x": math.nan}, "params.yaml: demo.x must be a finite number (got nan)"),
    ({"x": math.inf}, "params.yaml: demo.x must be a finite number (got inf)"),
    ({"x": "big"}, "params.yaml: demo.x must be a number (got 'big')"),
    ({"x": True}, "params.yaml: demo.x must be a number (got True)"),
    ({"n": 0}, "params.yaml: demo.n must be >= 1 (got 0)"),
    ({"n": 2.5}, "params.yaml: demo.n must be an integer (got 2.5)"),
    ({"n": "1e9"}, "params.yaml: demo.n must be <= 10 (got 1000000000)"),
    ({"flag": 1}, "params.yaml: demo.flag must be true or false (got 1)"),
    ({"mode": "medium"}, "params.yaml: demo.mode must be one of 'fast', 'slow' (got 'medium')"),
    ({"shape": 3}, "params.yaml: demo.shape must be in [0, 1]"),
    ({"span": [3, 1]}, "params.yaml: demo.span must be in increasing order [low, high] (got [3.0, 1.0])"),
    ({"span": [1]}, "params.yaml: demo.span must be a list of 2 values (got [1])"),
    ({"span": [-1, 1]}, "params.yaml: demo.span every value must be >= 0"),
    ({"names": []}, "params.yaml: demo.names needs at least 1 value(s) (got 0)"),
    ({"addr": 5}, "params.yaml: demo.addr must be a string or null (got 5)"),
    ({"inner": {"a": 0}}, "params.yaml: demo.inner.a must be > 0 (got 0)"),
    ({"inner": {"b": 1}}, "params.yaml: demo.inner.b is an unknown key (known: a)"),
    ({"inner": 3}, "params.yaml: demo.inner must be a mapping"),
    ({"table": {"t": {"a": -1}}}, "params.yaml: demo.table.t.a must be > 0 (got -1)"),
    ({"typo": 1}, "params.yaml: demo.typo is an unknown key (known: n, x, flag"),
])
def test_bad_values_name_the_key(params, message):
    assert message in refused(params)


def test_direct_construction_is_checked_too():
    with pytest.raises(SettingError, match="x must be > 0"):
        Demo(x=0)
    assert Demo(span=[0, 1]).span == (0.0, 1.0)


def test_the_real_blocks_refuse_bad_values():
    from pipeline.bake.bake import BakeSettings
    from pipeline.eyeball.geometry import EyeballSettings
    from pipeline.render.settings import RenderSettings
    from pipeline.rig.lids import RigSettings
    from pipeline.synthetic_head import SyntheticHeadSettings

    for cls, params, message in [
        (BakeSettings, {"max_distance_mm": -4}, "params.yaml: bake.max_distance_mm must be > 0 (got -4)"),
        (RenderSettings, {"n_images": 10**9}, "render.n_images must be <= 1000000"),
        (RenderSettings, {"width": 40, "height": 80}, "render.width must be >= height"),
        (RigSettings, {"sweep_step_deg": 0}, "rig.sweep_step_deg must be >= 0.05"),
        (SyntheticHeadSettings, {"eye_shape": "square"}, "synthetic_head.eye_shape must be"),
        (SyntheticHeadSettings, {"eye_shape": 2}, "must be round, hooded or a number in [0, 1]"),
        (EyeballSettings, {"geometry": {"apex": 30}}, "eyeball.geometry.apex 30 must lie between"),
        (EyeballSettings, {"resolution": {"n_around": 30}}, "eyeball.resolution.n_around must be a multiple of 8"),
        (EyeballSettings, {"resolution": "ultra"}, "eyeball.resolution must be one of 'low'"),
    ]:
        with pytest.raises(SettingsError) as exc:
            cls.from_params(params)
        assert message in str(exc.value), (cls, str(exc.value))


def test_stage_answers_a_bad_param_with_one_line(tmp_path):
    params = tmp_path / "params.yaml"
    params.write_text("bake:\n  max_distance_mm: -4\n")
    r = subprocess.run([sys.executable, "-m", "stages.bake", str(tmp_path / "r"), str(tmp_path / "d"),
                        str(tmp_path / "out"), "--params", str(params)], cwd=ROOT, capture_output=True,
                       text=True, timeout=120)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert r.stderr == f"error: {params}: bake.max_distance_mm must be > 0 (got -4)\n"
    assert not (tmp_path / "out").exists()


def test_timings_go_beside_the_metrics_not_into_them(tmp_path):
    """What a run measured (seconds, MiB, run facts) goes to <stage>.timings.json; the metrics
    file (a DVC output hashed in dvc.lock) keeps only what the inputs determine."""
    import json
    import time

    from pipeline.results import StageResult
    from stages._common import read_stage_metrics, run_stage, timings_path

    path = tmp_path / "build" / "x" / "stage.metrics.json"
    assert timings_path(path) == tmp_path / "build" / "x" / "stage.timings.json"

    def main(argv):          # by type: a metric with an "s" word stays a metric
        return StageResult({"accuracy_mm": 0.5, "n_s_shaped": 1}, {"fit_s": 1.25, "skipped_done": 2}, path)

    cpu_before = time.process_time()
    assert run_stage(main, []) == 0
    assert json.loads(path.read_text()) == {"accuracy_mm": 0.5, "n_s_shaped": 1}
    t = json.loads(timings_path(path).read_text())
    assert t["fit_s"] == 1.25 and t["skipped_done"] == 2 and t["wall_time_s"] >= 0 and t["peak_memory_mib"] > 0
    assert t["cpu_time_s"] >= cpu_before > 0        # this process's CPU from its start, children added
    assert read_stage_metrics(path)["fit_s"] == 1.25


def test_a_subclass_post_init_runs_after_the_checks_not_instead():
    seen = []

    @dataclass(frozen=True)
    class Legacy(Settings):
        block: ClassVar[str] = "legacy"
        r: tuple[float, float] = setting((10.0, 18.0), gt=0, ordered=True)
        flag: bool = True

        def __post_init__(self):
            seen.append(self.r)

    assert Legacy.from_params({"r": [1, 2]}).r == (1.0, 2.0) and seen == [(1.0, 2.0)]
    with pytest.raises(SettingsError, match=r"params.yaml: legacy.r must be in increasing order"):
        Legacy.from_params({"r": [2, 1]})
    assert len(seen) == 1


# ------------------------------------------------------------------- every block at its limits

def _nested(key: tuple, value) -> dict:
    d = value
    for k in reversed(key):
        d = {k: d}
    return d


def _block_boundaries():
    from pipeline.settings import boundaries
    from pipeline.params_check import BLOCKS, settings_class

    return [(block, key, value, ok) for block in BLOCKS
            for key, value, ok in boundaries(settings_class(block))]


@pytest.mark.parametrize("block", ["synthetic_head", "eyeball", "ingest", "remove_eyeballs", "retopo",
                                   "bake", "snap", "rig", "usd", "render"])
def test_every_block_takes_its_limits_and_refuses_past_them_in_one_line(block):
    """Fuzz from each block's own schema: a value at a limit is read as that value (or refused
    by a check across fields, in one line), the next value past it is refused in one line
    naming params.yaml and the key; the check_params stage reads the block the same way."""
    from pipeline.params_check import check_params, settings_class

    cls = settings_class(block)
    cases = [(k, v, ok) for b, k, v, ok in _block_boundaries() if b == block]
    assert cases
    taken = 0
    for key, value, ok in cases:
        dotted = ".".join(key)
        try:
            s = cls.from_params(_nested(key, value))
        except SettingsError as exc:
            msg = str(exc)
            assert "\n" not in msg and msg.startswith(f"params.yaml: {block}."), (dotted, value, msg)
            if not ok:
                assert msg.startswith(f"params.yaml: {block}.{dotted}"), (dotted, value, msg)
            continue
        assert ok, f"{block}.{dotted} = {value!r} was accepted past its limit"
        got = s
        for k in key:
            got = getattr(got, k)
        want = tuple(value) if isinstance(value, list) else value
        assert got == want, (dotted, value, got)
        check_params({block: _nested(key, value)})        # the stage that runs first agrees
        taken += 1
    assert taken >= sum(ok for _, _, ok in cases) // 2, f"{block}: most limits collide with other defaults"


def test_library_defaults_are_the_settings_defaults():
    """One definition per default: the ingest block's are the readers' limits and the repair's."""
    from pipeline.ingest.ingest import IngestSettings
    from pipeline.ingest.repair import RepairSettings
    from pipeline.io.formats.common import Limits
    from pipeline.io.scan import DEFAULT_MAX_YAML_BYTES

    s = IngestSettings()
    assert s.limits == Limits() and s.repair == RepairSettings() and s.max_yaml_bytes == DEFAULT_MAX_YAML_BYTES
    assert IngestSettings.from_params({"max_file_mb": 1}).limits.max_file_bytes == 2**20
