"""Stage ``ingest``: load an untrusted scan folder, validate it, repair what is safe to repair and
convert it to the head frame in millimetres.

``ingest``  :class:`IngestSettings` (the ``ingest:`` block) and :func:`ingest_scan`
``repair``  the safe repairs (merge, degenerate faces, debris, winding) and their settings
"""
