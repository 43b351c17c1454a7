"""Stage ``remove_eyeballs``: place both eyes of a scan, check them and cut the scanned eyes out.

``settings``         :class:`RemoveEyeballsSettings` (the ``remove_eyeballs:`` block)
``remove_eyeballs``  :func:`remove_eyeballs`: place, check, cut
``eye_place``        the joint placement of both eyes (a MAP fit of an eye model)
``eye_prior``        the eye-region prior (the UnityEyes shape model registered to the skin)
``eye_fit``          what an eye fit is (:class:`EyeFit`, :class:`EyeMesh`) and the mesh helpers around it
``eye_checks``       the self-checks every correct placement satisfies
``eye_texture``      the texture fallback for coarse scans; ``texels``: texture colours on the
                     surface; ``fissure``: the fissure a texture shows; ``fissure_cut``: the
                     opening cut along it
"""
