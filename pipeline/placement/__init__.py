"""Placement: where both eyes of a scan are, how sure that is, and what is doubted.

``place``        the face: :func:`place_pair` (place both eyes) and :func:`judge_pair` (what is
                 published of each once the stage has cut its opening)
``settings``     :class:`PlacementSettings` (the placement's part of the ``remove_eyeballs:`` block)
``model``        the eye model (sclera sphere, anterior cap, gaze)
``cues``         the surface around a hint, its eye/skin labels and each cue's residuals
``fit``          the joint MAP fit of both eyes (search, least squares, gaze restarts)
``uncertainty``  the calibrated uncertainty of a placement (:class:`Placement`)
``prior``        the eye-region prior (the UnityEyes shape model registered to the skin; its data,
                 derived from UnityEyes with the licence: data/)
``eye_fit``      what an eye fit is (:class:`EyeFit`, :class:`EyeMesh`) and the mesh helpers around it
``human_eye``    the asset's eye: the parametric eyeball anchored at the scan's limbus
``checks``       the self-checks every correct placement satisfies; ``doubts``: what is published
                 with a warning
``texture``      the texture fallback for coarse scans; ``texels``: texture colours on the
                 surface; ``fissure``: the fissure a texture shows
"""
