"""Shared mesh helpers: triangles and the mesh graph (meshtopo, mesh_checks, mesh_edit, flips),
sphere fits (spherefit) and frames (frame).

Also, until they move into their stage packages: the remove_eyeballs modules (remove_eyeballs,
eye_fit, eye_texture, eye_checks), retopo's (retopo, eyelid_loop, eye_rings) and snap's (snap).
"""
