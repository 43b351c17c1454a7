"""Both eyes of a scan placed and judged: the placement's face to the stage.

:func:`place_pair` places both eyes together on the surface around the hints (the joint MAP fit
of :mod:`pipeline.placement.fit`, the eye-region prior of :mod:`pipeline.placement.prior`; an eye
the geometry cannot place falls back to the colour texture, :mod:`pipeline.placement.texture`;
an opening a scanner filled flat is placed behind the fill's boundary,
:mod:`pipeline.placement.fill`).
The stage then cuts the openings; :func:`judge_pair` takes each cut loop and says what the
published eye is: the self-checks (:mod:`pipeline.placement.checks`), the asset's eye anchored
at the scan's limbus (:mod:`pipeline.placement.human_eye`), and every doubt
(:mod:`pipeline.placement.doubts`).
"""

from __future__ import annotations

import numpy as np

from pipeline.errors import ScanError
from pipeline.fork import fork_call, fork_result
from pipeline.geometry import meshtopo
from pipeline.geometry.frame import eye_basis
from pipeline.geometry.mesh_checks import closed_polyline_distance
from pipeline.io.eyes_file import Eye
from pipeline.placement import checks as eye_checks, human_eye
from pipeline.placement.doubts import check_doubts, fissure_doubts
from pipeline.placement.eye_fit import EyeFit, EyeMesh, clean_region, lid_crease_deg, patch_faces
from pipeline.placement.fill import FILL_SIGMA, find_flat_fill, fit_behind_loop, fit_from_fill
from pipeline.placement.fissure import points_in_polygon
from pipeline.placement.fit import (LID_BULGE_FOLD_DEG, LID_BULGE_RADIUS_MM, REPLACEMENT_MAX_RADIUS_MM,
                                   REPLACEMENT_MIN_FOLD_DEG, AtRadiusBound, place_eyes)
from pipeline.placement.iris_cap import AXIS_MODEL_SIGMA_DEG
from pipeline.placement.model import cornea_sphere, limbus_center, surface_residual
from pipeline.placement.settings import PlacementSettings
from pipeline.placement.texture import MARGIN_OFF, NoEyeInTexture, fit_texture
from pipeline.placement.uncertainty import residual_factor, residual_scaled

SIDES = ("left", "right")


def fill_faces(V, F, ratio):
    """(m,) bool: faces far larger than the scan's own (``ratio`` x the median area): a scanner's
    flat fill across an opening it could not measure, which says nothing about the eye."""
    A = 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1)
    return A > ratio * max(float(np.median(A)), 1e-12)


class CoarseEye(ScanError):
    """An open eye the scan's shape cannot place: ``region`` (m,) bool, the opening its too few
    eye vertices were found in (one simple loop round it), or None when the eye the geometry
    found lies outside the lids (:func:`_outside_margin`). ``no_eye``: one of :data:`NO_EYE`
    when the surface the search found was judged no eye's (the placed fit carries it)."""

    def __init__(self, path, problem, region, no_eye=None):
        super().__init__(path, problem)
        self.region, self.no_eye = region, no_eye


#: Why the surface the search found round an eye is no eye's, as a closed lid's is: it lies
#: outside the opening the skin round it outlines (``off_margin``), its every folded optimum
#: rests on the radius range's bound (``at_bound``), the cut round it is notched with the
#: iris it would place outside it (``notched``), or it labels too little eye surface
#: (``too_small``). An eye placed behind the prior's opening for one
#: of these on both sides is a pair of closed lids unless the user declares it open
#: (``remove_eyeballs.closed_pair``, docs/remove_eyeballs.md "A pair of closed lids").
NO_EYE = ("off_margin", "at_bound", "notched", "too_small")


class NarrowOpening(ScanError):
    """The cut round the eye the geometry found went round part of an eye: it spans less than
    any eye's fissure (``opening_wide``) and no iris shows in it, or the other eye's opening
    spans ``PAIR_OPENING_RATIO`` times as much, or it is notched (``opening_convex``) with the
    iris outside it. ``side``: which eye, ``width_mm``: the loop's span, ``why``: which; the
    stage places it again behind the opening the eye-region prior outlines (``place_pair``'s
    ``coarse``)."""

    def __init__(self, path, problem, side, width_mm, why="with no iris in it", notched=False):
        super().__init__(path, problem)
        self.side, self.width_mm, self.why, self.notched = side, float(width_mm), why, notched


# A person's two palpebral fissures are about one width (their difference is a millimetre or two
# of 27 mm), so a loop narrower than any fissure beside one this many times as wide is a cut round
# part of its eye even with an iris in it (n1004_photogrammetry_wide's right: 13.3 mm beside
# 22.9 mm, 74 mm2 of its scanned eye left as skin in front of the eye, canthi 5 and 14 mm off)
PAIR_OPENING_RATIO = 1.4


def notched_without_iris(opening_convex: dict, limbus_source: str) -> bool:
    """Whether a cut went round part of an eye by its shape: its loop fails ``opening_convex``
    (``{"value", "ok"}``) and the eye fell back to the opening (``limbus_source`` ``opening``:
    the iris the geometry placed lay outside the lids). An eye placed from its geometry keeps a
    notched loop as a doubt; one already placed behind an opening (``coarse``, ``fill``) has no
    iris to have missed."""
    return not opening_convex["ok"] and limbus_source == "opening"


def narrow_beside_wide(opening_wide: dict, side: str) -> str | None:
    """The other side when ``side``'s loop fails ``opening_wide`` and the other's spans
    ``PAIR_OPENING_RATIO`` times as much, else None. ``opening_wide``: side -> that check's
    ``{"value", "ok"}``."""
    other = SIDES[1 - SIDES.index(side)]
    mine, theirs = opening_wide[side], opening_wide[other]
    if not mine["ok"] and theirs["value"] >= PAIR_OPENING_RATIO * mine["value"]:
        return other
    return None


def _fit_from_coarse(mesh: EyeMesh, err: CoarseEye, side, hint, st: PlacementSettings, front=None,
                     declared=False):
    """The eye behind the opening of an eye the scan's shape cannot place
    (:func:`pipeline.placement.fill.fit_behind_loop`), as behind a scanner's flat fill. The
    opening is the eye surface the search labelled (``err.region``: too few vertices to place
    the eye from its shape) or, where that lay outside the lids (``err.region`` None), the faces
    inside the eye-region prior's lid margin (:func:`prior_opening`). ``err`` again when there
    is no such opening (``declared``: an eye the user declared open, whose refusal says that no
    opening was found to place it behind)."""
    region, by = err.region, "it was found in"
    refusal = err
    if declared or err.no_eye is not None:
        how = "" if declared else OPEN_HOW.format(side=side)
        refusal = ScanError(err.path, f"{err.problem}, and no opening round it to place it behind{how}")
    if region is None:
        region = prior_opening(mesh, front, hint, st.patch_radius_mm + 5.0)
        by = "the eye-region prior outlines"
    if region is None or not region.any():
        raise refusal
    try:
        loops = meshtopo.boundary_loops(mesh.F[region])
    except ValueError:
        raise refusal from None
    if len(loops) != 1:
        raise refusal
    fit = fit_behind_loop(mesh, loops[0], region, side, st.radius_prior_mm, None, "coarse")
    fit.why = f"{err.problem.split(': ', 1)[1]}: placed behind the opening {by}"
    fit.no_eye = None if declared else err.no_eye
    return fit


