"""Rendering labelled eye images from an asset (paper section 4).

``settings``  RenderSettings and its presets       ``spec``      RenderSpec, the worker's one input
``sampling``  one image's camera, gaze, lids, light ``camera``    Camera, look-at, projections, eye angles
``labels``    landmarks and gaze of an image        ``formats/``  one label writer per format
``seg``       segmentation classes of the masks     ``visibility`` which landmarks the camera sees
``shard``     a worker process per shard            ``run``       the render stage's images
``dataset``   many identities into one dataset      ``plan`` / ``mix`` / ``card``  its plan, mix, card
"""
