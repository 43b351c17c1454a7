"""Stage ``remove_eyeballs``: place both eyes, cut the scanned eyes out of the head.

Holes near the eyes are closed for the placement (:func:`pipeline.geometry.mesh_edit.fill_holes_near`)
and given to the opening; both eyes are placed together on a local sub-mesh by
:mod:`pipeline.placement` (a MAP fit of an eye model from every cue the scan keeps, with a
calibrated uncertainty; an eye the geometry cannot place is placed from the colour texture and
cut along the fissure the photograph shows; an opening a scanner filled flat is cut along the
fill's boundary, :mod:`pipeline.placement.fill`). The regions are cut out leaving one simple loop per
opening; each loop vertex moves to where the uncut surface lifts off the placed eye by
``margin_lift_mm`` (projected onto the eye; flip-guarded; loop vertices on a
reconstruction-filled crease keep the cut); loops are ordered from the medial canthus over the
upper lid; then :func:`pipeline.placement.place.judge_pair` says what is published of each eye
(its self-checks and doubts). Only what cannot be an asset is refused (a closed eye, nothing
eye-like near a hint, a cut that leaves no simple loop, a loop that misses the fitted sphere and
cuts into the eye the asset would carry: ``loop_on_eye``, a loop narrower than any eye's fissure:
``opening_wide``); an eye placed from little evidence, or
failing another self-check, is published with a doubt.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from pipeline.errors import ScanError
from pipeline.fork import fork_call, fork_result
from pipeline.geometry import meshtopo
from pipeline.geometry.flips import move_guarded
from pipeline.geometry.frame import eye_basis
from pipeline.geometry.mesh_edit import fill_holes_near
from pipeline.geometry.spherefit import signed_distance
from pipeline.placement.eye_fit import eye_surface_distance, local_mesh, median_edge_length
from pipeline.placement.place import NO_EYE, NarrowOpening, judge_pair, place_pair
from pipeline.remove_eyeballs.fissure_cut import move_loop_onto, openings_at_fissures
from pipeline.remove_eyeballs.settings import RemoveEyeballsSettings
from pipeline.results import StageResult

SIDES = ("left", "right")


def order_loop(loop, V, center, forward, side):
    """Rotate/reverse a closed loop: start at the medial canthus, upper lid first.

    Returns
    -------
    loop : (L,) int64
    lateral_index : int
        Position of the lateral canthus in the returned loop.
    """
    B = eye_basis(forward)
    Q = (V[loop] - center) @ B.T
    sign = 1.0 if side == "left" else -1.0
    x = Q[:, 0] * sign  # positive = lateral
    m = int(np.argmin(x))
    loop = np.roll(loop, -m)
    Q = np.roll(Q, -m, axis=0)
    x = np.roll(x, -m)
    lat = int(np.argmax(x))
    y_first = Q[1:lat, 1].mean() if lat > 1 else Q[1, 1]
    y_second = Q[lat + 1:, 1].mean() if lat + 1 < len(loop) else Q[-1, 1]
    if y_first < y_second:
        loop = np.concatenate([loop[:1], loop[1:][::-1]])
        lat = len(loop) - lat
    return loop, int(lat)


@dataclass
class RemovalResult:
    """What the stage writes: ``mesh`` (the arrays of mesh.npz, the eyes cut out), ``eyes``
    (side -> :class:`pipeline.io.eyes_file.Eye`), and ``result`` (its metrics); ``fits``: side
    -> the placement's :class:`pipeline.placement.eye_fit.EyeFit` (its region on the input)."""

    mesh: dict
    eyes: dict
    fits: dict
    result: StageResult

    @property
    def metrics(self) -> dict:
        return self.result.metrics


