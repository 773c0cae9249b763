"""The one error type that file readers and writers raise for bad files."""

from __future__ import annotations

from pathlib import Path


class CaraFileError(Exception):
    """A file could not be read or written.

    The message always names the file and says what is wrong with it, so it can be
    shown to the user as is.

    Parameters
    ----------
    path : str or Path
        The offending file.
    problem : str
        What is wrong, in plain words.
    """

    def __init__(self, path: str | Path, problem: str) -> None:
        self.path = Path(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}")