def prior_opening(mesh: EyeMesh, front, hint, patch_mm: float):
    """(m,) bool: the opening the eye-region prior outlines round ``hint``: the faces of the
    patch (``patch_mm`` round the hint) inside the prior's lid margin (``front``: its
    registration here) seen along its axis, and no more than ``COARSE_DEPTH_MM`` behind the
    margin's mean, the part nearest the hint made one simple opening; None without a
    registration or with no face there.

    Nothing in front of the margin is left out: inside the lids, what stands proud of them is the
    eye (a wide eye's cornea, or a coarse scan's eye bulging through its opening). Bounded in
    front as well (4 mm), the cornea and the raised upper lid beside it went out together as one
    notch from the upper lid to the middle of the opening (``n1004_photogrammetry_wide``'s right
    eye: its loop filled 78 % of its hull, the band folded in the sweep and the rig refused it)."""
    plane = _margin_plane(front)
    if plane is None:
        return None
    o, a, B, poly = plane
    d = mesh.centroids - o
    near = patch_faces(mesh, hint, patch_mm)
    inside = points_in_polygon(d @ B[:2].T, poly) & (d @ a > -COARSE_DEPTH_MM) & near
    if not inside.any():
        return None
    seed = np.zeros(len(inside), bool)
    seed[np.flatnonzero(inside)[np.argmin(np.linalg.norm(mesh.centroids[inside] - hint, axis=1))]] = True
    # islands left out (deeper than the margin allows) are filled: any part of the patch the
    # opening rings round goes with it, as in _fit_from_placement
    return clean_region(mesh, inside, seed, near)


def _margin_plane(front):
    """The eye-region prior's lid margin seen along its axis: ``(origin (3,), axis (3,), basis
    (3, 3), polygon (16, 2))``, or None without a registration (``front``)."""
    if front is None or front.get("margin") is None:
        return None
    M = np.asarray(front["margin"], float)
    a = np.asarray(front["axis"], float)
    a = a / np.linalg.norm(a)
    B = eye_basis(a)
    o = M.mean(axis=0)
    return o, a, B, (M - o) @ B[:2].T


def _outside_margin(point, front) -> float | None:
    """How far ``point`` (3,) lies outside the eye-region prior's lid margin seen along its
    axis (mm; negative inside), or None without a registration (``front``)."""
    plane = _margin_plane(front)
    if plane is None:
        return None
    o, _, B, poly = plane
    q = ((np.asarray(point, float) - o) @ B[:2].T)[None]
    d = float(closed_polyline_distance(q, poly)[0])
    return -d if points_in_polygon(q, poly)[0] else d


#: How far outside the prior's lid margin a scanned eye's limbus may lie (mm): on 62 held-out
#: eyes the truth's lay at most 1.0 mm outside and every placed one within 1.0 mm.
PRIOR_MARGIN_SLACK_MM = 3.0

#: How far below the middle of the prior's lid margin (seen along its axis) the rotation centre
#: of the human eye an optimum implies may lie (mm; its limbus centre less the paper's eye's
#: 10 mm along its axis, :func:`pipeline.placement.human_eye.limbus_depth`). On the cached unseen
#: heads with a truth (553 eyes of 285 heads, their searches' optima recorded) the truth's lay at
#: most 1.4 mm below it, and every optimum within 2.5 mm of the truth's limbus at most 1.8 mm
#: (2424 of them); the 32 lowest optima over 4 mm below were all 4.4 mm or more off: spheres on
#: the cheek under the lower lid, ringed by the fold beneath it, centred 4.4-13.5 mm below (a
#: 60k-face photogrammetry head's right, 20 mm ringed by 15.5 deg, 6.7 mm below and 10 mm off,
#: its true eye's 4.4 mm above).
BELOW_MARGIN_MM = 4.0
CENTRE_DEPTH_MM = 10.0

#: Why the search's lowest optimum was passed over (``Placement.passed_over``,
#: :func:`pipeline.placement.fit.passed_over_why`), as a doubt begins and as a refusal says it.
PASSED_OVER = {
    "off_margin": f"the search's lowest optimum lay over {PRIOR_MARGIN_SLACK_MM:g} mm outside the lid margin "
                  f"that the skin around it outlines",
    "below_margin": f"the search's lowest optimum put the eye's centre over {BELOW_MARGIN_MM:g} mm below the "
                    f"middle of the lid margin that the skin around it outlines, a cheek's sphere",
    "weak_fold": f"the search's lowest optimum was a sphere over {REPLACEMENT_MAX_RADIUS_MM:g} mm ringed by a "
                 f"lid fold under {REPLACEMENT_MIN_FOLD_DEG:g} deg, a cheek's or a lid's, no eye",
}
PASSED_OVER_SHORT = {"off_margin": "outside the lid margin", "below_margin": "below the lid margin",
                     "weak_fold": "a large sphere weakly ringed"}


def _below_margin(eye, front) -> float | None:
    """How far below the middle of the eye-region prior's lid margin (seen along its axis) the
    rotation centre of the human eye ``eye`` implies lies (mm; ``CENTRE_DEPTH_MM`` behind its
    limbus centre; negative above), or None without a registration (``front``)."""
    plane = _margin_plane(front)
    if plane is None:
        return None
    o, _, B, _ = plane
    centre = limbus_center(eye) - CENTRE_DEPTH_MM * np.asarray(eye.n, float)
    return -float((centre - o) @ B[1])


