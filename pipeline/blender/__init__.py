"""Everything that imports bpy. Modules here run as Blender worker subprocesses
(``python -m pipeline.blender.<module> ...``); importing this package never imports bpy.
"""
