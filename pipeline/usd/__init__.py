"""USD authoring and validation (imports pxr lazily; never bpy).

- :mod:`pipeline.usd.stage` -- shared helpers (stage setup, meshes, subsets, blend shapes,
  skeleton, UsdPreviewSurface materials);
- :mod:`pipeline.usd.validate` -- ``validate_stage(path_or_stage) -> list[str]``;
- :mod:`pipeline.usd.eyeball` -- the parametric eyeball asset.
"""
