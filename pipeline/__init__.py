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
    from pipeline.kernels import pin_process as _pin

    _pin()
