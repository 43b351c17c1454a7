"""Stage ``remove_eyeballs``: place both eyes, check them, cut the scanned eyes out of the head.

Both eyes are placed together on a local sub-mesh (``fit_eye_pair``: holes near the eyes closed
for the fit and given to the opening, a scanner's flat fills marked as no evidence) by
``pipeline.remove_eyeballs.eye_place`` (a MAP fit of an eye model from every cue the scan keeps, with a
calibrated uncertainty); an eye the geometry cannot place is placed from the colour texture
(``eye_texture``, coarse scans), cut along the fissure the photograph shows. The regions are cut
out leaving one simple loop per opening; each loop vertex moves to where the uncut surface lifts
off the placed eye by ``margin_lift_mm`` (projected onto the eye; flip-guarded; loop vertices on
a reconstruction-filled crease keep the cut); loops are ordered from the medial canthus over the
upper lid; the self-checks of ``pipeline.remove_eyeballs.eye_checks`` are recorded. Only what cannot be
an asset is refused (a closed eye, nothing eye-like near a hint, a cut that leaves no simple
loop); an eye placed from little evidence, or failing a self-check, is published with a doubt.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.errors import ScanError
from pipeline.geometry import meshtopo
from pipeline.geometry.flips import move_guarded
from pipeline.geometry.frame import eye_basis
from pipeline.geometry.spherefit import signed_distance
from pipeline.remove_eyeballs import eye_checks
from pipeline.remove_eyeballs.eye_fit import EyeMesh, eye_surface_distance, local_mesh, median_edge_length
from pipeline.remove_eyeballs.eye_texture import MARGIN_OFF
from pipeline.remove_eyeballs.fissure_cut import move_loop_onto, openings_at_fissures
from pipeline.remove_eyeballs.settings import RemoveEyeballsSettings

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
    mesh: dict
    eyes: dict
    fits: dict
    metrics: dict


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
    Fl = F[ok[F].all(axis=1)]
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
    reach = 2.0 * median_edge_length(V2, F2[np.isin(F2, loop).any(axis=1)])
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
    return move_guarded(V2, F2, loop, target, min_cos, min_area_ratio=0.1)


def fill_holes_near(V, F, centres, near_mm, max_perimeter_mm):
    """Close the mesh's holes near ``centres`` with a fan around each hole's centroid.

    Scanners often leave the dark pupil and iris unmeasured: a hole in the eye opening. The eye fit
    and the cut run on the closed surface; :func:`fit_eye_pair` then gives each hole to the
    opening or to the skin.

    Parameters
    ----------
    V : (n, 3) float64
    F : (m, 3) int64
    centres : list of (3,) float64
    near_mm : float
        A hole is closed when one of its vertices lies this close to a centre ...
    max_perimeter_mm : float
        ... and its perimeter is at most this.

    Returns
    -------
    V2 : (n + k, 3) float64
        ``V`` and one centroid vertex per closed hole.
    F2 : (m + f, 3) int64
        ``F`` and the fan faces (appended, so face ``i < m`` is still face ``i`` of ``F``).
    holes : list of (L,) int64
        The closed holes' loops (vertex ids), in the order of their centroid vertices.
    hole_of_face : (m + f,) int64
        -1 for the faces of ``F``, else the hole index.
    """
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    C = np.asarray(centres, dtype=np.float64).reshape(-1, 3)
    H = meshtopo.boundary_halfedges(F)
    loops = []
    if len(H):
        # each connected piece of the boundary near a centre that is one simple loop
        bv, Hc = np.unique(H, return_inverse=True)
        Hc = Hc.reshape(-1, 2)
        g = coo_matrix((np.ones(len(Hc)), (Hc[:, 0], Hc[:, 1])), shape=(len(bv), len(bv)))
        _, comp = connected_components(g, directed=False)
        near = np.linalg.norm(V[bv][:, None, :] - C[None], axis=2).min(axis=1) <= near_mm
        for k in np.unique(comp[near]):
            try:
                loops += meshtopo.boundary_loops(F, only=bv[comp == k], H=H)
            except ValueError:      # a bow-tie boundary: left as it is
                pass
    newV, newF, holes, owner = [], [], [], []
    for loop in loops:
        P = V[loop]
        per = float(np.linalg.norm(np.roll(P, -1, axis=0) - P, axis=1).sum())
        if per > max_perimeter_mm or len(loop) < 3:
            continue
        if np.linalg.norm(P[:, None, :] - C[None], axis=2).min() > near_mm:
            continue
        k = len(holes)
        c = len(V) + k
        # the boundary half-edge a -> b belongs to a face; the fill face runs b -> a
        newF.append(np.column_stack([np.roll(loop, -1), loop, np.full(len(loop), c)]))
        newV.append(P.mean(axis=0))
        holes.append(np.asarray(loop, dtype=np.int64))
        owner.append(np.full(len(loop), k))
    if not holes:
        return V, F, [], np.full(len(F), -1, dtype=np.int64)
    V2 = np.concatenate([V, np.asarray(newV)])
    F2 = np.concatenate([F, *newF]).astype(np.int64)
    return V2, F2, holes, np.concatenate([np.full(len(F), -1), *owner]).astype(np.int64)


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


def _holes_inside(F, remove, H=None):
    """Number of the mesh's boundary loops whose every edge belongs to a removed face (holes in
    the eye openings, which the cut absorbs). ``H``: the mesh's boundary half-edges, when already
    computed."""
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    H = meshtopo.boundary_halfedges(F) if H is None else H
    if len(H) == 0:
        return 0
    # the face of each boundary half-edge a -> b, looked up among the faces at boundary
    # vertices only (a few thousand of a scan's million: sorting all edges took 0.13 s)
    n = int(F.max()) + 1
    on_boundary = np.zeros(n, bool)
    on_boundary[H[:, 0]] = True
    near = np.flatnonzero(on_boundary[F].any(axis=1))
    Fn = F[near]
    E = np.concatenate([Fn[:, [0, 1]], Fn[:, [1, 2]], Fn[:, [2, 0]]])
    fid = np.tile(near, 3)
    key = E[:, 0] * n + E[:, 1]
    order = np.argsort(key)
    hf = fid[order[np.searchsorted(key[order], H[:, 0] * n + H[:, 1])]]
    bv, Hc = np.unique(H, return_inverse=True)
    Hc = Hc.reshape(-1, 2)
    g = coo_matrix((np.ones(len(Hc)), (Hc[:, 0], Hc[:, 1])), shape=(len(bv), len(bv)))
    _, comp = connected_components(g, directed=False)
    ecomp = comp[Hc[:, 0]]
    kept = np.zeros(comp.max() + 1, bool)
    np.logical_or.at(kept, ecomp, ~remove[hf])
    return int((~kept).sum())


def _fill_faces(V, F, ratio):
    """(m,) bool: faces far larger than the scan's own (``ratio`` x the median area): a scanner's
    flat fill across an opening it could not measure, which says nothing about the eye."""
    A = 0.5 * np.linalg.norm(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]]), axis=1)
    return A > ratio * max(float(np.median(A)), 1e-12)


def _fit_from_placement(mesh: EyeMesh, pl, hint, side, st: RemoveEyeballsSettings, source, ignore):
    """The :class:`EyeFit` of one placed eye: the removal region is the eye-labelled surface
    (faces whose three vertices are eye, and the unmeasured fills inside it), made one simple
    loop; a closed eye (little eye surface, or no lid fold around it) is a ScanError."""
    from pipeline.remove_eyeballs.eye_fit import EyeFit, clean_region, lid_crease_deg, patch_faces

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
    from pipeline.remove_eyeballs.eye_place import cornea_sphere, surface_residual
    cornea = cornea_sphere(e)
    crease = lid_crease_deg(mesh, region) if region.any() else 0.0
    if area < st.min_open_area_mm2:
        raise ScanError(source, f"{side} eye looks closed (or too little of the eyeball shows to place "
                                f"it): {area:.1f} mm2 of eye surface near "
                                f"{np.round(hint, 2).tolist()} (less than {st.min_open_area_mm2:g})")
    n_eye = int(np.count_nonzero(pl.lab))
    if n_eye < st.min_eye_vertices:     # a coarse scan (james: 3 mm faces) cannot show a cornea
        raise ScanError(source, f"{side} eye: too little of the eyeball shows to place it from the "
                                f"geometry: {n_eye} scan vertices on the eye surface near "
                                f"{np.round(hint, 2).tolist()} (fewer than {st.min_eye_vertices})")
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


def fit_eye_pair(mesh_arrays, hints: dict, st: RemoveEyeballsSettings, *, source="mesh", texture=None,
                 prior=None):
    """Place both eyes jointly (``pipeline.remove_eyeballs.eye_place``) on the surface around the
    hints; an eye the geometry cannot place falls back to the colour texture when there is one.

    ``prior``: callable ``(V, F, hint, side) -> {"front", "axis"}`` (the eye-region prior,
    ``eye_prior.register``) or None. Returns ``(mesh, fits, placements)``: the local
    :class:`EyeMesh`, per side an :class:`EyeFit` (region on the full mesh) and the
    :class:`eye_place.Placement` (None for a texture-placed eye)."""
    from pipeline.remove_eyeballs import eye_place
    from pipeline.remove_eyeballs.eye_texture import fit_texture

    V = np.asarray(mesh_arrays["V"], dtype=np.float64)
    F = np.asarray(mesh_arrays["F"], dtype=np.int64)
    median_edge = median_edge_length(V, F)
    # everything a fit reads lies within the patch of its hint, plus a few edge rings: fit on
    # that sub-mesh, which keeps the full mesh's face/vertex order, and map regions back
    reach = max(st.patch_radius_mm, st.place_patch_mm) + 5.0 + 6.0 * median_edge + max(2.0, 1.5 * median_edge)
    centres = [np.asarray(hints[s], float) for s in SIDES]
    Vs, Fs, faces, verts = local_mesh(V, F, centres, reach)
    n_local = len(Fs)
    Vs, Fs, holes, hole_of_face = fill_holes_near(Vs, Fs, centres, st.sample_radius_mm,
                                                  st.max_hole_perimeter_mm)
    mesh = EyeMesh(Vs, Fs, median_edge=median_edge)
    ignore = (hole_of_face >= 0) | _fill_faces(Vs, Fs, st.fill_face_ratio)
    sub_arrays = {k: (np.asarray(mesh_arrays[k])[faces] if k == "FUV" else mesh_arrays[k])
                  for k in ("UV", "FUV") if k in mesh_arrays}
    if holes and "FUV" in sub_arrays:   # fan faces take the texture corners of a rim face
        rim = np.array([np.flatnonzero(np.isin(Fs[:n_local], loop).any(axis=1))[0] for loop in holes])
        sub_arrays["FUV"] = np.concatenate([sub_arrays["FUV"],
                                            sub_arrays["FUV"][rim[hole_of_face[n_local:]]]])
    front = None
    if prior is not None:
        front = {}
        for s in SIDES:
            try:
                front[s] = {**prior(Vs, Fs, hints[s], s), "sigma": st.prior_front_sigma_mm}
            except (ValueError, np.linalg.LinAlgError):     # the model did not register here
                front[s] = None
    placements = eye_place.place_eyes(
        Vs, Fs, hints, patch_radius_mm=st.place_patch_mm, radius_range=tuple(st.radius_range_mm),
        radius_prior=(st.radius_prior_mm, st.radius_prior_sigma_mm),
        prior=None if front is None else front.get, ignore=ignore, seed=st.seed,
        temperature=st.uncertainty_temperature, sigma_scale=st.uncertainty_scale,
        min_fold_deg=st.min_crease_deg)
    fits = {}
    for s in SIDES:
        err = None
        if placements[s] is not None:
            try:
                fits[s] = _fit_from_placement(mesh, placements[s], hints[s], s, st, source, ignore)
                continue
            except ScanError as exc:
                err = exc
        else:
            err = ScanError(source, f"{s} eye looks closed (or too little of the eyeball shows to place "
                                    f"it): no eye surface ringed by a lid fold "
                                    f"near the hint {np.round(hints[s], 2).tolist()}")
        has_tex = texture is not None and "UV" in sub_arrays and "FUV" in sub_arrays
        if not (st.texture_fallback and has_tex):
            raise err
        fits[s] = fit_texture(mesh, sub_arrays, texture, hints[s], s, st, source)
        placements[s] = None
    for s in SIDES:
        if front is not None and front.get(s) is not None:
            fits[s].prior_axis = np.asarray(front[s]["axis"], float)
    for fit in fits.values():       # back to full-mesh ids
        region = np.zeros(len(F), bool)
        region[faces[_opening_holes(fit.region, Fs, holes, hole_of_face, n_local)]] = True
        fit.region = region
        if fit.inliers is not None:
            inl = np.asarray(fit.inliers, dtype=np.int64)
            fit.inliers = verts[inl[inl < len(verts)]]
    return mesh, fits, placements


def _fissure_doubts(V, F, mesh_arrays, texture, hint, fit, loop_points, st: RemoveEyeballsSettings):
    """A texture-placed eye's opening against the fissure its texture shows.

    Returns ``(record, doubts)``: the fissure's and the loop's widths along the eye (mm) and a
    list holding one sentence when the loop spans less than ``texture_fissure_min_share`` of
    the fissure (its canthi, eyelid landmarks 0 and 6, then lie far inside the true corners)."""
    from pipeline.geometry.frame import eye_basis
    from pipeline.remove_eyeballs.eye_texture import texture_fissure

    fis = texture_fissure(V, F, mesh_arrays["UV"], mesh_arrays["FUV"], texture, hint, fit.forward,
                          radius_mm=st.patch_radius_mm, min_contrast=st.texture_min_contrast)
    x = (np.asarray(loop_points, float) - fit.center) @ eye_basis(fit.forward)[0]
    record = {"width_mm": fis["width_mm"], "height_mm": fis["height_mm"],
              "loop_width_mm": float(x.max() - x.min()), "min_share": st.texture_fissure_min_share}
    doubts = []
    if record["loop_width_mm"] < st.texture_fissure_min_share * fis["width_mm"]:
        doubts.append(f"opening {record['loop_width_mm']:.1f} mm wide where the texture's fissure is "
                      f"{fis['width_mm']:.1f} mm: the canthi (eyelid landmarks 0 and 6) lie too close "
                      f"together; the scan is too coarse for its eye opening")
    return record, doubts


def _placement_record(pl, fit):
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
                                       "axis_deg": round(pl.limbus_laplace[1], 3)},
            "radius_profile": None if pl.profile is None else {
                "radius": [round(float(r), 3) for r in pl.profile[0]],
                "energy_above": [round(float(e), 2) for e in pl.profile[1]]},
            "rival_placements": [{"center": np.round(c, 4).tolist(), "radius": round(float(r), 4),
                                  "energy_above": round(float(de), 2)} for c, r, de in pl.modes[1:]]}


def _placement_doubts(eye: dict, st: RemoveEyeballsSettings) -> list:
    """Sentences for every failed self-check of the scan's sphere (the asset's eye adds its own:
    little evidence on the limbus or the axis, an iris outside the opening). The eye is still
    published."""
    return ["self-check " + k + ": " + eye_checks.describe(k, eye["checks"][k])
            for k in eye_checks.failed(eye["checks"])]


#: An eye placed from its texture states the anatomy's spread (the fissure's corners against the
#: eye centre, UnityEyes' eight regions: 0.4-1.9 mm; the gaze prior: within 5 deg of forward).
TEXTURE_SIGMA = (1.2, 5.0)


def _asset_eyes(eyes, fits, placements, eyeball, st: RemoveEyeballsSettings) -> dict:
    """The asset's eyes (:func:`human_eye.asset_eyes`) from what the scan shows: the fitted eye
    model's limbus and gaze, or for a texture placement the limbus of its anatomical eye."""
    from pipeline.eyeball.geometry import EyeballParams, placed_params
    from pipeline.remove_eyeballs import human_eye
    from pipeline.remove_eyeballs.eye_place import limbus_center

    geo = eyeball or EyeballParams()
    scan = {}
    for s in SIDES:
        fit, pl = fits[s], placements[s]
        e = {"center": np.asarray(fit.center, float), "radius": float(fit.radius), "loop_points": np.asarray(eyes[s]["loop_points"], float),
             "prior_axis": fit.prior_axis}
        if pl is not None:
            e.update(limbus_center=limbus_center(pl.eye), axis=np.asarray(pl.eye.n, float),
                     limbus_radius=float(pl.eye.R * np.sin(np.radians(pl.eye.tl))),
                     sigma_limbus_mm=pl.sigma_limbus_mm, sigma_axis_deg=pl.sigma_axis_deg,
                     sigma_radius=pl.sigma_radius_mm, source="geometry")
        else:
            here = placed_params(geo, fit.radius)     # the anatomical eye behind the fissure
            e.update(limbus_center=np.asarray(fit.center) + human_eye.limbus_depth(here) * np.asarray(fit.forward),
                     axis=np.asarray(fit.forward, float), limbus_radius=human_eye.limbus_radius(here),
                     sigma_limbus_mm=TEXTURE_SIGMA[0], sigma_axis_deg=TEXTURE_SIGMA[1],
                     sigma_radius=None, source="texture")
        scan[s] = e
    return human_eye.asset_eyes(scan, eye_size=st.eye_size, eyeball=geo,
                                population=tuple(st.population_radius_mm),
                                min_iris_visible=st.min_iris_visible,
                                doubt_limbus_sigma_mm=st.doubt_limbus_sigma_mm,
                                doubt_axis_sigma_deg=st.doubt_axis_sigma_deg)