def _admissible(front):
    """``(side, Mode) -> str``: why the mode is no eye this scan shows on that side ("" where it
    may be one), from the lid margin the eye-region prior registered round it (``front``: side ->
    its registration or None; an unregistered side admits every mode): ``off_margin`` where its
    limbus lies over ``PRIOR_MARGIN_SLACK_MM`` outside the margin, ``below_margin`` where the
    human eye it implies is centred over ``BELOW_MARGIN_MM`` below the margin's middle. The
    search's lowest optimum that is no eye is passed over for a higher one (the fallbacks below
    where there is none): `id330_icteye_down`, scanned with ICT's own eyeball looking down, had
    its lowest optima on 19-20 mm spheres 7-9 mm outside both margins (folds of 14 deg) and the
    true eyes' 150 above them (within 1.1-1.7 mm and 3 deg, folds of 20-22 deg), and was refused
    as a pair of closed lids. A closed lid's bulge (:func:`lid_bulge`) is left to be refused as
    closed whatever its centre: a wink's lies 4.4 mm below."""
    def why(side, mode) -> str:
        fr = front.get(side)
        off = _outside_margin(limbus_center(mode.eye), fr)
        if off is not None and off > PRIOR_MARGIN_SLACK_MM:
            return "off_margin"
        below = _below_margin(mode.eye, fr)
        if below is not None and below > BELOW_MARGIN_MM and not lid_bulge(mode):
            return "below_margin"
        return ""
    return why


#: How far behind the prior's lid margin a coarse eye's opening reaches (mm): the skin beyond
#: the canthi falls back 5 mm and more (in front of the margin, inside the lids, is the eye).
COARSE_DEPTH_MM = 4.0


def _fit_from_placement(mesh: EyeMesh, pl, hint, side, st: PlacementSettings, source, ignore):
    """The :class:`EyeFit` of one placed eye: the removal region is the eye-labelled surface
    (faces whose three vertices are eye, and the unmeasured fills inside it), made one simple
    loop. Too little eye surface is a :class:`CoarseEye` (``no_eye`` ``too_small``), and too few
    scan vertices on it one to place behind its own opening."""
    V, F = mesh.V, mesh.F
    eye_v = np.zeros(len(V), bool)
    eye_v[pl.patch.verts[pl.lab]] = True
    region = eye_v[F].all(axis=1)
    # flat fills take no side in the cut: they go with the opening when they touch it
    region |= ignore & eye_v[F].any(axis=1)
    patch = patch_faces(mesh, hint, st.patch_radius_mm + 5.0)
    e = pl.eye
    front = e.c + e.R * e.n
    seed = region & (np.linalg.norm(mesh.centroids - front, axis=1)
                     <= np.min(np.linalg.norm(mesh.centroids[region] - front, axis=1), initial=np.inf)
                     + max(2.0, 2 * mesh.median_edge)) if region.any() else region
    region = clean_region(mesh, region, seed, patch) if region.any() else region
    A = 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1)
    area = float(A[region & ~ignore].sum())
    cornea = cornea_sphere(e)
    crease = lid_crease_deg(mesh, region) if region.any() else 0.0
    if area < st.min_open_area_mm2:
        # a sliver of eye the search found ringed by a fold: no eye's surface to place from, as
        # a closed lid's; placed behind the prior's opening and counted by the pair rule
        raise CoarseEye(source, f"{side} eye: too little eye surface to place it from the geometry: "
                                f"{area:.1f} mm2 near {np.round(hint, 2).tolist()} (less than "
                                f"{st.min_open_area_mm2:g})", None, "too_small")
    n_eye = int(np.count_nonzero(pl.lab))
    if n_eye < st.min_eye_vertices:     # a coarse scan (james: 3 mm faces) cannot show a cornea
        raise CoarseEye(source, f"{side} eye: too little of the eyeball shows to place it from the "
                                f"geometry: {n_eye} scan vertices on the eye surface near "
                                f"{np.round(hint, 2).tolist()} (fewer than {st.min_eye_vertices})",
                        region)
    rv = np.unique(F[region & ~ignore])
    d, ant, _, _ = surface_residual(V[rv], e)
    scl = ~ant
    rms = float(np.sqrt(np.mean(d[scl] ** 2))) if scl.any() else float(np.sqrt(np.mean(d ** 2)))
    if cornea is not None:
        cornea = {"center": np.asarray(cornea["center"]), "radius": cornea["radius"],
                  "n_inliers": int((~scl).sum())}
    return EyeFit(side=side, center=np.asarray(e.c, float), radius=float(e.R),
                  forward=np.asarray(e.n, float), residual_rms_mm=rms, n_inliers=int(len(rv)),
                  method="geometry", region=region, cornea=cornea, crease_deg=float(crease),
                  capped=False, inliers=rv, radius_sigma=pl.sigma_radius_mm)


#: What a refusal as closed tells the user who knows better.
OPEN_HOW = " (if the eye is open, say so in scan.yaml: eyes.{side}.open: true)"


def lid_bulge(pl) -> bool:
    """Whether a placement's eye is a closed lid's bulge
    (:data:`pipeline.placement.fit.LID_BULGE_RADIUS_MM`)."""
    return float(pl.eye.R) > LID_BULGE_RADIUS_MM and float(pl.fold_deg) < LID_BULGE_FOLD_DEG


