"""Stage ``retopo``: crop the dense head to the eye region and remesh it low-poly.

``retopo``       :class:`RetopoSettings` (the ``retopo:`` block) and :func:`retopologize`
``eyelid_loop``  the eyelid loop resampled to a fixed vertex count along the scan's loop
``eye_rings``    concentric edge flow around the eyelid loops
``mesh_clean``   cleaning the remeshed mesh without opening holes
"""
