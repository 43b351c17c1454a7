"""The previews: Cycles contact sheets of the finished assets, a step of their own after USD
authoring (stages ``preview`` and ``eyeball_preview``), so that writing an asset never starts
Blender. Each module runs one Blender worker through the door (pipeline/blender/launch.py) and
names only that worker, so each stage's code deps hold just the worker it runs.

- :mod:`pipeline.preview.asset` -- a scan's rigged asset (pipeline/blender/asset_preview.py);
- :mod:`pipeline.preview.eyeball` -- the eyeball asset (pipeline/blender/eyeball_preview.py).
"""
