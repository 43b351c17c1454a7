"""The one exception type for bad input.

Stages catch :class:`ScanError`, print its one-line message on stderr and exit
non-zero without a traceback. Anything else is a bug and keeps its traceback.
"""

from __future__ import annotations

import os


class ScanError(Exception):
    """A problem with an input file that the user can fix.

    Parameters
    ----------
    path : str or os.PathLike
        The file (or folder) at fault.
    problem : str
        What is wrong with it, as one sentence without a trailing full stop.
    """

    def __init__(self, path, problem: str):
        self.path = os.fspath(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}")