def place_pair(V, F, hints: dict, st: PlacementSettings, *, median_edge: float, filled=None,
               uv=None, texture=None, prior=None, source="mesh", coarse=None, placed=None,
               declared_open=()):
    """Place both eyes jointly (:func:`pipeline.placement.fit.place_eyes`) on the surface around
    the hints; an eye the geometry cannot place falls back to the colour texture when there is one.
    An opening a scanner filled flat (:func:`pipeline.placement.fill.find_flat_fill`) is placed
    behind the fill's boundary instead (:func:`pipeline.placement.fill.fit_from_fill`; the
    search is skipped when both are).

    ``V``, ``F``: the surface around the hints (the stage's local sub-mesh, its holes near the
    eyes closed); ``median_edge``: the whole scan's median edge length; ``filled`` (m,) bool: the
    faces that close a hole (no evidence, like a scanner's flat fills); ``uv``: ``UV``/``FUV``
    of those faces, when the scan has a texture; ``prior``: callable ``(V, F, hint, side) ->
    {"front", "axis"}`` (the eye-region prior, ``prior.EyeRegionPrior.register``) or None.
    ``coarse``: side -> why, eyes to place behind the opening the eye-region prior outlines
    whatever the geometry found (a cut round part of an eye, :class:`NarrowOpening`);
    ``placed``: what the search of an earlier call on the same surface found (its ``searched``;
    the search is not run again). ``declared_open``: the sides the user declared open (scan.yaml
    ``eyes.<side>.open``): an eye that looks closed there (no eye surface ringed by a lid fold,
    too little of it, a closed lid's bulge) is placed behind the opening the eye-region prior
    outlines, doubted, instead of refused.
    Returns ``(mesh, fits, placements, searched)``: the :class:`EyeMesh`, per side an
    :class:`EyeFit` (its region on ``F``), the :class:`pipeline.placement.uncertainty.Placement`
    (None for an eye placed from its texture, a fill or its opening) and what the search found
    (for ``placed``: an eye the search found but placed from its opening follows the same path
    again)."""
    mesh = EyeMesh(V, F, median_edge=median_edge)
    ignore = fill_faces(V, F, st.fill_face_ratio)
    if filled is not None:
        ignore = filled | ignore
    uv = uv or {}

    def registered(s):
        try:
            return {**prior(V, F, hints[s], s), "sigma": st.prior_front_sigma_mm}
        except (ValueError, np.linalg.LinAlgError):     # the model did not register here
            return None

    # the left eye's prior registers in a child beside the right one's and the fills (pipeline.fork);
    # scipy.optimize (0.3 s) is imported before, once, not in both
    import scipy.optimize  # noqa: F401

    job = None if prior is None else fork_call(registered, "left")
    right = None if prior is None else registered("right")
    # an opening a scanner filled flat: its boundary is the fissure (pipeline/placement/fill.py)
    fills = {s: find_flat_fill(V, F, hints[s], median_edge, exclude=filled) for s in SIDES}
    front = None if prior is None else {"left": fork_result(job)[0], "right": right}
    coarse = coarse or {}
    if placed is not None:
        placements = dict(placed)
    else:
        placements = {s: None for s in SIDES} if all(fills.values()) else place_eyes(
            V, F, hints, patch_radius_mm=st.place_patch_mm, radius_range=tuple(st.radius_range_mm),
            radius_prior=(st.radius_prior_mm, st.radius_prior_sigma_mm),
            prior=None if front is None else front.get, ignore=ignore, seed=st.seed,
            temperature=st.uncertainty_temperature, sigma_scale=st.uncertainty_scale,
            min_fold_deg=st.min_crease_deg, admissible=None if front is None else _admissible(front))
    searched = dict(placements)     # what the search found, before the fallbacks below drop it
    fits, photographed = {}, {}     # photographed: side -> the texture's eye, where it overrules
    has_tex = texture is not None and "UV" in uv and "FUV" in uv
    for s in SIDES:
        if fills[s] is not None:
            fits[s], placements[s] = fit_from_fill(mesh, fills[s], s, st.radius_prior_mm), None
            continue
        err, bound = None, None
        if isinstance(placements[s], AtRadiusBound):
            bound, placements[s] = placements[s], None
        off = None if placements[s] is None or front is None else _outside_margin(
            limbus_center(placements[s].eye), front.get(s))
        if s in coarse:
            err = CoarseEye(source, f"{s} eye: {coarse[s]}", None)
        elif off is not None and off > PRIOR_MARGIN_SLACK_MM:
            # the eye the geometry found lies off the opening the lids around it outline (a coarse
            # photogrammetry head's right eye: on the lower lid, 8.6 mm outside, 13.7 mm off
            # with a 1.1 mm sigma): no eye this scan shows
            err = CoarseEye(source, f"{s} eye: the eye surface the geometry found lies {off:.1f} mm "
                                    f"outside the lid margin that the skin around it outlines "
                                    f"(eye-region prior; limit {PRIOR_MARGIN_SLACK_MM:g} mm)", None, "off_margin")
        elif bound is not None:
            # an open eye's surface too small to size (every folded optimum at the range's bound):
            # placed behind the opening the eye-region prior outlines, as a coarse scan's
            err = CoarseEye(source, f"{s} eye: the eye surface ringed by a lid fold ({bound.fold_deg:.0f} deg) "
                                    f"fits only a sphere on the radius range's bound ({bound.radius:.1f} mm): "
                                    f"too little of it shows to size the eye", None, "at_bound")
        elif placements[s] is not None and not (st.texture_fallback and has_tex) and lid_bulge(placements[s]):
            # with a photograph the fissure it shows judges such a sphere (_photo_disagrees)
            pl = placements[s]
            err = ScanError(source, f"{s} eye looks closed: the eye surface the search found near the hint "
                                    f"{np.round(hints[s], 2).tolist()} ringed by a lid fold fits a "
                                    f"{pl.eye.R:.1f} mm sphere ringed by {pl.fold_deg:.1f} deg, a closed "
                                    f"lid's bulge (limits {LID_BULGE_RADIUS_MM:g} mm, {LID_BULGE_FOLD_DEG:g} deg)")
        elif placements[s] is not None:
            try:
                fits[s] = _fit_from_placement(mesh, placements[s], hints[s], s, st, source, ignore)
            except ScanError as exc:
                err = exc
            else:
                photo = _photo_disagrees(mesh, fits[s], uv, texture, hints[s], s, st, source) if (
                    st.texture_fallback and has_tex) else None
                if photo is None:
                    if placements[s].passed_over:
                        fits[s].why = (f"{PASSED_OVER[placements[s].passed_over]}: placed from the next "
                                       f"one inside it, a {placements[s].eye.R:.1f} mm sphere ringed by a "
                                       f"lid fold of {placements[s].fold_deg:.1f} deg")
                    continue
                share, photographed[s] = photo
                err = CoarseEye(source, f"{s} eye: only {100 * share:.0f} % of the eye surface the geometry "
                                        f"found lies inside the fissure the texture shows (limit "
                                        f"{100 * PHOTO_INSIDE_MIN:.0f} %)", None)
        else:
            err = ScanError(source, f"{s} eye looks closed (or too little of the eyeball shows to place "
                                    f"it): no eye surface ringed by a lid fold "
                                    f"near the hint {np.round(hints[s], 2).tolist()}")
        if isinstance(err, CoarseEye) and err.no_eye is None and getattr(placements[s], "passed_over", ""):
            # the search's lowest optimum was no eye (off the margin, below it, a large sphere weakly ringed)
            # and the one placed instead gives no eye either (a cut round it too narrow, too few
            # vertices): no eye's surface, as a closed lid's, for the pair rule
            err.no_eye = "off_margin"
        if s in declared_open and not isinstance(err, CoarseEye):
            # the user says this eye is open: what looked closed is too little of it to place from
            # its shape, so its opening and the anatomy place it, doubted, as a coarse eye's
            err = CoarseEye(source, f"{s} eye: declared open (scan.yaml), but "
                                    f"{err.problem.split(': ', 1)[1] if ': ' in err.problem else err.problem}",
                            None)
        elif s not in declared_open and not isinstance(err, CoarseEye):
            err = ScanError(source, f"{err.problem}{OPEN_HOW.format(side=s)}")
        if not (st.texture_fallback and has_tex):
            if not isinstance(err, CoarseEye):
                raise err
            # no photograph to read the eye from: its opening and the anatomy place it, doubted
            fits[s] = _fit_from_coarse(mesh, err, s, hints[s], st, None if front is None else front.get(s),
                                       declared=s in declared_open)
            placements[s] = None
            continue
        try:
            # the photograph check's own fit, when it overruled the geometry (not fitted twice)
            fits[s] = photographed[s] if s in photographed else fit_texture(mesh, uv, texture, hints[s], s,
                                                                            st, source)
            if s in coarse:
                fits[s].why = f"{coarse[s]}: placed from the texture instead"
            elif s in photographed:
                fits[s].why = f"{err.problem.split(': ', 1)[1]}: placed from the texture instead"
        except NoEyeInTexture:
            # neither the geometry nor the texture shows an eye: skin across the opening, whatever
            # the scan's kind (a coarse scan's geometry may offer a sliver of "eye" the texture
            # then shows to be skin)
            why = ("no eye surface ringed by a lid fold" if placements[s] is None
                   else "too little eye surface to place it from the geometry")
            if s in declared_open:
                fits[s] = _fit_from_coarse(mesh, CoarseEye(
                    source, f"{s} eye: declared open (scan.yaml), but {why} and no eye colours in the texture",
                    None), s, hints[s], st, None if front is None else front.get(s), declared=True)
                placements[s] = None
                continue
            raise ScanError(source, f"{s} eye looks closed: {why}, and no eye colours in the "
                                    f"texture, near the hint {np.round(hints[s], 2).tolist()}"
                                    f"{OPEN_HOW.format(side=s)}") from None
        placements[s] = None
    for s in SIDES:
        if front is not None and front.get(s) is not None:
            fits[s].prior_axis = np.asarray(front[s]["axis"], float)
    return mesh, fits, placements, searched


