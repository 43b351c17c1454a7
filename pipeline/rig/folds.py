"""Folds in the lid shapes: faces that turn over somewhere in the pitch sweep, and smoothing the
skin's motion around them (:func:`relax_folds`, called by the rig's build before its sweep).

The lid field (:mod:`pipeline.rig.lid_shapes`) is smooth in space; a fold comes from a sliver the
retopology left, where a smooth motion still carries one corner across the opposite edge.
"""

from __future__ import annotations

import numpy as np

from pipeline.geometry.meshtopo import turned_over_faces, vertex_adjacency
from pipeline.rig.lids import BlendShape, evaluate_shapes, lid_weights


def flipped_faces(V, F, shapes, pitches_deg, max_pitch_deg: float) -> np.ndarray:
    """Faces (indices) that turn over (:func:`pipeline.geometry.meshtopo.turned_over_faces`) at any of ``pitches_deg``."""
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    n0 = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    ok = np.linalg.norm(n0, axis=1) > 1e-12
    bad = np.zeros(len(F), bool)
    for p in pitches_deg:
        P = evaluate_shapes(V, shapes, lid_weights(p, max_pitch_deg))
        n1 = np.cross(P[F[:, 1]] - P[F[:, 0]], P[F[:, 2]] - P[F[:, 0]])
        bad |= ok & turned_over_faces(n0, n1)
    return np.flatnonzero(bad)