def _lift_off_points(V, F, loop_old, h, tau, reach, k=3):
    """Where the surface lifts off the eye by ``tau``, nearest to each loop vertex.

    The ``tau`` iso-line of the height field is sampled where it crosses the edges of the uncut
    mesh near the loop (linear interpolation along each edge); each loop vertex gets the mean
    of its ``k`` nearest crossing points within ``reach`` mm (itself when there are none).

    Parameters
    ----------
    V : (n, 3) float64
    F : (m, 3) int64
        The uncut mesh.
    loop_old : (L,) int64
        Loop vertices (ids of ``V``).
    h : (n,) float64
        Height of each vertex above the eye surface (NaN where unknown).
    tau : float
    reach : float
    k : int

    Returns
    -------
    (L, 3) float64
    """
    from scipy.spatial import cKDTree

    ok = np.isfinite(h)
    first = np.flatnonzero(ok[F[:, 0]])     # h is known near the loop only: test the few faces
    Fl = F[first[ok[F[first, 1]] & ok[F[first, 2]]]]   # whose first corner has it (same faces)
    E = np.concatenate([Fl[:, [0, 1]], Fl[:, [1, 2]], Fl[:, [2, 0]]])
    E = np.unique(np.sort(E, axis=1), axis=0)
    ha, hb = h[E[:, 0]], h[E[:, 1]]
    cross = (ha - tau) * (hb - tau) < 0
    E, ha, hb = E[cross], ha[cross], hb[cross]
    out = V[loop_old].copy()
    if len(E) == 0:
        return out
    t = (tau - ha) / (hb - ha)
    P = V[E[:, 0]] + t[:, None] * (V[E[:, 1]] - V[E[:, 0]])
    kk = min(k, len(P))
    dist, idx = cKDTree(P).query(out, k=kk)
    dist, idx = dist.reshape(len(out), kk), idx.reshape(len(out), kk)
    w = (dist <= reach).astype(np.float64)
    n = w.sum(axis=1)
    has = n > 0
    out[has] = (P[idx[has]] * w[has, :, None]).sum(axis=1) / n[has, None]
    return out


def _project_to_eye(P, center, radius, cornea=None):
    """Closest points on the surface of the two-sphere eye (sclera sphere or corneal sphere,
    whichever is nearer), (n, 3)."""
    def onto(c, r):
        w = P - c
        return c + r * w / np.maximum(np.linalg.norm(w, axis=1), 1e-12)[:, None]
    out = onto(center, radius)
    if cornea is not None:
        ds = np.abs(signed_distance(P, center, radius))
        dc = np.abs(signed_distance(P, cornea["center"], cornea["radius"]))
        use = (dc < ds) & (signed_distance(P, center, radius) > 0)
        out[use] = onto(np.asarray(cornea["center"]), cornea["radius"])[use]
    return out


def _move_to_lift_off(V, F, V2, F2, old_ids, loop, fit, tau, min_cos=0.5, on_eye=0.3):
    """Move the loop vertices of the cut mesh (in place) to where the uncut surface lifts off the
    fitted eye surface by ``tau`` (``_lift_off_points``), the eyelid margin at a sub-edge
    position; a move that would turn an incident face by more than ``acos(min_cos)`` or shrink
    it below a tenth of its area is halved (three times, then dropped). Returns the mean move, mm.
    """
    loop_old = old_ids[loop]
    L = V[loop_old]
    on_loop = np.zeros(len(V2), bool)     # np.isin over the whole cut mesh sorted all its indices
    on_loop[loop] = True
    reach = 2.0 * median_edge_length(V2, F2[meshtopo.faces_touching(F2, on_loop)])
    lo, hi = L.min(axis=0) - reach - 1.0, L.max(axis=0) + reach + 1.0
    box = np.flatnonzero(((V >= lo) & (V <= hi)).all(axis=1))
    h = np.full(len(V), np.nan)
    h[box] = eye_surface_distance(V[box], fit.center, fit.radius, fit.cornea)
    target = _lift_off_points(V, F, loop_old, h, tau, reach)
    # onto the eye surface (the margin lies on the eyeball; the scan rounds the crease)
    # only where the cut reached the eyeball (the loop vertex lies within on_eye of it, so the
    # margin is between it and the first lid vertex); a loop vertex already lifted off lies on a
    # reconstruction-filled crease whose margin is hidden under the surface, and dropping the
    # loop there would fold the lid rim
    on = np.abs(h[loop_old]) <= on_eye
    target = np.where(on[:, None], _project_to_eye(target, fit.center, fit.radius, fit.cornea), L)
    start = V2[loop].copy()
    moved = move_guarded(V2, F2, loop, target, min_cos, min_area_ratio=0.1)
    apart = _apart(V2[loop], start)
    if apart is None:
        return moved
    V2[loop] = start
    return move_guarded(V2, F2, loop, np.where(apart[:, None], start, target), min_cos, min_area_ratio=0.1)