#: On a textured scan an eye the geometry placed on a sphere far from a human one (more than
#: :data:`PHOTO_CHECK_SIGMAS` prior sigmas off ``radius_prior_mm``) is checked against the
#: photograph: at least :data:`PHOTO_INSIDE_MIN` of its region's faces (seen along the head's
#: forward axis) lie inside the fissure the texture shows, or the texture places the eye. A hooded
#: procedural head's skin bulging under its hanging fold fits a 20.6 mm sphere ringed by a fold,
#: 16 % of it inside the photographed fissure (canthi 7.8 / 3.8 mm off); `synthetic_head`'s eyes
#: (11.8 mm) lie wholly inside theirs. Only suspect spheres are checked: the fissure's fit costs
#: 2.5-3.5 CPU-s an eye (its almond's Powell searches), most of the stage's cost on such a head.
PHOTO_INSIDE_MIN = 0.5
PHOTO_CHECK_SIGMAS = 2.0


def _photo_disagrees(mesh, fit, uv, texture, hint, side, st, source):
    """``(share, texture fit)`` where the geometric ``fit``'s sphere is suspect (above) and under
    :data:`PHOTO_INSIDE_MIN` of its region lies inside the fissure the texture shows near
    ``hint`` (:func:`fit_texture`), else None (a human-sized sphere; or they agree; or the
    texture shows no eye there: the geometry stands)."""
    if abs(fit.radius - st.radius_prior_mm) <= PHOTO_CHECK_SIGMAS * st.radius_prior_sigma_mm:
        return None
    try:
        tex = fit_texture(mesh, uv, texture, hint, side, st, source)
    except ScanError:           # NoEyeInTexture included: no photographed eye to disagree with
        return None
    from pipeline.placement import fissure as fs

    q = (mesh.centroids[fit.region] - tex.fissure["hint"]) @ tex.fissure["basis"].T
    share = float(fs.points_in_polygon(q, tex.fissure["outline_2d"]).mean()) if len(q) else 0.0
    return None if share >= PHOTO_INSIDE_MIN else (share, tex)


def placement_record(pl, fit):
    """What carried the fit and how sure it is: ``placement`` (cue names), ``uncertainty_mm``
    (calibrated 1-sigma: RMS of the 3-D centre error, and of the radius), ``cue_shares``."""
    if pl is None:      # placed from the colour texture with the radius prior
        return {"placement": [fit.method, "radius_prior"], "uncertainty_mm": None, "cue_shares": None}
    return {"placement": list(pl.cues),
            "uncertainty_mm": {"center": round(pl.sigma_center_mm, 4),
                               "radius": round(pl.sigma_radius_mm, 4)},
            "cue_shares": dict(pl.shares), "anterior_height": round(float(pl.eye.ha), 4),
            "anterior_ring": round(float(pl.eye.hb), 4),
            "limbus_half_angle_deg": round(float(pl.eye.tl), 3),
            "lid_fold_deg": round(float(pl.fold_deg), 2),
            "uncertainty_laplace_mm": {"center": round(pl.sigma_laplace_mm[0], 4),
                                       "radius": round(pl.sigma_laplace_mm[1], 4),
                                       "limbus": round(pl.limbus_laplace[0], 4),
                                       "axis_deg": round(pl.limbus_laplace[1], 3),
                                       # what the limbus and axis parts were scaled by: residual_scaled
                                       "residual_scale": round(residual_factor(fit.residual_rms_mm), 4)},
            "radius_profile": None if pl.profile is None else {
                "radius": [round(float(r), 3) for r in pl.profile[0]],
                "energy_above": [round(float(e), 2) for e in pl.profile[1]]},
            "rival_placements": [{"center": np.round(c, 4).tolist(), "radius": round(float(r), 4),
                                  "energy_above": round(float(de), 2)} for c, r, de in pl.modes[1:]]}


#: An eye placed from its texture states the anatomy's spread (the fissure's corners against the
#: eye centre, UnityEyes' eight regions: 0.4-1.9 mm; the gaze prior: within 5 deg of forward).
TEXTURE_SIGMA = (1.2, 5.0)


def scan_limbus(pl, st: PlacementSettings) -> dict:
    """The limbus a geometry placement ``pl`` shows: the eye model's (``limbus_fit: model``) or
    its refit with the iris plane on the labelled eye surface (``iris_plane``,
    :func:`pipeline.placement.iris_cap.refit_limbus`). Returns ``center`` (3,), ``axis`` (3,),
    ``radius``, ``record`` (what the refit found, for eyes.json; None for ``model``) and
    ``spread`` (mm, deg): how far the refit moved the model's limbus centre and turned its axis
    (0 when the model's is kept). Two models of one eye surface that disagree by that much say
    the limbus is no surer: the stated sigma takes it in quadrature (:func:`asset_eyes`)."""
    from pipeline.placement.iris_cap import refit_limbus

    if st.limbus_fit == "model":
        return {"center": limbus_center(pl.eye), "axis": np.asarray(pl.eye.n, float),
                "radius": float(pl.eye.R * np.sin(np.radians(pl.eye.tl))), "record": None,
                "spread": (0.0, 0.0)}
    lc, ax, cap, used = refit_limbus(pl.patch.V[pl.lab], pl.eye, radius_range=tuple(st.radius_range_mm))
    rec = None if cap is None else {
        "used": bool(used), "limbus_center": np.round(cap.limbus_center, 4).tolist(),
        "axis": np.round(cap.n, 6).tolist(), "radius": round(cap.R, 4), "limbus_half_angle_deg": round(cap.tl, 3),
        "iris_height_mm": round(cap.hp, 4), "iris_flat_mm": round(cap.rp, 4), "rms_mm": round(cap.rms_mm, 4)}
    radius = cap.limbus_radius if used else float(pl.eye.R * np.sin(np.radians(pl.eye.tl)))
    spread = (0.0, 0.0)
    if used:
        spread = (float(np.linalg.norm(lc - limbus_center(pl.eye))),
                  float(np.degrees(np.arccos(np.clip(np.dot(ax, pl.eye.n), -1.0, 1.0)))))
    return {"center": np.asarray(lc, float), "axis": np.asarray(ax, float), "radius": float(radius),
            "record": rec, "spread": spread}


