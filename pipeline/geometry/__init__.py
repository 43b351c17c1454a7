"""Shared mesh helpers: triangles and the mesh graph (meshtopo, mesh_checks, mesh_edit, flips),
sphere fits (spherefit), frames (frame), smooth ramps (ramps) and the eye corners off the globe
(corners: remove_eyeballs' checks and snap share them).
"""
