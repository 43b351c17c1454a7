"""The render worker's segmentation and depth passes (runs inside Blender worker processes only).

What the classes and the depth are, and why the cornea computes what lies behind it, is
documented once in :mod:`pipeline.render.seg`. Here:

* :func:`setup_passes` enables Cycles' Z pass and the two colour AOVs of
  :data:`pipeline.render.seg.AOV_CHANNELS` on the view layer, sets the pass alpha threshold to
  0 (the first surface the camera ray meets ends the data passes, a transparent coat too) and
  adds an AOV output to every material: a constant class for skin (caruncle by the distance
  attribute), the asset's caruncle subset, iris, pupil, sclera and lashes; for the cornea and sclera coat the
  "what lies behind" nodes (:func:`_behind_nodes`) whose plane uniforms are returned.
* :func:`set_eye_planes` sets those uniforms per image from the evaluated pupil and iris rings.
* :func:`coverage_and_depth` takes the per-class coverages and the Z pass from the render's
  passes (read once per image by :func:`pipeline.blender.film.render_passes`).

None of it changes the image: AOV outputs and data passes do not feed the combined pass.
"""

from __future__ import annotations

import numpy as np

from pipeline.io.seg_file import CARUNCLE, IRIS, LASHES, PUPIL, SCLERA, SKIN
from pipeline.render.seg import AOV_CHANNELS, CARUNCLE_RADIUS_MM

CANTHUS_ATTRIBUTE = "eyerig_canthus_mm"


def _aov(nt, cls_of_node):
    """AOV outputs of both seg AOVs: ``cls_of_node`` = {class id: output socket or constant}."""
    for name, chans in AOV_CHANNELS.items():
        out = nt.nodes.new("ShaderNodeOutputAOV")
        out.aov_name = name
        comb = nt.nodes.new("ShaderNodeCombineColor")
        for k, c in enumerate(chans):
            v = cls_of_node.get(c, 0.0)
            if isinstance(v, (int, float)):
                comb.inputs[k].default_value = float(v)
            else:
                nt.links.new(v, comb.inputs[k])
        nt.links.new(comb.outputs[0], out.inputs["Color"])


def _math(nt, op, a, b=None):
    n = nt.nodes.new("ShaderNodeMath")
    n.operation = op
    for k, v in enumerate((a, b)):
        if v is None:
            continue
        if isinstance(v, (int, float)):
            n.inputs[k].default_value = float(v)
        else:
            nt.links.new(v, n.inputs[k])
    return n.outputs[0]


def _vmath(nt, op, a, b=None, scale=None):
    n = nt.nodes.new("ShaderNodeVectorMath")
    n.operation = op
    for k, v in enumerate((a, b)):
        if v is not None:
            nt.links.new(v, n.inputs[k])
    if scale is not None:
        n.inputs["Scale"].default_value = float(scale)
    out = "Value" if op in ("DOT_PRODUCT", "LENGTH", "DISTANCE") else "Vector"
    return n.outputs[out]


def _inside_disc(nt, P, d, plane: dict):
    """1 where the ray ``P + t d`` (t > 0) crosses the plane inside the disc, else 0 (node output)."""
    c = nt.nodes.new("ShaderNodeCombineXYZ")
    n = nt.nodes.new("ShaderNodeCombineXYZ")
    r = nt.nodes.new("ShaderNodeValue")
    plane.update(c=c, n=n, r=r)
    num = _vmath(nt, "DOT_PRODUCT", _vmath(nt, "SUBTRACT", c.outputs[0], P), n.outputs[0])
    t = _math(nt, "DIVIDE", num, _vmath(nt, "DOT_PRODUCT", d, n.outputs[0]))   # 0 when parallel
    hit = _vmath(nt, "ADD", P, _scale(nt, d, t))
    dist = _vmath(nt, "DISTANCE", hit, c.outputs[0])
    return _math(nt, "MULTIPLY", _math(nt, "GREATER_THAN", t, 0.0), _math(nt, "LESS_THAN", dist, r.outputs[0]))


def _scale(nt, v, s):
    n = nt.nodes.new("ShaderNodeVectorMath")
    n.operation = "SCALE"
    nt.links.new(v, n.inputs[0])
    nt.links.new(s, n.inputs["Scale"])
    return n.outputs["Vector"]


