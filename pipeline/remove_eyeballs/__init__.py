"""Stage ``remove_eyeballs``: place both eyes of a scan (:mod:`pipeline.placement`) and cut the
scanned eyes out.

``settings``         :class:`RemoveEyeballsSettings` (the ``remove_eyeballs:`` block)
``remove_eyeballs``  :func:`remove_eyeballs`: holes closed, eyes placed, openings cut, the margin
                     lifted off the eye
``fissure_cut``      the opening of a texture-placed eye, cut along the fissure its texture shows
"""