#: Two loop vertices this close (mm) after the move lie on one point.
APART_MM = 1e-4


def _apart(P, start):
    """Which loop vertices to leave where the cut put them so that no two lie on one point: of
    each pair of moved positions ``P`` (L, 3) within ``APART_MM`` that started apart (``start``),
    the later; None when there is no such pair. Two loop vertices a sliver apart can average the
    same lift-off points, and moved together the two faces between them fold flat (`n1402_wide`:
    vertices 0.35 mm apart on either side of one edge, which retopo's weld then made one face
    twice, and its band found no annulus). Copies of one scan vertex (a bow-tie on the opening,
    one per fan) start together and move together."""
    from scipy.spatial import cKDTree

    P = np.asarray(P, dtype=np.float64)
    start = np.asarray(start, dtype=np.float64)
    keep = np.zeros(len(P), bool)
    for i, j in sorted(cKDTree(P).query_pairs(APART_MM)):
        if np.linalg.norm(start[i] - start[j]) > APART_MM:
            keep[j] = True
    return keep if keep.any() else None


def _opening_holes(region, F, holes, hole_of_face, n_faces, min_share=0.3):
    """The fitted region on the original faces. A hole whose fill or rim the region reaches
    (``min_share`` of its rim vertices, or half its fill) is part of the opening: the faces
    around it join the region, so the cut border passes around it (a scanner loses the crease
    where lid meets eye as easily as the pupil). A hole the region only grazes is kept off it."""
    out = region[:n_faces].copy()
    Fo = F[:n_faces]
    inside = np.zeros(int(F.max()) + 1, bool)
    inside[Fo[out].ravel()] = True
    for k, loop in enumerate(holes):
        rim = np.isin(Fo, loop).any(axis=1)
        if region[hole_of_face == k].mean() >= 0.5 or inside[loop].mean() >= min_share:
            out |= rim
        else:
            out &= ~rim
    return out


def _settle_holes(F, region, H, min_share=0.3, rounds=6):
    """``region`` (faces removed for one eye) with its border made one simple loop where it
    meets the scan's own holes (``H``: the scan's boundary half-edges). The fit settles the
    holes within ``sample_radius_mm`` of the hint (:func:`_opening_holes`); a hole farther out
    that the region still reaches (near a canthus of an eye turned out: ``id71_out``'s right,
    a hole of the scan pinched at a vertex into two), or one it touches at a single vertex
    (``id64_in``'s left), made the cut's boundary a bow-tie or a loop through vertices of no eye
    face, and the scan was refused. As :func:`_opening_holes`: a hole with
    ``min_share`` of its rim on the region joins the opening (its rim's faces join the region),
    one the region only grazes is kept off it (the region's faces at its rim stay skin, and
    retopo fills the hole); then a vertex where the region's border still meets itself loses
    the region's faces round it. A region that meets no hole and has no such vertex is returned
    as it came."""
    H = np.asarray(H, dtype=np.int64).reshape(-1, 2)
    region = np.asarray(region, dtype=bool)
    if not region.any():
        return region
    n = int(F.max()) + 1
    on_hole = np.zeros(n, bool)
    on_hole[H.ravel()] = True
    out = region.copy()
    for _ in range(rounds):
        inside = np.zeros(n, bool)
        inside[F[out].ravel()] = True
        touched = inside & on_hole
        new = out.copy()
        if touched.any():
            # asked every round: a rim that joined may reach another hole
            for loop in _holes_through(H, touched):
                share = float(inside[loop].mean())
                if share == 0.0:
                    continue
                mask = np.zeros(n, bool)
                mask[loop] = True
                if share == 1.0 and _rim_inside(F, out, H, mask):
                    continue
                rim = meshtopo.faces_touching(F, mask)
                new = new | rim if share >= min_share else new & ~rim
        # the region's border half-edges: a region face's edge whose twin is no region face
        Fr = F[new]
        a = np.concatenate([Fr[:, 0], Fr[:, 1], Fr[:, 2]])
        b = np.concatenate([Fr[:, 1], Fr[:, 2], Fr[:, 0]])
        key = a * n + b
        border = ~np.isin(b * n + a, key)
        deg = np.bincount(a[border], minlength=n) + np.bincount(b[border], minlength=n)
        # only a vertex the cut keeps can pinch its boundary: one whose every face goes with the
        # region (a scanner's hole pinched at a vertex, both its fans inside) leaves no vertex
        # there (fresh31's `n3703_squint_in`: losing those fans left the scan's own pinch on the
        # opening's loop, and the scan was refused for a bow-tie)
        kept = np.zeros(n, bool)
        kept[F[~new].ravel()] = True
        bad = (deg > 2) & kept
        if bad.any():
            new &= ~meshtopo.faces_touching(F, bad)
        if np.array_equal(new, out):
            break
        out = new
    return out