def _behind_nodes(mat, eta: float) -> dict:
    """AOV nodes of a clear eye surface (cornea, coat): the camera ray refracted by ``eta``
    (1 = straight through) with the surface's shading normal, then pupil disc -> pupil, iris
    disc -> iris, else sclera. Returns the plane uniforms ``{"pupil": {c, n, r}, "iris": ...}``."""
    nt = mat.node_tree
    geo = nt.nodes.new("ShaderNodeNewGeometry")
    inc = _vmath(nt, "SCALE", geo.outputs["Incoming"], scale=-1.0)          # toward the surface
    d = _vmath(nt, "REFRACT", inc, geo.outputs["Normal"], scale=eta)
    planes = {"pupil": {}, "iris": {}}
    in_p = _inside_disc(nt, geo.outputs["Position"], d, planes["pupil"])
    in_i = _inside_disc(nt, geo.outputs["Position"], d, planes["iris"])
    iris = _math(nt, "MULTIPLY", in_i, _math(nt, "SUBTRACT", 1.0, in_p))
    sclera = _math(nt, "SUBTRACT", 1.0, _math(nt, "MAXIMUM", in_p, in_i))
    _aov(nt, {PUPIL: in_p, IRIS: iris, SCLERA: sclera})
    return planes


def _skin_nodes(mat) -> None:
    nt = mat.node_tree
    attr = nt.nodes.new("ShaderNodeAttribute")
    attr.attribute_type = "GEOMETRY"
    attr.attribute_name = CANTHUS_ATTRIBUTE
    car = _math(nt, "LESS_THAN", attr.outputs["Fac"], CARUNCLE_RADIUS_MM)
    _aov(nt, {SKIN: _math(nt, "SUBTRACT", 1.0, car), CARUNCLE: car})


def canthus_distance(skin_rest_mm, medial_vertices) -> np.ndarray:
    """(n,) float32 distance (mm) of each rest skin vertex to the nearest medial canthus."""
    V = np.asarray(skin_rest_mm, float)
    C = V[np.asarray(medial_vertices, np.int64)]
    return np.min(np.linalg.norm(V[:, None] - C[None], axis=2), axis=1).astype(np.float32)


def setup_passes(bpy, scene, skin, skin_rest_mm, medial_vertices, eyes: dict, lash_material,
                 refractive_coat: bool, ior: float) -> dict:
    """Enable the passes and add the AOV nodes (see the module doc).

    Parameters
    ----------
    skin : the EyeRegion mesh object; ``skin_rest_mm`` (n, 3) its rest vertices (mm, any rigid
        frame); ``medial_vertices`` the medial-canthus vertex of each eye
    eyes : {side: {"outer": obj, "inner": obj}}
    lash_material : the eyelashes' material

    Returns
    -------
    dict  side -> list of plane-uniform dicts (one per clear surface material of that eye)
    """
    vl = scene.view_layers[0]
    vl.use_pass_z = True
    vl.pass_alpha_threshold = 0.0
    for name in AOV_CHANNELS:
        if name not in vl.aovs:
            a = vl.aovs.add()
            a.name = name
            a.type = "COLOR"
    dist = canthus_distance(skin_rest_mm, medial_vertices)
    attr = skin.data.attributes.get(CANTHUS_ATTRIBUTE) or skin.data.attributes.new(CANTHUS_ATTRIBUTE, "FLOAT",
                                                                                  "POINT")
    attr.data.foreach_set("value", dist)
    from pipeline.blender.materials import is_caruncle

    for slot in skin.material_slots:
        if is_caruncle(slot.material):
            _aov(slot.material.node_tree, {CARUNCLE: 1.0})     # the corner strip's caruncle subset
        elif slot.material is not None:
            _skin_nodes(slot.material)
    _aov(lash_material.node_tree, {LASHES: 1.0})
    uniforms = {}
    for side, e in eyes.items():
        uniforms[side] = []
        for o in (e["outer"], e["inner"]):
            for slot in o.material_slots:
                m = slot.material
                name = m.name.split(".")[0] if m is not None else ""
                if name == "Cornea":
                    uniforms[side].append(_behind_nodes(m, 1.0 / ior))
                elif name == "ScleraCoat":
                    uniforms[side].append(_behind_nodes(m, 1.0 / ior if refractive_coat else 1.0))
                elif name in ("Iris", "Pupil", "Sclera"):
                    _aov(m.node_tree, {{"Iris": IRIS, "Pupil": PUPIL, "Sclera": SCLERA}[name]: 1.0})
    return uniforms


