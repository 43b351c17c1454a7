"""Stage ``snap``: snap the eyelid margin onto the placed eyeball.

``snap``  :class:`SnapSettings` (the ``snap:`` block) and :func:`snap_mesh`; the corners off the
          globe it fades toward stay in :mod:`pipeline.geometry.corners` (remove_eyeballs' checks
          use them too)
"""
