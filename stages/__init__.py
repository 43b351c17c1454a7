"""One thin script per DVC stage: parse paths, load, call the library, save."""

import pipeline  # noqa: F401 -- first: a stage pins its numeric kernels before numpy loads (pipeline/kernels.py)
