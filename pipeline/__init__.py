"""eyerig: dense head scans to rigged eye-region USD assets and labelled eye renders.

Importing this package is cheap: heavy optional modules (bpy, pxr, pymeshlab, igl,
embreex) are imported lazily inside the functions that need them.

A program started as ``python -m pipeline.<module>`` or ``python -m stages.<stage>`` first pins
the numeric kernels of numpy, OpenBLAS and libm (:mod:`pipeline.kernels`: the same bytes on any
x86-64 CPU); while ``-m`` locates its module, ``sys.argv[0]`` is ``"-m"``.
"""

import sys as _sys

__version__ = "0.1.0"

if _sys.argv[:1] == ["-m"]:
    import os as _os

    # numpy asks for transparent huge pages for every array over 4 MiB; the stages make and drop
    # many 25-150 MB temporaries, and faulting each in as huge pages (kernel zeroing and
    # compaction) cost a third of bake's CPU and 0.3-1.3 s of ingest's on the 2-core machines,
    # with the same arrays either way (numpy reads this once, at import)
    _os.environ.setdefault("NUMPY_MADVISE_HUGEPAGE", "0")
    from pipeline.kernels import pin_process as _pin

    _pin()