def relax_folds(V, F, shapes, eyes, pitches_deg, max_pitch_deg: float, rounds: int = 6,
                iterations: int = 8):
    """Smooth the shapes' motion of the skin around faces that turn over, until none does.

    The lid field is smooth in space, but on a sliver a smooth motion can still carry one corner
    across the opposite edge (a vertex lying almost on the edge of two others). Each round finds
    the faces that flip at any of ``pitches_deg``, takes their vertices and ``round`` rings of
    neighbours, less every margin and corner-strip vertex (their motion is the lid's), and
    replaces the displacement of those vertices in every stored pose by the mean of their
    neighbours' (``iterations`` Jacobi sweeps): locally the motion becomes nearly affine, which
    folds nothing. The round with the fewest flipped faces is returned (the shapes unchanged
    when none flips or no round helps).

    Returns
    -------
    shapes : list of BlendShape
    rounds_used : int
        The round returned; 0 = the shapes as given.
    n_relaxed : int
        Vertices whose motion was smoothed (all rounds).
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    n = len(V)
    locked = np.zeros(n, bool)
    for e in eyes:
        locked[e.loop] = True
        locked[e.strip_inner] = True
    A = vertex_adjacency(F, n)
    deg = np.maximum(np.asarray(A.sum(axis=1)).ravel(), 1.0)
    touched = np.zeros(n, bool)
    bad = flipped_faces(V, F, shapes, pitches_deg, max_pitch_deg)
    best = (len(bad), shapes, 0, 0)
    for r in range(1, rounds + 1):
        if len(bad) == 0:
            break
        region = np.zeros(n, bool)
        region[F[bad].ravel()] = True
        for _ in range(r):
            region |= (A @ region.astype(np.float64)) > 0
        region &= ~locked
        touched |= region
        out = []
        for s in shapes:
            w, offs = s.knots()
            D = np.zeros((len(w) - 1, n, 3))
            D[:, s.point_indices] = offs[1:]
            for _ in range(iterations):
                for k in range(len(D)):
                    D[k, region] = (A @ D[k])[region] / deg[region, None]
            moved = np.flatnonzero(np.abs(D).max(axis=(0, 2)) > 0.0)
            out.append(BlendShape(name=s.name, point_indices=moved.astype(np.int64),
                                  offsets=D[-1, moved], inbetween_weights=s.inbetween_weights,
                                  inbetween_offsets=D[:-1][:, moved]))
        shapes = out
        bad = flipped_faces(V, F, shapes, pitches_deg, max_pitch_deg)
        if len(bad) < best[0]:
            best = (len(bad), shapes, r, int(touched.sum()))
    # smoothing next to a margin can also turn a face over: keep the round with the fewest folds
    return best[1], best[2], best[3]


def _ring_of(F, n, loop, verts, max_rings=60) -> int | None:
    """Edge rings from ``loop`` to the nearest of ``verts``: 0 when one is a loop vertex (the
    band's first ring), k when k edges lead there; None beyond ``max_rings``."""
    A = vertex_adjacency(F, n)
    reached = np.zeros(n, bool)
    reached[loop] = True
    for k in range(max_rings + 1):
        if reached[verts].any():
            return k
        reached |= (A @ reached.astype(np.float64)) > 0
    return None


def _lid_of(k: int, lateral_index: int) -> str:
    """Which part of a loop (medial canthus first, upper lid, lateral canthus, lower lid) its
    vertex ``k`` lies on."""
    if k == 0:
        return "medial canthus"
    if k == lateral_index:
        return "lateral canthus"
    return "upper lid" if k < lateral_index else "lower lid"


def fold_report(V, F, eyes, shapes, pitches_deg, max_pitch_deg: float) -> dict | None:
    """Where the lid sweep folds: the faces the sweep counts (:func:`pipeline.rig.sweep.sweep_check`:
    a vertex moved by a shape, turned over at some pitch: :func:`pipeline.geometry.meshtopo.turned_over_faces`), each given
    to the eye and lid whose loop vertex lies nearest its centroid.

    Returns None when no face turns over, else a dict: ``faces`` (how many turn at some pitch),
    ``per_lid`` (``"<side> <lid>"`` -> count), ``first_pitch_deg`` (the pitch nearest rest at
    which a face turns), and ``worst``: the face that turns furthest (``face``, ``turn_deg``,
    ``pitch_deg`` where it turns furthest, ``first_pitch_deg`` where it first turns, ``side``,
    ``lid``, ``loop_vertex`` (its loop position, medial canthus 0) and ``loop_length``, ``ring``
    (edge rings out from the loop: the band's ring, 0 = touching the margin),
    ``margin_mm`` (its centroid's distance from that loop vertex) and ``position_mm`` (the
    centroid in the head frame)). The refusal names these, so a fold can be found."""
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    n0 = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    l0 = np.linalg.norm(n0, axis=1)
    moved = np.zeros(len(V), bool)
    for s in shapes:
        moved[s.point_indices] = True
    check = (l0 > 1e-12) & moved[F].any(axis=1)
    worst_cos = np.full(len(F), np.inf)
    worst_pitch = np.zeros(len(F))
    first = np.full(len(F), np.nan)
    # nearest rest first, so a face's first pitch is the smallest turn of the eye that folds it
    for p in sorted(pitches_deg, key=lambda q: (abs(q), q)):
        P = evaluate_shapes(V, shapes, lid_weights(p, max_pitch_deg))
        n1 = np.cross(P[F[:, 1]] - P[F[:, 0]], P[F[:, 2]] - P[F[:, 0]])
        cos = np.einsum("ij,ij->i", n0, n1) / np.maximum(l0 * np.linalg.norm(n1, axis=1), 1e-300)
        cos = np.where(check & turned_over_faces(n0, n1), cos, np.inf)
        flip = cos <= 0
        first[flip & np.isnan(first)] = p
        better = cos < worst_cos
        worst_cos[better], worst_pitch[better] = cos[better], p
    bad = np.flatnonzero(~np.isnan(first))
    if len(bad) == 0:
        return None
    C = V[F[bad]].mean(axis=1)
    # every flipped face to the eye and loop vertex nearest it
    dist = np.stack([np.min(np.linalg.norm(C[:, None] - V[e.loop][None], axis=2), axis=1) for e in eyes])
    owner = np.argmin(dist, axis=0)
    per_lid: dict[str, int] = {}
    for i, f in enumerate(bad):
        e = eyes[owner[i]]
        k = int(np.argmin(np.linalg.norm(V[e.loop] - C[i], axis=1)))
        key = f"{e.side} {_lid_of(k, e.lateral_index)}"
        per_lid[key] = per_lid.get(key, 0) + 1
    j = int(np.argmin(worst_cos[bad]))
    f, e = int(bad[j]), eyes[owner[j]]
    k = int(np.argmin(np.linalg.norm(V[e.loop] - C[j], axis=1)))
    earliest = bad[np.argmin(np.abs(first[bad]))]
    return {"faces": int(len(bad)), "per_lid": dict(sorted(per_lid.items(), key=lambda t: -t[1])),
            "first_pitch_deg": float(first[earliest]),
            "worst": {"face": f, "turn_deg": float(np.degrees(np.arccos(np.clip(worst_cos[f], -1.0, 1.0)))),
                      "pitch_deg": float(worst_pitch[f]), "first_pitch_deg": float(first[f]),
                      "side": e.side, "lid": _lid_of(k, e.lateral_index), "loop_vertex": k,
                      "loop_length": int(len(e.loop)), "ring": _ring_of(F, len(V), e.loop, F[f]),
                      "margin_mm": float(np.linalg.norm(C[j] - V[e.loop[k]])),
                      "position_mm": [round(float(x), 2) for x in C[j]]}}


def describe_folds(rep: dict) -> str:
    """One clause for the refusal: where the worst flipped face lies and at which pitch."""
    w = rep["worst"]
    ring = "beyond 60 rings" if w["ring"] is None else f"ring {w['ring']}"
    lids = ", ".join(f"{k} {v}" for k, v in rep["per_lid"].items())
    return (f"worst on the {w['side']} eye's {w['lid']}: a face turned {w['turn_deg']:.0f} deg at pitch "
            f"{w['pitch_deg']:+g} deg (over from {w['first_pitch_deg']:+g} deg), {ring} out from loop vertex "
            f"{w['loop_vertex']} of {w['loop_length']} ({w['margin_mm']:.1f} mm off the margin), at "
            f"({', '.join(f'{x:.1f}' for x in w['position_mm'])}) mm in the head frame; faces turning over "
            f"at some pitch, per lid: {lids}; the first at pitch {rep['first_pitch_deg']:+g} deg")
