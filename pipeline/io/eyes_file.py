"""``eyes.json``: the serialisation of :class:`Eye`, the one eye type from remove_eyeballs on.

Written by ``remove_eyeballs`` (and re-written by ``snap`` with the loop on the snapped mesh),
read by ``retopo``, ``snap`` and ``rig``. Layout (mm, head frame)::

    {"schema": 1,
     "left":  {"center": [x, y, z], "radius": r, "forward": [x, y, z] (unit),
               "loop_indices": [...], "loop_points": [[x, y, z], ...],
               "lateral_canthus_index": i, "placement": "surface" | "texture",
               "checks": {...}, "residual_rms_mm": ..., "cornea": null | {...}, ...},
     "right": {...}}

Every reader validates (the schema, both eyes, finite centre, radius in (0, 100) mm, a non-zero
forward and, where present, a loop of at least 8 distinct vertex indices inside the mesh with
the lateral canthus inside it) and refuses anything else with one line naming the file; keys it
does not know are carried unchanged. The loop is optional: stages after retopo carry their loops
in mesh.npz (``loop_left``/``loop_right``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pipeline.errors import ScanError
from pipeline.io.atomic import write_json

SCHEMA = 1
SIDES = ("left", "right")


#: The keys of an ``eyes.json`` entry in the order they are written: :class:`Eye`'s named
#: fields and the keys it carries (``extra``) keep this order, so an entry read and written
#: again is the same bytes; a key this list does not know follows them, in its own order.
KEY_ORDER = (
    "center", "radius", "forward",
    # the scan's fit (remove_eyeballs): what carried it and how sure it is
    "residual_rms_mm", "n_inliers", "method", "placement", "cue_shares", "anterior_height",
    "anterior_ring", "limbus_half_angle_deg", "lid_fold_deg", "uncertainty_laplace_mm",
    "radius_profile", "rival_placements", "checks", "cornea",
    # the opening
    "loop_indices", "loop_points", "lateral_canthus_index", "texture_fissure", "doubts",
    # the asset's eye
    "scan_sphere", "eye_size", "limbus", "uncertainty", "uncertainty_mm", "iris_at_rest",
    # the snap's report
    "snap",
)


@dataclass
class Eye:
    """One eye of a head: where the asset's eyeball sits and what is known of it, from
    remove_eyeballs on (``eyes.json`` is its serialisation: :meth:`from_doc`, :meth:`to_doc`).

    Attributes
    ----------
    side : str
        ``"left"`` (the subject's left, head +X) or ``"right"``.
    center : (3,) float64
        The eyeball's rotation centre, mm, head frame.
    radius : float
        The eyeball's radius, mm.
    forward : (3,) float64
        The rest gaze (optical axis) as written (unit to the 9 decimals remove_eyeballs keeps;
        :attr:`unit_forward` is it normalised).
    loop_indices : (L,) int64 or None
        The eyelid-opening loop on the stage's mesh, medial canthus first, upper lid first.
    loop_points : (L, 3) float64 or None
        Its points.
    lateral_canthus_index : int or None
        Position of the lateral canthus in the loop (the medial canthus is position 0).
    limbus : dict or None
        The limbus as the scan shows it: ``center``, ``radius``, ``source``, ``depth_mm``.
    uncertainty : dict or None
        Calibrated 1-sigma: ``limbus_mm``, ``axis_deg``, ``center_mm``, ``radius_mm``.
    placement : list of str or None
        The cues that carried the placement.
    doubts : list of str
        What the pipeline is not sure of about this eye, one sentence each (the eye is still
        published).
    extra : dict
        Every other key of the entry, carried unchanged (checks, the scan's sphere, the cornea,
        the texture fissure, the snap's report, ...; read from rig.json: the rig's ``surface``,
        ``joint``, ``pitch_axis``, ...).
    """

    side: str
    center: np.ndarray
    radius: float
    forward: np.ndarray
    loop_indices: np.ndarray | None = None
    loop_points: np.ndarray | None = None
    lateral_canthus_index: int | None = None
    limbus: dict | None = None
    uncertainty: dict | None = None
    placement: list | None = None
    doubts: list = field(default_factory=list)
    extra: dict = field(default_factory=dict, repr=False)

    #: Entry keys held by named fields (the rest is ``extra``).
    NAMED = ("center", "radius", "forward", "loop_indices", "loop_points", "lateral_canthus_index",
             "limbus", "uncertainty", "placement", "doubts")

    @property
    def unit_forward(self) -> np.ndarray:
        """(3,) the rest gaze, normalised."""
        f = np.asarray(self.forward, dtype=np.float64)
        return f / float(np.linalg.norm(f))

    @property
    def model_radius(self) -> float | None:
        """``r1`` of the parametric eye the rig's eyelid margin follows (rig.json's
        ``surface.parametric_eye``, checked by :func:`pipeline.io.rig_file.read_rig`); None: a
        sphere, or an eye that no rig has read (eyes.json has no ``surface``)."""
        surface = self.extra.get("surface")
        if isinstance(surface, dict) and "parametric_eye" in surface:
            return float(surface["parametric_eye"]["r1"])
        return None

    @classmethod
    def from_doc(cls, side: str, doc: dict, path="eyes.json", n_vertices: int | None = None) -> "Eye":
        """The eye of one ``eyes.json`` entry, validated (module doc); ScanError naming ``path``."""
        return _record(side, doc, path, n_vertices)

    def to_doc(self) -> dict:
        """The ``eyes.json`` entry: named fields and ``extra`` in :data:`KEY_ORDER` (a named
        field that is None is left out)."""
        named = {"center": np.asarray(self.center, float).tolist(), "radius": self.radius,
                 "forward": np.asarray(self.forward, float).tolist(),
                 "loop_indices": None if self.loop_indices is None else np.asarray(self.loop_indices).tolist(),
                 "loop_points": None if self.loop_points is None else np.asarray(self.loop_points, float).tolist(),
                 "lateral_canthus_index": self.lateral_canthus_index, "limbus": self.limbus,
                 "uncertainty": self.uncertainty, "placement": self.placement,
                 "doubts": list(self.doubts)}
        keep = {k: v for k, v in named.items() if v is not None}
        keep.update(self.extra)
        rank = {k: i for i, k in enumerate(KEY_ORDER)}
        return dict(sorted(keep.items(), key=lambda kv: rank.get(kv[0], len(rank))))


def eye_basis(forward) -> np.ndarray:
    """Orthonormal eye frame from a forward direction and head +Y: the frame in which an
    ``eyes.json`` record's loop is read (its lateral canthus, :func:`lateral_canthus_index`)
    and every later stage poses the eye (re-exported by pipeline/geometry/frame.py).

    Returns
    -------
    (3, 3) float64
        Rows ``e_x = normalize(Y x f)`` (toward head +X), ``e_y = f x e_x`` (up), ``e_z = f``.
    """
    f = np.asarray(forward, dtype=np.float64)
    f = f / np.linalg.norm(f)
    ex = np.cross([0.0, 1.0, 0.0], f)
    n = np.linalg.norm(ex)
    if n < 1e-6:
        raise ValueError("forward direction is vertical; pitch axis undefined")
    ex /= n
    ey = np.cross(f, ex)
    return np.stack([ex, ey, f])


def lateral_canthus_index(points, center, forward, side: str) -> int:
    """Position of the lateral canthus in a loop: the point farthest toward the eye's lateral
    side (head +X for the left eye, -X for the right) in the eye frame of ``forward``.

    Parameters
    ----------
    points : (L, 3) float64
        The loop's points.
    center : (3,) float64
    forward : (3,) float64
    side : str
    """
    x = (np.asarray(points, float) - center) @ eye_basis(forward)[0]
    return int(np.argmax(x if side == "left" else -x))


def _record(side: str, e, path, n_vertices):
    if not isinstance(e, dict):
        raise ScanError(path, f"has no '{side}' eye")
    try:
        c = np.asarray(e["center"], dtype=np.float64).reshape(3)
        r = float(e["radius"])
        f = np.asarray(e["forward"], dtype=np.float64).reshape(3)
    except KeyError as exc:
        raise ScanError(path, f"{side} eye: no {exc.args[0]}") from None
    except (TypeError, ValueError):
        raise ScanError(path, f"{side} eye: center, radius and forward must be numbers "
                              f"(3, 1 and 3 of them)") from None
    if not (np.isfinite(c).all() and np.isfinite(f).all() and np.isfinite(r)):
        raise ScanError(path, f"{side} eye: non-finite centre, radius or forward")
    if not 0.0 < r < 100.0:
        raise ScanError(path, f"{side} eye: radius {r:g} mm is not in (0, 100)")
    n = float(np.linalg.norm(f))
    if n < 1e-9:
        raise ScanError(path, f"{side} eye: forward is the zero vector")
    loop, lat = e.get("loop_indices"), e.get("lateral_canthus_index")
    if loop is not None:
        loop = np.asarray(loop)
        if loop.ndim != 1 or len(loop) < 8 or loop.dtype.kind not in "iu":
            raise ScanError(path, f"{side} eye: loop_indices must be at least 8 vertex indices")
        loop = loop.astype(np.int64)
        if len(np.unique(loop)) != len(loop):
            raise ScanError(path, f"{side} eye: loop_indices repeat a vertex (the loop is not simple)")
        if loop.min() < 0 or (n_vertices is not None and loop.max() >= n_vertices):
            raise ScanError(path, f"{side} eye: loop_indices outside the mesh's {n_vertices} vertices")
        if lat is not None and (not isinstance(lat, int) or isinstance(lat, bool)
                                or not 0 < lat < len(loop)):
            raise ScanError(path, f"{side} eye: lateral_canthus_index must be a position inside "
                                  f"the loop")
    else:
        lat = None
    doubts = e.get("doubts")
    if doubts is not None and (not isinstance(doubts, list)
                               or not all(isinstance(d, str) and d for d in doubts)):
        raise ScanError(path, f"{side} eye: doubts must be a list of sentences")
    pts = e.get("loop_points")
    if pts is not None:
        try:
            pts = np.asarray(pts, dtype=np.float64).reshape(-1, 3)
        except (TypeError, ValueError):
            raise ScanError(path, f"{side} eye: loop_points must be points (3 numbers each)") from None
    return Eye(side, c, r, f, loop, pts, lat, e.get("limbus"), e.get("uncertainty"),
               e.get("placement"), list(doubts or []),
               {k: v for k, v in e.items() if k not in Eye.NAMED})


def read_eyes(path, n_vertices: int | None = None) -> dict[str, Eye]:
    """Both eyes of an ``eyes.json``, validated (against ``n_vertices`` when given).

    Raises
    ------
    ScanError
        One line naming ``path``: missing, not JSON, another schema, or a bad entry.
    """
    from pipeline.io.docfile import read_json_doc

    path = Path(path)
    doc = read_json_doc(path, "eyes.json", SCHEMA, "remove_eyeballs")
    return {s: _record(s, doc.get(s), path, n_vertices) for s in SIDES}


def write_eyes(path, eyes: dict) -> None:
    """Write ``{"left": Eye, "right": Eye}`` (or entries as :func:`read_eyes` accepts them) with
    the schema number, atomically.

    Raises
    ------
    ScanError
        An entry that :func:`read_eyes` would refuse (one line naming ``path``); nothing is written.
    """
    out = {"schema": SCHEMA}
    for s in SIDES:
        e = eyes[s]
        out[s] = e.to_doc() if isinstance(e, Eye) else e
        _record(s, out[s], path, None)   # never write what read_eyes would refuse
    write_json(path, out)


def read_eye_loops(path, n_vertices: int) -> dict[str, Eye]:
    """Both eyes of an ``eyes.json`` as :func:`read_eyes` gives them, for retopo, which cuts
    along the loops: an eye without its ``loop_indices`` is refused in one line."""
    eyes = read_eyes(path, n_vertices)
    for side, e in eyes.items():
        if e.loop_indices is None:
            raise ScanError(path, f"{side} eye: no loop_indices (write it with remove_eyeballs)")
    return eyes