def _rim_inside(F, region, H, mask) -> bool:
    """Whether every boundary half-edge of the hole ``mask`` (its vertices) lies on a face of
    ``region``: the cut then takes the whole hole. Every rim vertex on a region face is not
    enough: a hole in a pupil the scanner left open (``n1501_pupil_holes``) had each vertex on
    the region but one edge's face outside it, and after the cut the hole and the opening were
    one loop, the scan refused for a loop count."""
    hk = H[mask[H[:, 0]] & mask[H[:, 1]]]
    near = np.flatnonzero(meshtopo.faces_touching(F, mask))
    Fn = F[near]
    n = int(F.max()) + 1
    key = np.concatenate([Fn[:, [0, 1]], Fn[:, [1, 2]], Fn[:, [2, 0]]]) @ np.array([n, 1])
    fid = np.tile(near, 3)
    order = np.argsort(key)
    pos = np.searchsorted(key[order], hk[:, 0] * n + hk[:, 1])
    return bool(region[fid[order[pos]]].all())


def _boundary_pieces(H):
    """``(bv, Hc, comp)`` of the boundary half-edges ``H`` (k, 2): the boundary's vertex ids, the
    half-edges as indices into them, and each vertex's connected piece (a hole, simple or pinched
    at a vertex into two)."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    bv, Hc = np.unique(H, return_inverse=True)
    Hc = Hc.reshape(-1, 2)
    _, comp = connected_components(coo_matrix((np.ones(len(Hc)), (Hc[:, 0], Hc[:, 1])),
                                              shape=(len(bv), len(bv))), directed=False)
    return bv, Hc, comp


def _holes_through(H, vmask):
    """The vertex ids of each piece of the boundary half-edges ``H`` (:func:`_boundary_pieces`)
    that passes through a vertex of ``vmask``."""
    bv, _, comp = _boundary_pieces(H)
    return [bv[comp == c] for c in np.unique(comp[vmask[bv]])]


def _hole_at_bow_ties(V, H_in, H2, old_ids, ids_new):
    """Where the cut's boundary meets itself at vertices of the scan's own holes (``H_in``, the
    scan's boundary half-edges; ``H2`` the cut mesh's, on its vertices ``old_ids`` of the scan;
    ``ids_new`` the eye region's border vertices on the cut mesh): ``(perimeter mm, centre (3,)
    rounded, bow-tie count)`` of the largest such hole, or None. The opening then runs into a
    scanner hole through a strip of skin a face wide (``n2003_trim_tight``: a 168 mm trim hole
    over the right eye's upper lid), and the cut has no simple loop to give."""
    H2 = np.asarray(H2, np.int64).reshape(-1, 2)
    out = np.bincount(H2[:, 0], minlength=len(old_ids))
    ids = np.fromiter(ids_new, dtype=np.int64)
    bt = old_ids[ids[out[ids] > 1]]
    if len(bt) == 0:
        return None
    mask = np.zeros(len(V), bool)
    mask[bt] = True
    H_in = np.asarray(H_in, np.int64).reshape(-1, 2)
    best = None
    for loop in _holes_through(H_in, mask):
        on = np.zeros(len(V), bool)
        on[loop] = True
        e = H_in[on[H_in[:, 0]]]
        perim = float(np.linalg.norm(V[e[:, 0]] - V[e[:, 1]], axis=1).sum())
        if best is None or perim > best[0]:
            best = (perim, np.round(V[loop].mean(axis=0), 1).tolist(), int(mask[loop].sum()))
    return best


def _holes_inside(F, remove, H=None):
    """Number of the mesh's boundary loops whose every edge belongs to a removed face (holes in
    the eye openings, which the cut absorbs). ``H``: the mesh's boundary half-edges, when already
    computed."""
    H = meshtopo.boundary_halfedges(F) if H is None else H
    if len(H) == 0:
        return 0
    # the face of each boundary half-edge a -> b, looked up among the faces at boundary
    # vertices only (a few thousand of a scan's million: sorting all edges took 0.13 s)
    n = int(F.max()) + 1
    on_boundary = np.zeros(n, bool)
    on_boundary[H[:, 0]] = True
    near = np.flatnonzero(meshtopo.faces_touching(F, on_boundary))
    Fn = F[near]
    E = np.concatenate([Fn[:, [0, 1]], Fn[:, [1, 2]], Fn[:, [2, 0]]])
    fid = np.tile(near, 3)
    key = E[:, 0] * n + E[:, 1]
    order = np.argsort(key)
    hf = fid[order[np.searchsorted(key[order], H[:, 0] * n + H[:, 1])]]
    _, Hc, comp = _boundary_pieces(H)
    ecomp = comp[Hc[:, 0]]
    kept = np.zeros(comp.max() + 1, bool)
    np.logical_or.at(kept, ecomp, ~remove[hf])
    return int((~kept).sum())


def place_near_hints(mesh_arrays, hints: dict, st: RemoveEyeballsSettings, *, source="mesh",
                     texture=None, prior=None, coarse=None, placed=None, declared_open=()):
    """Place both eyes (:func:`pipeline.placement.place.place_pair`) on the surface around the
    hints, its holes near the eyes closed for the fit; each hole then goes with the opening or
    the skin (:func:`_opening_holes`).

    ``prior``: callable ``(V, F, hint, side) -> {"front", "axis"}`` (the eye-region prior,
    ``pipeline.placement.prior.EyeRegionPrior.register``) or None. Returns ``(fits,
    placements, median_edge, searched)``: per side an :class:`EyeFit` (its region on the full
    mesh) and the :class:`pipeline.placement.uncertainty.Placement` (None for an eye placed from
    its texture, a fill or its opening), the scan's median edge length, and what the search
    found (:func:`place_pair`). ``coarse``, ``placed``, ``declared_open``: as :func:`place_pair`'s."""
    V = np.asarray(mesh_arrays["V"], dtype=np.float64)
    F = np.asarray(mesh_arrays["F"], dtype=np.int64)
    median_edge, max_edge = median_edge_length(V, F, with_max=True)
    # everything a fit reads lies within the patch of its hint, plus a few edge rings: fit on
    # that sub-mesh, which keeps the full mesh's face/vertex order, and map regions back
    reach = max(st.patch_radius_mm, st.place_patch_mm) + 5.0 + 6.0 * median_edge + max(2.0, 1.5 * median_edge)
    centres = [np.asarray(hints[s], float) for s in SIDES]
    Vs, Fs, faces, verts = local_mesh(V, F, centres, reach, max_edge=max_edge)
    n_local = len(Fs)
    Vs, Fs, holes, hole_of_face = fill_holes_near(Vs, Fs, centres, st.sample_radius_mm,
                                                  st.max_hole_perimeter_mm)
    sub_arrays = {k: (np.asarray(mesh_arrays[k])[faces] if k == "FUV" else mesh_arrays[k])
                  for k in ("UV", "FUV") if k in mesh_arrays}
    if holes and "FUV" in sub_arrays:   # fan faces take the texture corners of a rim face
        rim = np.array([np.flatnonzero(np.isin(Fs[:n_local], loop).any(axis=1))[0] for loop in holes])
        sub_arrays["FUV"] = np.concatenate([sub_arrays["FUV"],
                                            sub_arrays["FUV"][rim[hole_of_face[n_local:]]]])
    _, fits, placements, searched = place_pair(Vs, Fs, hints, st, median_edge=median_edge,
                                     filled=hole_of_face >= 0, uv=sub_arrays, texture=texture,
                                     prior=prior, source=source, coarse=coarse, placed=placed,
                                     declared_open=declared_open)
    for fit in fits.values():       # back to full-mesh ids
        region = np.zeros(len(F), bool)
        region[faces[_opening_holes(fit.region, Fs, holes, hole_of_face, n_local)]] = True
        fit.region = region
        if fit.inliers is not None:
            inl = np.asarray(fit.inliers, dtype=np.int64)
            fit.inliers = verts[inl[inl < len(verts)]]
    return fits, placements, median_edge, searched


def remove_eyeballs(mesh_arrays: Mapping, hints: dict, st: RemoveEyeballsSettings | None = None, *,
                    source="mesh", texture=None, prior=None, eyeball=None, declared_open=()) -> RemovalResult:
    """Fit both eyes and cut the scanned eyeball surface out of the head mesh.

    Parameters
    ----------
    mesh_arrays : StageMesh or dict
        ``V`` (n,3) float64 mm head frame, ``F`` (m,3) int64, optional ``UV``/``FUV``/``VC``
        and other per-face/per-vertex arrays (carried through).
    hints : dict
        ``{"left": (3,), "right": (3,)}`` eye hints, head frame mm.
    st : RemoveEyeballsSettings
    source : str
        File named in error messages.
    texture : (h, w, 3) uint8, optional
        Colour texture (used when geometry alone cannot find the eye).
    prior : callable, optional
        The eye-region prior (``pipeline.placement.prior.EyeRegionPrior.register``), or None.
    eyeball : EyeballParams, optional
        The parametric eyeball the asset carries (its ``r1`` and ``iris_radius``; default the
        paper's): the asset's eye is that eyeball anchored at the scan's limbus
        (:mod:`pipeline.placement.human_eye`).
    declared_open : tuple of str
        The sides the user declared open (scan.yaml ``eyes.<side>.open``): an eye that looks
        closed there is placed behind the opening the eye-region prior outlines, doubted.

    Returns
    -------
    RemovalResult
        ``mesh`` (arrays with the eyeball faces removed and vertices re-indexed),
        ``eyes`` (:class:`pipeline.io.eyes_file.Eye` per side), ``fits`` (EyeFit per side),
        ``result`` (the metrics).
    """
    st = st or RemoveEyeballsSettings()
    # the scan's own boundary (one sort of its 3m half-edges, a tenth of the stage on a 1.4M-face
    # scan) depends on the faces only: a child finds it while the eyes are placed (pipeline.fork)
    job = fork_call(meshtopo.boundary_mask, np.asarray(mesh_arrays["F"], dtype=np.int64))
    fits, placements, median_edge, searched = place_near_hints(mesh_arrays, hints, st, source=source,
                                                               texture=texture, prior=prior,
                                                               declared_open=declared_open)
    cut = dict(source=source, texture=texture, eyeball=eyeball, boundary=(mesh_arrays, fork_result(job)[0]))
    coarse, notched, first = {}, set(), None

    def both(exc):      # the first refusal and why the eye placed again is refused too, one line
        return ScanError(source, f"{first.problem}; placed behind the opening the eye-region prior "
                                 f"outlines instead: {exc.problem}")

    while True:
        try:
            result = _cut_and_judge(mesh_arrays, hints, st, fits, placements, median_edge, **cut)
        except NarrowOpening as exc:
            if prior is None:
                raise
            if exc.side in coarse:
                raise both(exc) from None
            # the cut went round part of an eye the geometry misplaced (an eye looking down, the
            # upper lid lowered over it: id303_down's left eye): that eye is placed again behind
            # the opening the eye-region prior outlines in the skin round it, doubted
            coarse[exc.side] = (f"the cut round the eye the geometry found spans {exc.width_mm:.1f} mm "
                                f"{exc.why}")
            if exc.notched:
                notched.add(exc.side)
            first = first or exc
        except ScanError as exc:
            if first is None:
                raise
            raise both(exc) from None
        else:
            closed_pair(result.fits, source, declared_open)
            return result
        try:
            # every other eye as the search found it: one it placed from its opening (a coarse
            # photogrammetry head's) is placed so again, not taken for closed
            fits, placements, median_edge, _ = _place_again(mesh_arrays, hints, st, coarse, searched, prior, cut,
                                                            declared_open)
            for s in notched:   # a cut notched round an iris outside it: no eye's surface (NO_EYE)
                if fits[s].method == "coarse" and s not in declared_open:
                    fits[s].no_eye = "notched"
        except ScanError as exc:
            raise both(exc) from None


def closed_pair(fits: dict, source, declared_open=()) -> None:
    """Refuse a pair of closed lids: both eyes placed behind the prior's opening because the
    surface the search found round each was no eye's (``EyeFit.no_eye``, :data:`NO_EYE`), and
    neither declared open. A closed lid's bulge offers the search a sphere ringed by a fold that
    lies off the opening the skin outlines, or whose cut is notched round an iris outside it; an
    open eye the scan shows offers its own surface on at least one side. A ScanError naming
    ``source`` and what each eye's search found."""
    if declared_open or not all(fits[s].method == "coarse" and fits[s].no_eye in NO_EYE for s in SIDES):
        return
    why = "; ".join(f"{s}: {fits[s].why.rsplit(': placed behind', 1)[0]}" for s in SIDES)
    raise ScanError(source, f"both eyes look closed: the surface the search found round neither eye is "
                            f"an eye's, as closed lids give ({why}) (if the eyes are open, say so in "
                            f"scan.yaml: eyes.left.open: true and eyes.right.open: true)")


def _place_again(mesh_arrays, hints, st, coarse: dict, searched, prior, cut, declared_open=()):
    """:func:`place_near_hints` with the eyes ``coarse`` (side -> why) placed behind the opening
    the eye-region prior outlines and the others from what the first search found
    (``searched``; the search is not run again)."""
    return place_near_hints(mesh_arrays, hints, st, source=cut["source"], texture=cut["texture"],
                            prior=prior, coarse=coarse, placed=searched, declared_open=declared_open)


def _cut_and_judge(mesh_arrays, hints, st, fits, placements, median_edge, *, source, texture,
                   eyeball, boundary=None) -> RemovalResult:
    """Cut both placed eyes' regions out of the scan and judge what is published
    (:func:`remove_eyeballs`). ``boundary``: ``(arrays, meshtopo.boundary_mask(arrays["F"]))``
    when already found."""
    # an eye placed from its texture is cut along the fissure the photograph shows: the faces
    # near that outline are split first (pipeline/remove_eyeballs/fissure_cut.py)
    scan_arrays = mesh_arrays
    mesh_arrays, fits = openings_at_fissures(mesh_arrays, fits)
    V = np.asarray(mesh_arrays["V"], dtype=np.float64)
    F = np.asarray(mesh_arrays["F"], dtype=np.int64)
    if (fits["left"].region & fits["right"].region).any():
        raise ScanError(source, "the two eye regions overlap (hints too close or wrong)")
    # one sort of the scan's directed edges gives its boundary and whether it is edge-manifold;
    # the cut mesh's boundary follows from it by a look-up near the openings (meshtopo.cut_boundary_mask)
    open_in, repeated = (boundary[1] if boundary is not None and boundary[0] is scan_arrays is mesh_arrays
                         else meshtopo.boundary_mask(F))
    H_in = meshtopo.halfedges_of(F, open_in)
    loops_in = meshtopo.boundary_component_count(F, H_in)
    for s in SIDES:
        fits[s].region = _settle_holes(F, fits[s].region, H_in)
    remove = fits["left"].region | fits["right"].region
    absorbed = _holes_inside(F, remove, H_in)
    keepF = ~remove
    F2 = F[keepF]
    used = np.zeros(len(V), bool)
    used[F2.ravel()] = True
    remap = -np.ones(len(V), dtype=np.int64)
    remap[used] = np.arange(used.sum())
    out = {}
    nV, nF = len(V), len(F)
    for k, a in mesh_arrays.items():
        a = np.asarray(a)
        if k == "F":
            out[k] = remap[F2]
        elif k == "V":
            out[k] = V[used]
        elif k == "FUV":
            out[k] = a[keepF]
        elif k in ("poly_counts", "poly_indices"):
            continue  # polygons are not kept through a cut of the triangulation
        elif a.ndim >= 1 and a.shape[0] == nV and k not in ("UV",):
            out[k] = a[used]
        elif a.ndim >= 1 and a.shape[0] == nF and k not in ("UV",):
            out[k] = a[keepF]
        else:
            out[k] = a
    if "UV" in out and "FUV" in out:
        usedt = np.zeros(len(out["UV"]), bool)
        usedt[out["FUV"].ravel()] = True
        rt = -np.ones(len(out["UV"]), dtype=np.int64)
        rt[usedt] = np.arange(usedt.sum())
        out["UV"] = out["UV"][usedt]
        out["FUV"] = rt[out["FUV"]]
    V2, F2n = out["V"], out["F"]
    H2 = meshtopo.halfedges_of(F2n, meshtopo.cut_boundary_mask(F, open_in, remove))
    n_loops_out = meshtopo.boundary_component_count(F2n, H2)
    # region border vertices (old ids) per eye -> loops touching them
    loops, moved = {}, {}
    old_ids = np.flatnonzero(used)
    for s in SIDES:
        fit = fits[s]
        border = np.zeros(len(V), bool)
        border[F[fit.region].ravel()] = True
        border &= used
        ids_new = set(remap[border].tolist())
        try:
            mine = meshtopo.boundary_loops(F2n, only=np.fromiter(ids_new, dtype=np.int64), H=H2)
        except ValueError as exc:
            hole = _hole_at_bow_ties(V, H_in, H2, np.flatnonzero(used), ids_new)
            if hole is not None:
                raise ScanError(source, f"{s} eye: a hole in the scan ({hole[0]:.0f} mm round, centred "
                                        f"{hole[1]}) runs into the eye's opening, meeting it at "
                                        f"{hole[2]} vertices with no skin between them; fill the hole "
                                        f"or scan the region again") from None
            raise ScanError(source, f"{s} eye: the cut left a non-simple boundary ({exc})") from None
        if len(mine) != 1:
            raise ScanError(source, f"{s} eye: the cut left {len(mine)} boundary loops at the eye "
                                    f"opening instead of one")
        loop = mine[0]
        if st.margin_lift_mm > 0 and fit.method == "geometry":
            moved[s] = _move_to_lift_off(V, F, V2, F2n, old_ids, loop, fit, st.margin_lift_mm,
                                         np.cos(np.radians(st.margin_max_turn_deg)),
                                         st.margin_on_eye_mm)
        elif getattr(fit, "fissure", None) is not None:   # the cut's loop onto the fissure itself
            moved[s] = move_loop_onto(V2, F2n, loop, fit.fissure)
        try:
            loops[s] = order_loop(loop, V2, fit.center, fit.forward, s)
        except ValueError:      # eye_basis: a gaze straight up or down has no pitch axis
            raise ScanError(source, f"{s} eye: the fitted gaze {np.round(fit.forward, 3).tolist()} "
                                    f"is vertical; not an eye") from None
    if n_loops_out != loops_in - absorbed + 2:
        raise ScanError(source, f"cutting the eyeballs gave {n_loops_out} boundary loops, expected "
                                f"{loops_in} - {absorbed} holes in the openings + 2")
    eyes, metrics = judge_pair(V, F, V2, loops, fits, placements, st, median_edge=median_edge,
                               mesh_arrays=mesh_arrays, hints=hints, texture=texture,
                               eyeball=eyeball, moved=moved, source=source)
    metrics.update({"vertices_in": nV, "faces_in": nF, "vertices_out": int(len(V2)),
                    "faces_out": int(len(F2n)), "vertices_removed": int(nV - len(V2)),
                    "faces_removed": int(remove.sum()), "boundary_loops_in": loops_in,
                    "boundary_loops_out": n_loops_out, "holes_in_openings": absorbed,
                    # removing faces repeats no directed edge: an edge-manifold scan stays one
                    "edge_manifold_out": True if not repeated else meshtopo.is_edge_manifold(F2n)})
    return RemovalResult(mesh=out, eyes=eyes, fits=fits, result=StageResult(metrics))
