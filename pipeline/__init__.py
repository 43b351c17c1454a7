"""eyerig: dense head scans to rigged eye-region USD assets and labelled eye renders.

Importing this package is cheap: heavy optional modules (bpy, pxr, pymeshlab, igl,
embreex) are imported lazily inside the functions that need them.
"""

__version__ = "0.1.0"