def remove_eyeballs(mesh_arrays: dict, hints: dict, st: RemoveEyeballsSettings | None = None, *,
                    source="mesh", texture=None, prior=None, eyeball=None) -> RemovalResult:
    """Fit both eyes and cut the scanned eyeball surface out of the head mesh.

    Parameters
    ----------
    mesh_arrays : dict
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
        The eye-region prior (``eye_prior.EyeRegionPrior.register``), or None.
    eyeball : EyeballParams, optional
        The parametric eyeball the asset carries (its ``r1`` and ``iris_radius``; default the
        paper's): the asset's eye is that eyeball anchored at the scan's limbus
        (:mod:`pipeline.remove_eyeballs.human_eye`).

    Returns
    -------
    RemovalResult
        ``mesh`` (arrays with the eyeball faces removed and vertices re-indexed),
        ``eyes`` (eyes.json content), ``fits`` (EyeFit per side), ``metrics``.
    """
    st = st or RemoveEyeballsSettings()
    mesh, fits, placements = fit_eye_pair(mesh_arrays, hints, st, source=source, texture=texture,
                                          prior=prior)
    # an eye placed from its texture is cut along the fissure the photograph shows: the faces
    # near that outline are split first (pipeline/remove_eyeballs/fissure_cut.py)
    mesh_arrays, fits = openings_at_fissures(mesh_arrays, fits)
    V = np.asarray(mesh_arrays["V"], dtype=np.float64)
    F = np.asarray(mesh_arrays["F"], dtype=np.int64)
    if (fits["left"].region & fits["right"].region).any():
        raise ScanError(source, "the two eye regions overlap (hints too close or wrong)")
    H_in = meshtopo.boundary_halfedges(F)
    loops_in = meshtopo.boundary_component_count(F, H_in)
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
    H2 = meshtopo.boundary_halfedges(F2n)
    n_loops_out = meshtopo.boundary_component_count(F2n, H2)
    # region border vertices (old ids) per eye -> loops touching them
    eyes, metrics, moved, checks = {}, {}, {}, {}
    lim = eye_checks.limits_for(mesh.median_edge, st.radius_range_mm)
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
            loop, lat = order_loop(loop, V2, fit.center, fit.forward, s)
        except ValueError:      # eye_basis: a gaze straight up or down has no pitch axis
            raise ScanError(source, f"{s} eye: the fitted gaze {np.round(fit.forward, 3).tolist()} "
                                    f"is vertical; not an eye") from None
        # an eye placed from its texture cuts away the scan's coarse stand-in for the eye (the
        # photographed eye): only the head that stays must lie outside the eyeball
        checks[s] = eye_checks.check_eye(
            V, F if fit.method == "geometry" else F[~fit.region], fit.center, fit.radius,
            fit.forward, V2[loop], lim, fit.residual_rms_mm,
            eye_points=V[np.unique(F[fit.region])] if fit.method == "geometry" else None,
            cornea=fit.cornea, lateral_index=lat,
            standoff_mm=0.0 if fit.method == "geometry" else MARGIN_OFF[0])
        fissure, doubts = None, []
        if fit.method == "texture" and texture is not None:
            fissure, doubts = _fissure_doubts(V, F, mesh_arrays, texture, hints[s], fit, V2[loop], st)
        eyes[s] = {
            "center": fit.center.tolist(), "radius": fit.radius, "forward": fit.forward.tolist(),
            "residual_rms_mm": fit.residual_rms_mm, "n_inliers": fit.n_inliers,
            "method": fit.method,
            **_placement_record(placements[s], fit),
            "checks": checks[s],
            "cornea": None if fit.cornea is None else {
                "center": np.asarray(fit.cornea["center"]).tolist(),
                "radius": fit.cornea["radius"], "n_inliers": fit.cornea["n_inliers"]},
            "loop_indices": loop.tolist(), "loop_points": V2[loop].tolist(),
            "lateral_canthus_index": lat,
            "texture_fissure": fissure,
            "doubts": doubts,
        }
        metrics[s] = {"radius_mm": round(fit.radius, 4), "residual_rms_mm": round(fit.residual_rms_mm, 4),
                      "n_inliers": fit.n_inliers, "method": fit.method,
                      "faces_removed": int(fit.region.sum()), "loop_length": len(loop),
                      "crease_deg": round(fit.crease_deg, 3),
                      "cornea_fitted": fit.cornea is not None,
                      "loop_moved_mean_mm": round(moved.get(s, 0.0), 4),
                      "doubts": len(doubts)}
        if fissure is not None:
            metrics[s].update({"texture_fissure_width_mm": round(fissure["width_mm"], 2),
                               "loop_width_mm": round(fissure["loop_width_mm"], 2)})
    pair = eye_checks.check_pair({s: fits[s].radius for s in SIDES}, lim)
    asset = _asset_eyes(eyes, fits, placements, eyeball, st)
    for s in SIDES:
        eyes[s]["checks"].update(pair)
        metrics[s]["placement"] = "+".join(eyes[s]["placement"])
        metrics[s]["checks_failed"] = eye_checks.failed(eyes[s]["checks"])
        metrics[s].update({f"check_{k}": c["value"] for k, c in eyes[s]["checks"].items()})
        a = asset[s]
        eyes[s]["scan_sphere"] = {"center": eyes[s]["center"], "radius": eyes[s]["radius"],
                                  "uncertainty_mm": eyes[s].pop("uncertainty_mm")}
        eyes[s].update({
            "center": np.round(a["center"], 6).tolist(), "radius": round(a["radius"], 6),
            "forward": np.round(a["forward"], 9).tolist(), "eye_size": st.eye_size,
            "limbus": {"center": np.round(a["limbus"]["center"], 6).tolist(),
                       "radius": round(a["limbus"]["radius"], 4), "source": a["limbus"]["source"],
                       "depth_mm": round(a["limbus"]["depth_mm"], 6)},
            "uncertainty": {k: round(v, 4) for k, v in a["uncertainty"].items()},
            "uncertainty_mm": {"center": round(a["uncertainty"]["center_mm"], 4),
                               "radius": round(a["uncertainty"]["radius_mm"], 4)},
            "iris_at_rest": a["iris"]})
        eyes[s]["doubts"] = _placement_doubts(eyes[s], st) + a["doubts"] + eyes[s]["doubts"]
        metrics[s]["doubts"] = len(eyes[s]["doubts"])
        metrics[s].update({"radius_mm": round(a["radius"], 4),
                           "scan_sphere_radius_mm": round(fits[s].radius, 4),
                           "sigma_limbus_mm": eyes[s]["uncertainty"]["limbus_mm"],
                           "sigma_axis_deg": eyes[s]["uncertainty"]["axis_deg"],
                           "sigma_center_mm": eyes[s]["uncertainty"]["center_mm"],
                           "limbus_source": a["limbus"]["source"],
                           "iris_visible_share": a["iris"]["visible_share"]})
    if n_loops_out != loops_in - absorbed + 2:
        raise ScanError(source, f"cutting the eyeballs gave {n_loops_out} boundary loops, expected "
                                f"{loops_in} - {absorbed} holes in the openings + 2")
    metrics.update({"vertices_in": nV, "faces_in": nF, "vertices_out": int(len(V2)),
                    "faces_out": int(len(F2n)), "vertices_removed": int(nV - len(V2)),
                    "faces_removed": int(remove.sum()), "boundary_loops_in": loops_in,
                    "boundary_loops_out": n_loops_out, "holes_in_openings": absorbed,
                    "edge_manifold_out": meshtopo.is_edge_manifold(F2n)})
    return RemovalResult(mesh=out, eyes=eyes, fits=fits, metrics=metrics)