def ring_plane(P) -> tuple[np.ndarray, np.ndarray, float]:
    """(centre, unit normal, mean radius) of a ring of points (n, 3)."""
    P = np.asarray(P, float)
    c = P.mean(0)
    n = np.linalg.svd(P - c)[2][2]
    return c, n, float(np.mean(np.linalg.norm(P - c, axis=1)))


def set_eye_planes(uniforms: list, pupil_world, iris_world) -> None:
    """Set the plane uniforms of one eye from its evaluated pupil and iris rings (world coordinates)."""
    for key, ring in (("pupil", pupil_world), ("iris", iris_world)):
        c, n, r = ring_plane(ring)
        for u in uniforms:
            p = u[key]
            for k in range(3):
                if p["c"].inputs[k].default_value != c[k]:
                    p["c"].inputs[k].default_value = float(c[k])
                if p["n"].inputs[k].default_value != n[k]:
                    p["n"].inputs[k].default_value = float(n[k])
            if p["r"].outputs[0].default_value != r:
                p["r"].outputs[0].default_value = r


def coverage_and_depth(passes: dict) -> tuple[dict, np.ndarray]:
    """Per-class coverages and the Z pass from the render's passes (:func:`pipeline.blender.film.render_passes`).

    Returns
    -------
    coverage : dict  class id -> (H, W) float32 (top row first)
    z : (H, W) float32  Cycles' Z pass (metres from the camera along its axis)
    """
    def get(*names):
        for nm in names:
            if nm in passes:
                return passes[nm]
        raise RuntimeError(f"render passes lack {names[0]} (has {sorted(passes)})")

    cov = {}
    for name, chans in AOV_CHANNELS.items():
        rgb = get(name)
        for k, c in enumerate(chans):
            cov[c] = rgb[..., k]
    return cov, get("Depth.Z", "Depth")


class SegPasses:
    """The render worker's mask and depth outputs, set up on the first image that asks for them
    (a worker that never writes masks renders exactly as before)."""

    def __init__(self, worker, refractive_coat: bool, ior: float, pullback_m: float):
        self.w = worker
        self.refractive_coat, self.ior, self.pullback_m = refractive_coat, float(ior), float(pullback_m)
        self.uniforms = None

    def _setup(self) -> None:
        w = self.w
        P = np.empty(len(w.skin.data.vertices) * 3)
        w.skin.data.vertices.foreach_get("co", P)          # rest (reference key) positions
        M = w.Hinv @ w.Rw_inv @ np.array(w.skin.matrix_world)
        rest = P.reshape(-1, 3) @ M[:3, :3].T + M[:3, 3]
        medial = [int(e["loop"][0]) for e in w.eyes.values()]
        lash_mat = w.lashes[next(iter(w.lashes))][0].data.materials[0]
        self.uniforms = setup_passes(w.bpy, w.scene, w.skin, rest, medial, w.eyes, lash_mat,
                                     self.refractive_coat, self.ior)

    def before_render(self, depsgraph) -> None:
        """Set up (once) and set both eyes' pupil/iris planes from the evaluated Inner meshes."""
        from pipeline.blender.scene import evaluated_vertices

        if self.uniforms is None:
            self._setup()
        for side, e in self.w.eyes.items():
            P, Mw = evaluated_vertices(e["inner"], depsgraph)
            W = P @ Mw[:3, :3].T + Mw[:3, 3]
            lm = self.w.eb_landmarks
            set_eye_planes(self.uniforms[side], W[lm["pupil"]], W[lm["iris"]])

    def after_render(self, seg_path, depth_path, passes: dict) -> None:
        """Write the seg PNG and depth EXR from the last render's passes."""
        from pipeline.io.seg_file import write_depth, write_seg
        from pipeline.render.seg import classes_from_coverage, depth_mm_from_z

        cov, z = coverage_and_depth(passes)
        if seg_path is not None:
            write_seg(seg_path, classes_from_coverage(cov))
        if depth_path is not None:
            write_depth(depth_path, depth_mm_from_z(z, self.w.h_scale, self.pullback_m))
