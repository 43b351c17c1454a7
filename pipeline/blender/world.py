"""The render worker's world: one HDR environment map, the only light of the scene.

:class:`EnvironmentWorld` builds the world shader once (environment texture -> background, the
importance map kept small: ``sample_map_resolution``) and, per image, loads the map when it
changes and turns the spec's ``lighting`` into what the worker applies. Any edit of the world
shader makes Cycles rebuild the environment's importance map (seconds per image), so rotation
and strength are applied without touching it, exactly:

* rotating the map by +rot about head +Y (= Blender +Z) is rotating everything else (the
  worker's root objects and the camera) by -rot about Blender +Z: :meth:`EnvironmentWorld.set`
  returns that rotation ``Rw`` (4, 4);
* the world is the only light, so its strength is a linear scale of the image: exposure
  ``log2(strength)`` stops, applied before the view transform.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from pipeline.blender.scene import bundled_hdri


def environment_path(name: str) -> Path:
    """A bundled map's name or an absolute path, as a spec's ``lighting.hdri`` gives it."""
    p = Path(name)
    if not p.is_absolute():
        if p.name != name or not name:
            raise ValueError(f"lighting.hdri {name!r}: a bundled map name or an absolute path")
        p = bundled_hdri(name)
    if not p.is_file():
        raise ValueError(f"lighting.hdri {name!r}: no such environment map")
    return p


def world_rotation(rotation_deg: float) -> np.ndarray:
    """(4, 4) Rz(-rot) in Blender's frame: what rotating the environment by +rot about head +Y
    does to everything else (module doc)."""
    a = math.radians(rotation_deg)
    ca, sa = math.cos(a), math.sin(a)
    return np.array([[ca, sa, 0, 0], [-sa, ca, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1.0]])


class EnvironmentWorld:
    """The world shader of ``scene`` and the map it shows (``hdri``: the spec's name, or None)."""

    def __init__(self, bpy, scene, map_resolution: int):
        self.bpy = bpy
        world = bpy.data.worlds.new("RenderWorld")
        scene.world = world
        world.use_nodes = True
        world.cycles.sampling_method = "MANUAL"      # importance map built once per map: keep it small
        world.cycles.sample_map_resolution = int(map_resolution)
        nt = world.node_tree
        for n in list(nt.nodes):
            nt.nodes.remove(n)
        self.env = nt.nodes.new("ShaderNodeTexEnvironment")
        background = nt.nodes.new("ShaderNodeBackground")
        out = nt.nodes.new("ShaderNodeOutputWorld")
        nt.links.new(self.env.outputs["Color"], background.inputs["Color"])
        nt.links.new(background.outputs["Background"], out.inputs["Surface"])
        self.hdri = None

    def set(self, light: dict) -> tuple[np.ndarray, float]:
        """Show ``light["hdri"]`` (loaded only when it changes; the old map's data purged) and
        return ``(Rw, exposure)`` for its ``rotation_deg`` and ``strength`` (module doc).

        Raises
        ------
        ValueError
            A map that is neither a bundled name nor an existing absolute path; a non-finite
            rotation or strength, or strength <= 0.
        """
        bpy = self.bpy
        name = str(light["hdri"])
        path = environment_path(name)
        if name != self.hdri:
            old = self.env.image
            self.env.image = bpy.data.images.load(str(path), check_existing=False)
            if old is not None:
                bpy.data.images.remove(old)
            bpy.data.orphans_purge(do_local_ids=True, do_linked_ids=True, do_recursive=True)
            self.hdri = name
        rot = float(light.get("rotation_deg", 0.0))
        strength = float(light.get("strength", 1.0))
        if not (math.isfinite(rot) and math.isfinite(strength) and strength > 0):
            raise ValueError("lighting.rotation_deg / strength must be finite, strength > 0")
        return world_rotation(rot), math.log2(strength)