def asset_eyes(loop_points: dict, fits, placements, eyeball, st: PlacementSettings, limbi=None,
               standoffs=None, V=None, reread=()) -> dict:
    """The asset's eyes (:func:`human_eye.asset_eyes`) from what the scan shows: the scan's
    limbus and gaze (``limbi``: side -> :func:`scan_limbus`, computed when None), or for a
    texture placement the limbus of its anatomical eye. ``standoffs``: side -> ``(standoff,
    front)``: the ``cornea_shows`` check's value (the eye surface along the fitted axis over its
    sides, mm) and :func:`eye_checks.front_elsewhere`'s (None where not measured), which
    :func:`human_eye.axis_off_front` reads. ``V`` (n, 3): the scan's vertices, from which an eye of
    ``reread`` (sides) the geometry placed with its iris hidden reads it again inside its opening."""
    from pipeline.eyeball.geometry import EyeballParams, placed_params
    from pipeline.placement import human_eye

    geo = eyeball or EyeballParams()
    scan = {}
    for s in SIDES:
        fit, pl = fits[s], placements[s]
        e = {"center": np.asarray(fit.center, float), "radius": float(fit.radius), "loop_points": np.asarray(loop_points[s], float),
             "prior_axis": fit.prior_axis}
        if pl is not None:
            lim = (limbi or {}).get(s) or scan_limbus(pl, st)
            pl = residual_scaled(pl, float(fit.residual_rms_mm))
            e.update(limbus_center=lim["center"], axis=lim["axis"], limbus_radius=lim["radius"],
                     sigma_limbus_mm=float(np.hypot(pl.sigma_limbus_mm, lim["spread"][0])),
                     sigma_axis_deg=float(np.hypot(pl.sigma_axis_deg, lim["spread"][1])),
                     sigma_radius=pl.sigma_radius_mm, source="geometry",
                     axis_model_sigma_deg=AXIS_MODEL_SIGMA_DEG if (lim["record"] or {}).get("used") else 0.0,
                     axis_standoff_mm=(standoffs or {}).get(s, (None, None))[0],
                     front_elsewhere_mm=(standoffs or {}).get(s, (None, None))[1])
            if V is not None and s in reread:
                e["scan_points"] = V        # read only where the eye falls back (human_eye.reread_iris)
        else:       # the anatomical eye behind the fissure (photographed, or a flat fill's boundary)
            here = placed_params(geo, fit.radius)
            sigma = FILL_SIGMA if fit.method in ("fill", "coarse") else TEXTURE_SIGMA
            e.update(limbus_center=np.asarray(fit.center) + human_eye.limbus_depth(here) * np.asarray(fit.forward),
                     axis=np.asarray(fit.forward, float), limbus_radius=human_eye.limbus_radius(here),
                     sigma_limbus_mm=sigma[0], sigma_axis_deg=sigma[1],
                     sigma_radius=None, source=fit.method)
        scan[s] = e
    # radii_agree's own test (judge_pair's check_pair): a pair that fails it widens the sigmas
    dr = abs(float(fits["left"].radius) - float(fits["right"].radius))
    return human_eye.asset_eyes(scan, eye_size=st.eye_size, eyeball=geo,
                                population=tuple(st.population_radius_mm),
                                min_iris_visible=st.min_iris_visible,
                                doubt_limbus_sigma_mm=st.doubt_limbus_sigma_mm,
                                doubt_axis_sigma_deg=st.doubt_axis_sigma_deg,
                                pair_disagree_mm=dr if dr > eye_checks.CheckLimits().max_radius_diff_mm else 0.0)


def loop_on_asset_eye(loop_points, asset_eye: dict, eyeball, lim, lateral_index) -> dict:
    """:func:`pipeline.placement.checks.loop_inside_eye` on the eye the asset carries
    (``asset_eye``: one side of :func:`asset_eyes`; its sclera and its cornea, the eyeball
    ``eyeball`` placed at its radius). After ``loop_on_sphere`` failed on the fitted sphere, this
    says whether the fallbacks (the opening's eye, the human eye anchored at the limbus) left
    an eye the loop can rest on."""
    from pipeline.eyeball.geometry import EyeballParams, placed_params

    geo = placed_params(eyeball or EyeballParams(), float(asset_eye["radius"]))
    c, n = np.asarray(asset_eye["center"], float), np.asarray(asset_eye["forward"], float)
    return eye_checks.loop_inside_eye(loop_points, c, geo.r1, n, c + (geo.apex - geo.r2) * n, geo.r2,
                                      lim, lateral_index)


SEAT_STEP_MM, SEAT_MAX_MM = 0.05, 6.0     # how an eye placed from its opening is set back behind its lids


