"""What a stage reports, in two kinds kept apart by type: :class:`StageResult`.

* ``metrics``: what the inputs determine (sizes, counts, accuracy figures). The stage writes them
  to ``build/<scan>/<stage>.metrics.json`` and their headline to ``<stage>.summary.json`` (the DVC
  metrics, stages/_common.py), DVC outputs recorded in ``dvc.lock``, so the same inputs must give
  the same bytes.
* ``timings``: what this run measured (wall and CPU seconds, memory, workers, how much a resumed
  run skipped). They go to ``<stage>.timings.json`` beside it, which DVC does not track.

A library function that does a stage's work returns a :class:`StageResult` (alone, or as the
``result`` of what it returns), its metrics and timings apart by type where they are measured;
the stage script adds where the metrics go (``path``) and stages/_common.py writes both files.
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
