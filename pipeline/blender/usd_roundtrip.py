"""Blender worker: import a USD asset with Blender's own importer and dump what it made.

    python -m pipeline.blender.usd_roundtrip ASSET.usda OUT.npz

Writes ``OUT.npz`` with, per imported mesh object ``<name>``:
``<name>.basis`` (n, 3) rest points and ``<name>.key.<shape>`` (n, 3) shape-key
points in object-local coordinates (= the USD stage's units and axes: Blender
puts the metersPerUnit scale and the Y-up -> Z-up rotation into the object's
world matrix), ``<name>.matrix_world`` (4, 4), ``<name>.world`` (n, 3) evaluated
(modifiers, armature pose) world-space points in Blender metres, and ``meta`` = JSON text (object
names, shape-key names, material slots, world scale = metres per stage unit, parent, modifiers,
vertex groups, UV layers, image files used by each material; ``armatures``: bone names and
rest heads).

An optional third argument is a JSON pose ``{"bone": [ax, ay, az, degrees]}``: each pose bone
is rotated by that angle about the axis (bone-local) before ``<name>.world`` is evaluated.
Run as a subprocess (bpy only ever lives in worker processes).
"""

from __future__ import annotations

import json
import sys

import numpy as np

from pipeline.blender.scene import evaluated_vertices, images_of, import_usd


def _material_images(mat) -> list[str]:
    return sorted({im.filepath for im in images_of(mat)})


def _pose(pose: dict | None) -> dict:
    """Rotate pose bones; returns the armature description for ``meta``."""
    import bpy
    from mathutils import Quaternion, Vector

    arms = {}
    for o in bpy.context.scene.objects:
        if o.type != "ARMATURE":
            continue
        arms[o.name] = {"bones": [b.name for b in o.data.bones],
                        "heads": [list(b.head_local) for b in o.data.bones]}
        for name, (ax, ay, az, deg) in (pose or {}).items():
            pb = o.pose.bones.get(name)
            if pb is not None:
                pb.rotation_mode = "QUATERNION"
                pb.rotation_quaternion = Quaternion(Vector((ax, ay, az)).normalized(),
                                                    float(np.radians(deg)))
    bpy.context.view_layer.update()
    return arms


def dump(path: str, unit_conversion: bool = True, pose: dict | None = None) -> dict:
    """Arrays described in the module docstring (after importing ``path``)."""
    import bpy

    objs = import_usd(path, unit_conversion)
    bpy.context.view_layer.update()
    out, meta = {}, {"objects": {}}
    meta["armatures"] = _pose(pose)
    depsgraph = bpy.context.evaluated_depsgraph_get()
    for o in objs:
        me = o.data
        n = len(me.vertices)
        M = np.array(o.matrix_world)
        # the unit conversion is a uniform scale on the object's world matrix
        scale = float(np.cbrt(abs(np.linalg.det(M[:3, :3])))) or 1.0
        def pts(data):
            a = np.empty(n * 3)
            data.foreach_get("co", a)
            return a.reshape(n, 3)
        basis = pts(me.vertices)
        keys = []
        if me.shape_keys is not None:
            for kb in me.shape_keys.key_blocks:
                if kb == me.shape_keys.reference_key:
                    basis = pts(kb.data)
                    continue
                out[f"{o.name}.key.{kb.name}"] = pts(kb.data)
                keys.append(kb.name)
        out[f"{o.name}.basis"] = basis
        out[f"{o.name}.matrix_world"] = M
        W, Mw = evaluated_vertices(o, depsgraph)
        out[f"{o.name}.world"] = W @ Mw[:3, :3].T + Mw[:3, 3]
        prim = o.get("prim_path") or ""
        meta["objects"][o.name] = {"vertices": n, "polygons": len(me.polygons), "shape_keys": keys,
                                   "materials": [m.name if m else None for m in me.materials],
                                   "world_scale": scale, "prim_path": str(prim),
                                   "parent": o.parent.name if o.parent else None,
                                   "modifiers": [[m.type, getattr(getattr(m, "object", None), "name", None)]
                                                 for m in o.modifiers],
                                   "vertex_groups": [g.name for g in o.vertex_groups],
                                   "uv_layers": [u.name for u in me.uv_layers],
                                   "images": {m.name: _material_images(m) for m in me.materials if m}}
    out["meta"] = np.array(json.dumps(meta))
    return out


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) not in (2, 3):
        print("usage: python -m pipeline.blender.usd_roundtrip ASSET.usda OUT.npz [POSE_JSON]",
              file=sys.stderr)
        return 2
    arrays = dump(argv[0], pose=json.loads(argv[2]) if len(argv) == 3 else None)
    np.savez(argv[1], **arrays)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
