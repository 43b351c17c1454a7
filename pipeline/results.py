"""What a stage reports, in two kinds kept apart by type: :class:`StageResult`.

* ``metrics``: what the inputs determine (sizes, counts, accuracy figures). The stage writes them
  to ``build/<scan>/<stage>.metrics.json`` and their headline to ``<stage>.summary.json`` (the DVC
  metrics, stages/_common.py), DVC outputs recorded in ``dvc.lock``, so the same inputs must give
  the same bytes.
* ``timings``: what this run measured (wall and CPU seconds, memory, workers, how much a resumed
  run skipped). They go to ``<stage>.timings.json`` beside it, which DVC does not track.

A library function that does a stage's work returns a :class:`StageResult`; the stage script
adds where the metrics go (``path``) and stages/_common.py writes both files. Libraries that
still return one mixed dict are split by :meth:`StageResult.from_mixed`, the old rule by key name.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path


@dataclass
class StageResult:
    """A stage's metrics and timings (module doc); ``path`` is where its metrics file goes."""

    metrics: dict = field(default_factory=dict)
    timings: dict = field(default_factory=dict)
    path: Path | None = None

    def __add__(self, other: "StageResult") -> "StageResult":
        """Both results' metrics and timings, ``other``'s after this one's (the path of either)."""
        return StageResult({**self.metrics, **other.metrics}, {**self.timings, **other.timings},
                           self.path or other.path)

    def at(self, path) -> "StageResult":
        """This result, written to ``path`` (the stage's metrics file)."""
        return StageResult(self.metrics, self.timings, Path(path))

    @classmethod
    def from_mixed(cls, mixed: dict, path=None) -> "StageResult":
        """Split one dict by key name: a key with an ``s`` or ``mib`` word (``wall_time_s``,
        ``render_s_median``, ``images_per_s``, ``peak_memory_mib``) is a timing, with its whole
        value; nested dicts are split alike. For libraries that do not return a StageResult yet."""
        metrics, timings = _split(mixed)
        return cls(metrics, timings, Path(path) if path is not None else None)


def is_timing_key(key) -> bool:
    """The name rule of :meth:`StageResult.from_mixed`."""
    return bool({"s", "mib"} & set(str(key).split("_")))


def _split(d: dict) -> tuple[dict, dict]:
    results, timings = {}, {}
    for k, v in d.items():
        if is_timing_key(k):
            timings[k] = v
        elif isinstance(v, dict):
            r, t = _split(v)
            if r or not t:
                results[k] = r
            if t:
                timings[k] = t
        else:
            results[k] = v
    return results, timings
