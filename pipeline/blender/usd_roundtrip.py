"""Blender worker: import a USD asset with Blender's own importer and dump what it made.

    python -m pipeline.blender.usd_roundtrip ASSET.usda OUT.npz

Writes ``OUT.npz`` with, per imported mesh object ``<name>``:
``<name>.basis`` (n, 3) rest points and ``<name>.key.<shape>`` (n, 3) shape-key
points in object-local coordinates (= the USD stage's units and axes: Blender
puts the metersPerUnit scale and the Y-up -> Z-up rotation into the object's
world matrix), ``<name>.matrix_world`` (4, 4), and ``meta`` = JSON text (object
names, shape-key names, material slots, world scale = metres per stage unit).
Run as a subprocess (bpy only ever lives in worker processes).
"""

from __future__ import annotations

import json
import sys

import numpy as np


def import_usd(path: str, unit_conversion: bool = False):
    """Import ``path`` into an empty scene; returns the list of mesh objects."""
    import bpy

    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.wm.usd_import(filepath=str(path), import_blendshapes=True, import_skeletons=True,
                          import_materials=True, import_usd_preview=True,
                          apply_unit_conversion_scale=unit_conversion, scale=1.0)
    return [o for o in bpy.context.scene.objects if o.type == "MESH"]


def dump(path: str, unit_conversion: bool = True) -> dict:
    """Arrays described in the module docstring (after importing ``path``)."""
    import bpy

    objs = import_usd(path, unit_conversion)
    bpy.context.view_layer.update()
    out, meta = {}, {"objects": {}}
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
        prim = o.get("prim_path") or ""
        meta["objects"][o.name] = {"vertices": n, "polygons": len(me.polygons), "shape_keys": keys,
                                   "materials": [m.name if m else None for m in me.materials],
                                   "world_scale": scale, "prim_path": str(prim)}
    out["meta"] = np.array(json.dumps(meta))
    return out


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if len(argv) != 2:
        print("usage: python -m pipeline.blender.usd_roundtrip ASSET.usda OUT.npz", file=sys.stderr)
        return 2
    arrays = dump(argv[0])
    np.savez(argv[1], **arrays)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