def seat_behind_loop(asset_eye: dict, loop_points, eyeball, lim, lateral_index) -> float:
    """Set an eye placed from its opening (``asset_eye``: one side of :func:`asset_eyes`, changed
    in place) back along its axis, in steps of ``SEAT_STEP_MM``, by the least that leaves its
    lids no deeper inside it than ``loop_on_eye`` allows (``lim.max_loop_off_mm``). The opening
    places the iris centred ``OPENING_LIMBUS_DEPTH_MM`` behind the margin's mean; a margin that
    curves round a globe looking down (the upper lid lowered over it) lies up to 1.8 mm inside
    that eye (`id303_down`, `id304_in`), an eye no lid could hold. Setting it back further, until
    no lid lies inside, folded `id303_down`'s upper lid in the rig sweep (the snap then pulls the
    margin back onto a globe it no longer touched). The shift joins the limbus and centre
    sigmas and a doubt says it; an eye no shift up to ``SEAT_MAX_MM`` seats stays where it was.
    Returns the shift (mm)."""
    depth = loop_on_asset_eye(loop_points, asset_eye, eyeball, lim, lateral_index)["value"]
    if depth <= lim.max_loop_off_mm:
        return 0.0
    ax = np.asarray(asset_eye["forward"], float)
    c0, l0 = np.asarray(asset_eye["center"], float), np.asarray(asset_eye["limbus"]["center"], float)
    for shift in np.arange(SEAT_STEP_MM, SEAT_MAX_MM + 1e-9, SEAT_STEP_MM):
        asset_eye["center"] = c0 - shift * ax
        if loop_on_asset_eye(loop_points, asset_eye, eyeball, lim, lateral_index)["value"] <= lim.max_loop_off_mm:
            break
    else:       # no globe this close behind these lids holds them: left as placed, for loop_on_eye to say
        asset_eye["center"] = c0
        return 0.0
    shift = float(shift)
    asset_eye["limbus"]["center"] = l0 - shift * ax
    u = asset_eye["uncertainty"]
    u["limbus_mm"] = float(np.hypot(u["limbus_mm"], shift))
    u["center_mm"] = float(np.hypot(u["center_mm"], shift))
    asset_eye["doubts"].append(f"the lids lay {depth:.2f} mm inside the eye placed from the opening: "
                               f"set back {shift:.2f} mm along its axis, to within "
                               f"{lim.max_loop_off_mm:.2f} mm of where they rest on it")
    return shift


