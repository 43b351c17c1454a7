"""What the scan says about an eye: the surface around a hint, its eye/skin labels and the
residual blocks each cue adds to the energy (each one optional; none is required).

* the visible sclera and the anterior cap: Gaussian residuals to the model surface of the
  vertices labelled *eye* (``SIG_SCLERA`` / ``SIG_ANTERIOR``);
* the skin around the opening: every vertex labelled *skin* must lie outside the globe
  (one-sided residual beyond ``TAU_INSIDE``), and the eye/skin labels come from a minimum
  graph cut whose edges are cheap along concave creases (the lid fold around the opening), so
  the opening's border follows the fold;
* the eye-region prior (:mod:`pipeline.placement.prior`, the UnityEyes shape model registered
  to the skin around the eye, when its data are present): where the front of the globe lies;
* the two eyes together (:func:`midplane_x`, used by :mod:`pipeline.placement.fit`): one
  radius, and a loose mirror prior on the centres about the face's midplane;
* a broad population prior on ``R`` (``radius_prior_mm``), on the limbus angle and on the ring.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pipeline.placement.eye_fit import normal_fold_deg
from pipeline.placement.model import LIMBUS_DEG, Eye, cap_height_partials, surface_residual

SIG_SCLERA = 0.15       # mm: scanner noise on the exposed sclera
SIG_ANTERIOR = 0.15     # mm: as the sclera; a looser cap made a small sphere through the cornea
                        # (every vertex at the tighter scale) likelier than the true globe
TAU_INSIDE = 0.35       # mm: skin may lie this far inside the globe (noise) before it is impossible
SKIN_SPREAD_MM = 10.0   # skin near the eye: anywhere within this of the globe, uniform
HB_SIGMA = 1.0          # weak prior on the ring (0 = a plain cap)
CUT_LAMBDA = 2.0        # graph-cut cost per mm of an eye/skin border on smooth skin
CREASE_DEG = 8.0        # ... falling by e per this many degrees of concave fold
COARSE_VERTICES = 1500  # the eye is searched on a patch of at most about this many vertices (coarse_patch)


@dataclass
class Patch:
    """The surface around one hint, with what the energy needs.

    Attributes
    ----------
    V : (n, 3) float64
    F : (m, 3) int64
    A : (n,) float64
        Vertex areas (mm^2; zero for vertices only on ``ignore`` faces).
    N : (n, 3) float64
        Unit vertex normals.
    E : (k, 2) int64
        Interior edges.
    w : (k,) float64
        Cut cost of each edge (cheap along concave folds).
    hint : (3,) float64
    verts : (n,) int64
        Vertex ids in the mesh the patch was cut from.
    faces : (m,) int64
        Face ids in that mesh.
    """

    V: np.ndarray
    F: np.ndarray
    A: np.ndarray
    N: np.ndarray
    E: np.ndarray
    w: np.ndarray
    hint: np.ndarray
    verts: np.ndarray
    faces: np.ndarray


def build_patch(V, F, hint, radius_mm, ignore=None) -> Patch:
    """Faces with centroid within ``radius_mm`` of ``hint``; ``ignore`` (m,) bool marks faces
    that carry no evidence (a scanner's flat fill across an opening): their vertices get no
    area unless a measured face shares them."""
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    hint = np.asarray(hint, dtype=np.float64)
    faces = np.flatnonzero(np.linalg.norm(V[F].mean(axis=1) - hint, axis=1) < radius_mm)
    verts, Fs = np.unique(F[faces], return_inverse=True)
    ign = np.zeros(len(faces), bool) if ignore is None else np.asarray(ignore, bool)[faces]
    return _patch(V[verts], Fs.reshape(-1, 3).astype(np.int64), ign, hint, verts, faces)


def coarse_patch(p: Patch, max_vertices: int = COARSE_VERTICES) -> Patch:
    """``p`` simplified to about ``max_vertices`` vertices (quadric edge collapse, its border
    kept), or ``p`` itself when it has no more vertices, or no more than twice as many faces (the
    collapse's target). Not for a patch with faces that carry no evidence (a fill's faces would
    merge with measured ones). The eye is searched on this copy: the energy is area-weighted and
    its cut cost is per mm, so it keeps its scale, while a 1.4M-triangle scan's 12k-vertex patch
    (0.4 mm edges) makes every least-squares step pay for edges the model cannot use. The copy's
    ``verts`` and ``faces`` are empty: it is cut from no mesh; label the full patch instead."""
    import fast_simplification

    if len(p.V) <= max_vertices or len(p.F) <= 2 * int(max_vertices):
        return p
    Vd, Fd = fast_simplification.simplify(p.V, p.F.astype(np.int32), target_count=2 * int(max_vertices),
                                          preserve_border=True)
    Fd = np.asarray(Fd, np.int64)
    # the collapse can leave duplicate or degenerate faces: drop them
    Fd = Fd[(Fd[:, 0] != Fd[:, 1]) & (Fd[:, 1] != Fd[:, 2]) & (Fd[:, 2] != Fd[:, 0])]
    _, first = np.unique(np.sort(Fd, axis=1), axis=0, return_index=True)
    Fd = Fd[np.sort(first)]
    used, Fd = np.unique(Fd, return_inverse=True)
    return _patch(np.asarray(Vd, np.float64)[used], Fd.reshape(-1, 3).astype(np.int64), np.zeros(len(Fd) // 3, bool),
                  p.hint, np.zeros(0, np.int64), np.zeros(0, np.int64))


def _patch(P, Fs, ign, hint, verts, faces) -> Patch:
    """The :class:`Patch` of the triangles ``Fs`` over ``P`` (``ign``: faces without evidence)."""
    FN = np.cross(P[Fs[:, 1]] - P[Fs[:, 0]], P[Fs[:, 2]] - P[Fs[:, 0]])
    fa = 0.5 * np.linalg.norm(FN, axis=1)
    A = np.zeros(len(P))
    np.add.at(A, Fs[~ign].ravel(), np.repeat(fa[~ign] / 3.0, 3))
    VN = np.zeros_like(P)
    for k in range(3):
        np.add.at(VN, Fs[:, k], FN)
    VN = VN / np.maximum(np.linalg.norm(VN, axis=1, keepdims=True), 1e-300)
    fu = FN / np.maximum(2.0 * fa, 1e-300)[:, None]
    # interior edges with their two faces; concave when the far vertex of one face lies above
    # the other's plane (the lid rising off the eye)
    Ed = np.concatenate([Fs[:, [0, 1]], Fs[:, [1, 2]], Fs[:, [2, 0]]])
    opp = np.concatenate([Fs[:, 2], Fs[:, 0], Fs[:, 1]])
    fid = np.tile(np.arange(len(Fs)), 3)
    key = np.sort(Ed, axis=1)
    k1 = key[:, 0] * len(P) + key[:, 1]
    order = np.argsort(k1, kind="stable")
    same = np.flatnonzero(k1[order][1:] == k1[order][:-1])
    a, b = order[same], order[same + 1]
    E = key[a]
    h = ((P[opp[b]] - P[E[:, 0]]) * fu[fid[a]]).sum(axis=1)
    fold = np.degrees(np.arccos(np.clip((fu[fid[a]] * fu[fid[b]]).sum(axis=1), -1.0, 1.0)))
    concave = np.where(h > 0, fold, 0.0)
    L = np.linalg.norm(P[E[:, 0]] - P[E[:, 1]], axis=1)
    w = CUT_LAMBDA * L * np.exp(-concave / CREASE_DEG)
    return Patch(P, Fs, A, VN, E, w, hint, verts, faces)


def unary_costs(p: Patch, e: Eye, ray=None):
    """Area-weighted negative log-likelihoods of each vertex as eye and as skin, (n,), (n,).
    ``ray``: :func:`pipeline.placement.model.rays` of the patch from ``e``, when made already."""
    d, ant, dsph, u = surface_residual(p.V, e, ray)
    sig = np.where(ant, SIG_ANTERIOR, SIG_SCLERA)
    eye = 0.5 * (d / sig) ** 2 + np.log(sig * np.sqrt(2.0 * np.pi))
    un = u * p.N                        # summed x, y, z as sum(axis=1) does, without its reduce
    eye = np.where(un[:, 0] + un[:, 1] + un[:, 2] > 0.5, np.minimum(eye, 30.0), 30.0)   # eye faces outward
    skin = np.log(SKIN_SPREAD_MM) + np.where(dsph < -TAU_INSIDE,
                                             0.5 * ((dsph + TAU_INSIDE) / SIG_SCLERA) ** 2, 0.0)
    return p.A * eye, p.A * skin


def _cut_structure(p: Patch):
    """The cut graph's CSR layout on ``p`` (its edges never change, only their capacities):
    ``(indices, indptr, slot)``, ``slot`` the CSR entry of each edge of the edge list (an edge
    listed twice, on a non-manifold patch, sums its capacities as the coordinate form did).
    Made once per patch; building the sparse matrix from coordinates every cut was most of
    a cut's time (a placement makes several hundred)."""
    got = _CUT_STRUCTURES.get(id(p))
    if got is not None and got[0] is p:
        return got[1]
    n = len(p.V)
    rows = np.concatenate([p.E[:, 0], p.E[:, 1], np.full(n, n), np.arange(n)])
    cols = np.concatenate([p.E[:, 1], p.E[:, 0], np.arange(n), np.full(n, n + 1)])
    keys, slot = np.unique(rows * (n + 2) + cols, return_inverse=True)
    indptr = np.searchsorted(keys // (n + 2), np.arange(n + 3)).astype(np.int32)
    out = ((keys % (n + 2)).astype(np.int32), indptr, slot.ravel())
    if len(_CUT_STRUCTURES) > 64:
        _CUT_STRUCTURES.clear()
    _CUT_STRUCTURES[id(p)] = (p, out)
    return out


_CUT_STRUCTURES: dict = {}


def _residual_layout(p: Patch, flow):
    """Where each entry of the cut graph lies in ``flow``'s layout (maximum_flow's: the graph's
    entries and their reverses, rows sorted), and the row of each of ``flow``'s entries:
    ``(pos, rows)``. The layout depends on the graph's entries only, which never change on a
    patch: made at its first cut."""
    got = _RESIDUAL_LAYOUTS.get(id(p))
    if got is not None and got[0] is p and got[1] == len(flow.indices):
        return got[2]
    indices, indptr, _ = _cut_structure(p)
    n2 = len(indptr) - 1
    rows = np.repeat(np.arange(n2), np.diff(flow.indptr))
    keys = rows.astype(np.int64) * n2 + flow.indices
    own = np.repeat(np.arange(n2), np.diff(indptr)).astype(np.int64) * n2 + indices
    out = (np.searchsorted(keys, own), rows)
    if len(_RESIDUAL_LAYOUTS) > 64:
        _RESIDUAL_LAYOUTS.clear()
    _RESIDUAL_LAYOUTS[id(p)] = (p, len(flow.indices), out)
    return out


_RESIDUAL_LAYOUTS: dict = {}


def graph_cut(p: Patch, ce, ck):
    """Minimum cut of the eye/skin labelling: (n,) bool, True = eye: the vertices the source
    reaches in the residual graph of the maximum flow (the same set for every maximum flow)."""
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import breadth_first_order, maximum_flow

    n = len(p.V)
    S, T = n, n + 1
    m = np.minimum(ce, ck)
    caps = np.concatenate([p.w, p.w, ck - m, ce - m])      # s->i: cost of skin; i->t: of eye
    caps = np.minimum(np.round(caps * 1000.0), 2 ** 30).astype(np.int32)
    indices, indptr, slot = _cut_structure(p)
    caps = np.bincount(slot, weights=caps, minlength=len(indices)).astype(np.int32)
    G = csr_matrix((caps, indices, indptr), shape=(n + 2, n + 2))
    flow = maximum_flow(G, S, T).flow
    # the residual capacities laid out as the flow is (``G - flow`` with its zeros dropped, made
    # without the sparse subtraction and conversions: they were a fifth of a cut's time)
    pos, rows = _residual_layout(p, flow)
    res = -flow.data.astype(np.int64)
    res[pos] += caps
    keep = res > 0
    ptr = np.zeros(n + 3, np.int32)
    np.cumsum(np.bincount(rows[keep], minlength=n + 2), out=ptr[1:])
    R = csr_matrix((np.ones(int(keep.sum()), np.int8), flow.indices[keep], ptr), shape=(n + 2, n + 2))
    lab = np.zeros(n + 2, bool)
    lab[breadth_first_order(R, S, directed=True, return_predecessors=False)] = True
    return lab[:n]


def eye_components(p: Patch, lab, e: Eye, max_angle_deg=70.0):
    """The eye-labelled components of this eye: the one nearest the front of the globe, and
    every other wholly within ``max_angle_deg`` of the axis (sclera beyond the limbus, split
    off by the cap's rim)."""
    from scipy.sparse import csr_matrix
    from scipy.sparse.csgraph import connected_components

    if not lab.any():
        return lab
    ok = lab[p.E[:, 0]] & lab[p.E[:, 1]]
    G = csr_matrix((np.ones(int(ok.sum())), (p.E[ok, 0], p.E[ok, 1])), shape=(len(p.V),) * 2)
    ncomp, comp = connected_components(G, directed=False)
    ids = np.flatnonzero(lab)
    w = p.V[ids] - e.c
    cosa = (w @ e.n) / np.linalg.norm(w, axis=1)
    front = e.c + e.R * e.n
    keep = np.zeros(ncomp, bool)
    keep[comp[ids[np.argmin(np.linalg.norm(p.V[ids] - front, axis=1))]]] = True
    # each component's least cosine (1.0 where it has none) and its size, by array instead of a
    # loop over the eye vertices
    mins = np.ones(ncomp)
    np.minimum.at(mins, comp[ids], cosa)
    keep |= (mins > np.cos(np.radians(max_angle_deg))) & (np.bincount(comp[ids], minlength=ncomp) >= 2)
    return lab & keep[comp]


def segment(p: Patch, e: Eye):
    """The eye/skin labelling of ``p`` under ``e`` and its energy (unaries + cut)."""
    ce, ck = unary_costs(p, e)
    lab = eye_components(p, graph_cut(p, ce, ck), e)
    cut = lab[p.E[:, 0]] != lab[p.E[:, 1]]
    return lab, float(ce[lab].sum() + ck[~lab].sum() + p.w[cut].sum())


@dataclass
class Cues:
    """Fixed inputs of one eye's least squares besides its patch and labels."""

    front: np.ndarray | None = None     # eye-region prior: front of the globe (3,)
    axis: np.ndarray | None = None      # ... along this unit axis
    front_sigma: float = 4.0
    radius_prior: tuple = (12.0, 3.0)


def residual_blocks(p: Patch, lab, e: Eye, cues: Cues, anterior=None):
    """Residual blocks (name -> array) of one eye; ``anterior`` (n,) bool fixes which eye
    vertices count as anterior (default: where the eye's dome stands off the sclera)."""
    d, ant, dsph, _ = surface_residual(p.V, e)
    sa = np.sqrt(p.A)
    if anterior is None:
        anterior = ant
    out = {"sclera": sa[lab & ~anterior] * d[lab & ~anterior] / SIG_SCLERA,
           "anterior": sa[lab & anterior] * d[lab & anterior] / SIG_ANTERIOR,
           "skin": sa[~lab] * np.minimum(dsph[~lab] + TAU_INSIDE, 0.0) / SIG_SCLERA}
    out.update(prior_blocks(e, cues))
    return out


def prior_blocks(e: Eye, cues: Cues):
    """The :data:`PRIOR_BLOCKS` of :func:`residual_blocks` (name -> array, in its order): they
    depend on the eye alone, not on the patch."""
    out = {}
    if cues.front is not None:
        out["prior"] = (e.c + e.R * cues.axis - cues.front) / cues.front_sigma
    out["radius_prior"] = np.array([(e.R - cues.radius_prior[0]) / cues.radius_prior[1]])
    out["limbus_prior"] = np.array([(e.tl - LIMBUS_DEG[0]) / LIMBUS_DEG[1]])
    out["ring_prior"] = np.array([e.hb / HB_SIGMA])
    return out


class ResidualRows:
    """:func:`residual_blocks` of one eye, concatenated, for many eyes at once: the patch, the
    labels and the anterior mask stay fixed through one least-squares fit, so what depends only
    on them (``sqrt(A)``, the masks) is made once, and the forward differences' eyes (one per
    parameter) are evaluated as one stack instead of one call each (most of a fit's time was the
    Python around numpy's calls on ~1,500 vertices). Each row is bit for bit
    ``np.concatenate(list(residual_blocks(p, lab, e, cues, anterior).values()))``: the same
    operations element by element, the cap's scalars made one eye at a time by
    :func:`pipeline.placement.model._cap` (``tests/test_placement.py`` holds the equality)."""

    def __init__(self, p: Patch, lab, cues: Cues, anterior):
        lab = np.asarray(lab, bool)
        anterior = np.asarray(anterior, bool)
        sa = np.sqrt(p.A)
        # the rows' points padded to an even count: each row's block of the stack then starts
        # 16-byte aligned like the fresh array surface_residual makes, and OpenBLAS's product
        # with the gaze (3 values per point, every other point aligned) rounds as it does there;
        # an odd count shifted every other row by 8 bytes and changed last bits
        self.n = len(p.V)
        self.V = np.vstack([p.V, np.zeros((len(p.V) % 2, 3))])
        self.cues = cues
        self.eye, self.skin = np.flatnonzero(lab), ~lab
        self.scl, self.ant = ~anterior[lab], anterior[lab]      # among the eye vertices
        self.sa_scl, self.sa_ant, self.sa_skin = sa[lab & ~anterior], sa[lab & anterior], sa[~lab]

    def __call__(self, c, R, n, ha, tl, hb):
        """Rows for ``b`` eyes: ``c`` (b, 3), ``n`` (b, 3) unit gazes, ``R``, ``ha``, ``tl``,
        ``hb``: sequences of ``b`` Python floats. Returns (b, rows)."""
        from pipeline.placement.model import APEX_FRACTION, _cap

        b = len(R)
        Rc = np.array(R, dtype=np.float64)[:, None]
        tlc = np.array(tl, dtype=np.float64)[:, None]
        caps = [_cap(R[j], ha[j], tl[j]) for j in range(b)]
        z0 = np.array([z for z, _ in caps], dtype=np.float64)[:, None]
        r = np.array([q for _, q in caps], dtype=np.float64)[:, None]
        # surface_residual and cap_height, row by row as they compute them; the product with
        # the gaze over the whole patch (one BLAS call per row, as there), the cap only where
        # it is read (the eye vertices; the skin's residual is the plain sphere's)
        w = self.V[None, :, :] - c[:, None, :]
        # np.linalg.norm's sum of squares, in its order (x, then y, then z), without its reduce
        # over a length-3 axis
        wn = np.matmul(w, n[:, :, None])[:, :self.n, 0]
        w = w[:, :self.n]
        wx, wy, wz = w[:, :, 0], w[:, :, 1], w[:, :, 2]
        nw = np.maximum(np.sqrt(wx * wx + wy * wy + wz * wz), 1e-9)
        nwe = nw[:, self.eye]
        ca = np.clip(wn[:, self.eye] / nwe, -1.0, 1.0)
        t = z0 * ca + np.sqrt(np.maximum(r * r - z0 * z0 * (1.0 - ca * ca), 0.0))
        s2 = (np.arccos(ca) / np.radians(tlc)) ** 2
        k = np.array([hb[j] * APEX_FRACTION * R[j] * 4.0 for j in range(b)], dtype=np.float64)[:, None]
        ring = k * s2 * (1.0 - s2)
        h = np.where(ca > np.cos(np.radians(tlc)), t - Rc + ring, 0.0)
        d = nwe - Rc - h
        cu = self.cues
        cols = [self.sa_scl * d[:, self.scl] / SIG_SCLERA,
                self.sa_ant * d[:, self.ant] / SIG_ANTERIOR,
                self.sa_skin * np.minimum(nw[:, self.skin] - Rc + TAU_INSIDE, 0.0) / SIG_SCLERA]
        if cu.front is not None:
            cols.append((c + Rc * cu.axis - cu.front) / cu.front_sigma)
        cols.append((Rc - cu.radius_prior[0]) / cu.radius_prior[1])
        cols.append((tlc - LIMBUS_DEG[0]) / LIMBUS_DEG[1])
        cols.append(np.array(hb, dtype=np.float64)[:, None] / HB_SIGMA)
        return np.concatenate(cols, axis=1)


JAC_COLUMNS = ("cx", "cy", "cz", "R", "nx", "ny", "nz", "ha", "tl", "hb")


def residual_jacobians(p: Patch, lab, e: Eye, cues: Cues, anterior=None):
    """The partials of :func:`residual_blocks` (same names, same rows) along the eye's
    ``JAC_COLUMNS``: centre, radius, gaze (as a free 3-vector: a fit chains it to its own
    parametrisation), anterior height, limbus angle, ring. Analytic: the fit's least squares
    took a finite-difference Jacobian, ten residual evaluations a step, most of its time."""
    w = p.V - e.c
    nw = np.maximum(np.linalg.norm(w, axis=1), 1e-9)
    u = w / nw[:, None]
    n = np.asarray(e.n, float)
    ca = u @ n
    _, dh = cap_height_partials(ca, e.R, e.ha, e.tl, e.hb)
    if anterior is None:
        anterior = ca > np.cos(np.radians(e.tl))
    sa = np.sqrt(p.A)
    # d (distance off the model) = |w| - R - h(ca, R, ha, tl, hb), ca = u . n
    dca_dc = -(n[None, :] - ca[:, None] * u) / nw[:, None]
    Jd = np.empty((len(w), 10))
    Jd[:, 0:3] = -u - dh[:, :1] * dca_dc
    Jd[:, 3] = -1.0 - dh[:, 1]
    Jd[:, 4:7] = -dh[:, :1] * u
    Jd[:, 7:10] = -dh[:, 2:5]
    out = {}
    m = lab & ~anterior
    out["sclera"] = Jd[m] * (sa[m] / SIG_SCLERA)[:, None]
    m = lab & anterior
    out["anterior"] = Jd[m] * (sa[m] / SIG_ANTERIOR)[:, None]
    m = ~lab
    on = (nw[m] - e.R + TAU_INSIDE) < 0.0          # skin inside the globe: min(dsph + tau, 0)
    Js = np.zeros((int(m.sum()), 10))
    Js[:, 0:3] = -u[m]
    Js[:, 3] = -1.0
    out["skin"] = Js * (np.where(on, sa[m], 0.0) / SIG_SCLERA)[:, None]
    if cues.front is not None:
        Jp = np.zeros((3, 10))
        Jp[:, 0:3] = np.eye(3) / cues.front_sigma
        Jp[:, 3] = np.asarray(cues.axis, float) / cues.front_sigma
        out["prior"] = Jp
    out["radius_prior"] = np.zeros((1, 10))
    out["radius_prior"][0, 3] = 1.0 / cues.radius_prior[1]
    out["limbus_prior"] = np.zeros((1, 10))
    out["limbus_prior"][0, 8] = 1.0 / LIMBUS_DEG[1]
    out["ring_prior"] = np.zeros((1, 10))
    out["ring_prior"][0, 9] = 1.0 / HB_SIGMA
    return out


def fold_deg(p: Patch, lab, radius_mm=2.0):
    """How sharply the surface folds where the eye surface meets the skin, degrees: median over
    the border vertices of the angle between the mean normal of eye vertices and of skin
    vertices within ``radius_mm``. An open eye is ringed by a fold (the lids rise off the
    globe); a sphere laid over a closed lid, or over the cheek, continues smoothly into the skin."""
    from scipy.spatial import cKDTree

    if not lab.any() or lab.all():
        return 0.0
    border = np.unique(np.concatenate([p.E[lab[p.E[:, 0]] & ~lab[p.E[:, 1]], 0],
                                       p.E[lab[p.E[:, 1]] & ~lab[p.E[:, 0]], 1]]))
    if len(border) == 0:
        return 0.0
    ie, ik = np.flatnonzero(lab), np.flatnonzero(~lab)
    te, tk = cKDTree(p.V[ie]), cKDTree(p.V[ik])
    P = p.V[border]
    angles = normal_fold_deg(p.N[ie], te.query_ball_point(P, radius_mm), p.N[ik], tk.query_ball_point(P, radius_mm))
    return float(np.median(angles)) if len(angles) else 0.0


def midplane_x(V, hints, reach_mm=40.0, max_points=6000):
    """x of the face's mirror plane (normal +X, the head frame's left-right axis): the
    reflection that best overlays the surface around the eyes on itself (1-D search)."""
    from scipy.spatial import cKDTree

    mid = 0.5 * (np.asarray(hints["left"], float) + np.asarray(hints["right"], float))
    sel = np.flatnonzero((np.abs(V[:, 1] - mid[1]) < reach_mm) & (V[:, 2] > mid[2] - reach_mm)
                         & (np.abs(V[:, 0] - mid[0]) < 2.5 * reach_mm))
    P = V[sel][:: max(1, len(sel) // max_points)]
    if len(P) < 10:
        return float(mid[0])
    tree = cKDTree(P)

    def cost(xm):
        Q = P.copy()
        Q[:, 0] = 2.0 * xm - Q[:, 0]
        # beyond the 3 mm cap the nearest point's distance is not needed (the same costs)
        return float(np.mean(np.minimum(tree.query(Q, distance_upper_bound=3.0)[0], 3.0) ** 2))
    xs = np.linspace(mid[0] - 4.0, mid[0] + 4.0, 33)
    x0 = xs[int(np.argmin([cost(x) for x in xs]))]
    xs = np.linspace(x0 - 0.3, x0 + 0.3, 25)
    return float(xs[int(np.argmin([cost(x) for x in xs]))])


PRIOR_BLOCKS = ("prior", "radius_prior", "limbus_prior", "ring_prior")
CUE_NAMES = {"sclera": "sclera", "anterior": "cornea_or_iris", "skin": "skin",
             "prior": "eye_region_prior", "radius_prior": "radius_prior", "pair": "pair",
             "limbus_prior": "limbus_prior", "ring_prior": "ring_prior"}