def judge_pair(V, F, V2, loops: dict, fits: dict, placements: dict, st: PlacementSettings, *,
               median_edge: float, mesh_arrays=None, hints=None, texture=None, eyeball=None,
               moved=None, source="mesh"):
    """What is published of each placed eye once the stage has cut its opening.

    ``V``, ``F``: the uncut head (faces split along a texture fissure included); ``V2``: the cut
    head's vertices; ``loops``: side -> ``(loop, lateral_index)``, the opening's loop (ids of
    ``V2``, ordered from the medial canthus) and where its lateral canthus lies; ``fits``,
    ``placements``: :func:`place_pair`'s, regions on ``F``; ``mesh_arrays``, ``hints``,
    ``texture``: for a texture-placed eye, the fissure its texture shows; ``moved``: side -> the
    mean move of the loop onto the margin (mm). Returns ``(eyes, metrics)``: per side the
    :class:`pipeline.io.eyes_file.Eye` (the asset's eye anchored at the scan's limbus, the
    scan's sphere, the self-checks and every doubt) and the eye's metrics.

    An eye whose loop fails ``loop_on_sphere`` is published (with that doubt) only when the eye
    the asset carries, after the fallbacks, holds the loop (:func:`loop_on_asset_eye`);
    otherwise the cut follows no eye and the scan is a ScanError naming ``source``, the eye and
    both checks. So is a loop narrower than any eye's fissure (``opening_wide``) that no iris in
    it places (the eye would fall back to that opening); with the iris in it, a doubt.
    """
    moved = moved or {}
    checks, fissures, records, doubts, metrics, limbi = {}, {}, {}, {}, {}, {}
    lim = eye_checks.limits_for(median_edge, st.radius_range_mm)
    for s in SIDES:
        fit = fits[s]
        loop, lat = loops[s]
        # an eye placed from its texture cuts away the scan's coarse stand-in for the eye (the
        # photographed eye): only the head that stays must lie outside the eyeball
        checks[s] = eye_checks.check_eye(
            V, F if fit.method == "geometry" else F[~fit.region], fit.center, fit.radius,
            fit.forward, V2[loop], lim, fit.residual_rms_mm,
            eye_points=V[np.unique(F[fit.region])] if fit.method == "geometry" else None,
            cornea=fit.cornea, lateral_index=lat,
            standoff_mm=0.0 if fit.method == "geometry" else MARGIN_OFF[0])
        fissures[s], doubts[s] = None, []
        if fit.method == "texture" and texture is not None:
            fissures[s], doubts[s] = fissure_doubts(V, F, mesh_arrays, texture, hints[s], fit, V2[loop], st)
        if fit.why:
            doubts[s].append(fit.why)
        records[s] = placement_record(placements[s], fit)
        if placements[s] is not None:
            limbi[s] = scan_limbus(placements[s], st)
            records[s]["iris_plane"] = limbi[s]["record"]
        metrics[s] = {"radius_mm": round(fit.radius, 4), "residual_rms_mm": round(fit.residual_rms_mm, 4),
                      "n_inliers": fit.n_inliers, "method": fit.method,
                      "faces_removed": int(fit.region.sum()), "loop_length": len(loop),
                      "crease_deg": round(fit.crease_deg, 3),
                      "cornea_fitted": fit.cornea is not None,
                      "loop_moved_mean_mm": round(moved.get(s, 0.0), 4),
                      "doubts": len(doubts[s])}
        if fissures[s] is not None:
            metrics[s].update({"texture_fissure_width_mm": round(fissures[s]["width_mm"], 2),
                               "loop_width_mm": round(fissures[s]["loop_width_mm"], 2)})
    pair = eye_checks.check_pair({s: fits[s].radius for s in SIDES}, lim)
    standoffs = {}
    for s in SIDES:     # where the axis dips, is there a front of an eye elsewhere? (human_eye.axis_off_front)
        st_s, front = (checks[s].get("cornea_shows") or {}).get("value"), None
        if st_s is not None and st_s < -human_eye.CORNER_DIP_MM and fits[s].method == "geometry":
            front = eye_checks.front_elsewhere(V[np.unique(F[fits[s].region])], fits[s].center,
                                               fits[s].radius, fits[s].forward, lim)[0]
            records[s]["front_elsewhere_mm"] = None if front is None else round(front, 4)
        standoffs[s] = (st_s, front)
    asset = asset_eyes({s: V2[loops[s][0]] for s in SIDES}, fits, placements, eyeball, st, limbi,
                       standoffs=standoffs, V=V,
                       # only inside an opening: a cut that went round part of an eye (notched, or
                       # narrower than any fissure) is cut again behind the prior's opening below
                       reread={s for s in SIDES if checks[s]["opening_convex"]["ok"]
                               and checks[s]["opening_wide"]["ok"]})
    for s in SIDES:
        if getattr(placements[s], "passed_over", "") and asset[s]["limbus"]["source"] in ("opening", "coarse"):
            # an optimum placed instead of the search's lowest (off the margin, below it, or a large
            # sphere weakly ringed) is believed only when its iris shows in the cut round it: one whose
            # iris the asset would take from that opening is a lid's crease, not an eye (the closed
            # eye of the wink n3501_wink_left_noise: a cut 9 mm low, the eye 10.7 mm off), and the
            # eye is placed behind the prior's opening as before, no eye's surface for the pair rule
            lowest = PASSED_OVER_SHORT[placements[s].passed_over]
            raise NarrowOpening(source, f"{s} eye: the optimum placed instead of the search's lowest ({lowest}) "
                                        f"puts its iris outside the cut round it", s,
                                checks[s]["opening_wide"]["value"],
                                why=f"round the optimum after one {lowest}, its iris outside it")
    for s in SIDES:
        if asset[s]["limbus"]["source"] in ("opening", "coarse"):
            seat_behind_loop(asset[s], V2[loops[s][0]], eyeball, lim, loops[s][1])
    for s in SIDES:
        if not checks[s]["loop_on_sphere"]["ok"]:
            checks[s]["loop_on_eye"] = loop_on_asset_eye(V2[loops[s][0]], asset[s], eyeball, lim, loops[s][1])
            if not checks[s]["loop_on_eye"]["ok"]:
                raise ScanError(source, f"{s} eye: self-check loop_on_sphere: "
                                        f"{eye_checks.describe('loop_on_sphere', checks[s]['loop_on_sphere'])}, "
                                        f"and self-check loop_on_eye: "
                                        f"{eye_checks.describe('loop_on_eye', checks[s]['loop_on_eye'])} "
                                        f"(placed from the {asset[s]['limbus']['source']}): the cut follows "
                                        f"no eye behind these lids")
            # repaired: published, and says by what
            doubts[s].append(f"the eyelid loop missed the fitted sphere, but the eye the asset carries "
                             f"(placed from the {asset[s]['limbus']['source']}) holds it (loop_on_eye: "
                             f"{checks[s]['loop_on_eye']['value']:.2f} mm inside it at most, limit "
                             f"{checks[s]['loop_on_eye']['limit']} mm)")
        if not checks[s]["opening_wide"]["ok"] and asset[s]["limbus"]["source"] in ("opening", "coarse"):
            # a loop narrower than any fissure whose eye no iris in it places: the cut went round
            # part of an eye (its cap turned off the scanned cornea), and an eye placed from this
            # opening sits behind the wrong place (id311_look_right: 5 mm deep, the rest of the
            # scanned eye left as skin, black through the opening). A narrow loop with the iris in
            # it is a narrow scanned opening (id322_all's sparse views): published, with the doubt
            raise NarrowOpening(source, f"{s} eye: self-check opening_wide: "
                                        f"{eye_checks.describe('opening_wide', checks[s]['opening_wide'])}, "
                                        f"and no iris shows in it (the eye would be placed from this opening)", s,
                                        checks[s]["opening_wide"]["value"])
        if fits[s].method == "geometry" and notched_without_iris(checks[s]["opening_convex"],
                                                                asset[s]["limbus"]["source"]):
            # a notched loop whose iris lay outside it (the eye fell back to this opening): the
            # cut went round part of an eye and left the rest on a lid as skin (n1101: 199 mm2).
            # Only the geometry's cut: one already behind the prior's opening would be refused
            fill = checks[s]["opening_convex"]["value"]
            raise NarrowOpening(source, f"{s} eye: self-check opening_convex: "
                                        f"{eye_checks.describe('opening_convex', checks[s]['opening_convex'])}, "
                                        f"and the iris lay outside it (the eye would be placed from this "
                                        f"opening)", s, checks[s]["opening_wide"]["value"],
                                why=f"and fills {100 * fill:.0f} % of its hull with the iris outside it",
                                notched=True)
        o = narrow_beside_wide({k: checks[k]["opening_wide"] for k in SIDES}, s)
        if o is not None:
            # an iris in a loop beside a fissure this much wider: the iris the cut holds is part
            # of an eye whose rest stays on the lids as skin (n1004_photogrammetry_wide)
            span, other = checks[s]["opening_wide"]["value"], checks[o]["opening_wide"]["value"]
            raise NarrowOpening(source, f"{s} eye: self-check opening_wide: "
                                        f"{eye_checks.describe('opening_wide', checks[s]['opening_wide'])}, "
                                        f"and the {o} eye's opening spans {other:.1f} mm", s, span,
                                why=f"beside the {o} eye's {other:.1f} mm")
    eyes = {}
    for s in SIDES:
        fit, (loop, lat), a, rec = fits[s], loops[s], asset[s], records[s]
        checks[s].update(pair)
        uncertainty = {k: round(v, 4) for k, v in a["uncertainty"].items()}
        eyes[s] = Eye(
            side=s, center=np.round(a["center"], 6), radius=round(a["radius"], 6),
            forward=np.round(a["forward"], 9), loop_indices=loop, loop_points=V2[loop],
            lateral_canthus_index=lat,
            limbus={"center": np.round(a["limbus"]["center"], 6).tolist(),
                    "radius": round(a["limbus"]["radius"], 4), "source": a["limbus"]["source"],
                    "depth_mm": round(a["limbus"]["depth_mm"], 6)},
            uncertainty=uncertainty, placement=rec["placement"],
            doubts=check_doubts(checks[s]) + a["doubts"] + doubts[s],
            extra={"residual_rms_mm": fit.residual_rms_mm, "n_inliers": fit.n_inliers,
                   "method": fit.method,
                   **{k: v for k, v in rec.items() if k not in ("placement", "uncertainty_mm")},
                   "checks": checks[s],
                   "cornea": None if fit.cornea is None else {
                       "center": np.asarray(fit.cornea["center"]).tolist(),
                       "radius": fit.cornea["radius"], "n_inliers": fit.cornea["n_inliers"]},
                   "texture_fissure": fissures[s],
                   "scan_sphere": {"center": fit.center.tolist(), "radius": fit.radius,
                                   "uncertainty_mm": rec["uncertainty_mm"]},
                   "eye_size": st.eye_size,
                   "uncertainty_mm": {"center": round(a["uncertainty"]["center_mm"], 4),
                                      "radius": round(a["uncertainty"]["radius_mm"], 4)},
                   "iris_at_rest": a["iris"]})
        metrics[s]["placement"] = "+".join(rec["placement"])
        metrics[s]["checks_failed"] = eye_checks.failed(checks[s])
        metrics[s].update({f"check_{k}": c["value"] for k, c in checks[s].items()})
        metrics[s]["doubts"] = len(eyes[s].doubts)
        metrics[s].update({"radius_mm": round(a["radius"], 4),
                           "scan_sphere_radius_mm": round(fit.radius, 4),
                           "sigma_limbus_mm": uncertainty["limbus_mm"],
                           "sigma_axis_deg": uncertainty["axis_deg"],
                           "sigma_center_mm": uncertainty["center_mm"],
                           "limbus_source": a["limbus"]["source"],
                           "iris_visible_share": a["iris"]["visible_share"]})
    return eyes, metrics
