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
        #: Set by `unexpected_error`: raised by a reader's last-resort net.
        self.internal = False
        super().__init__(f"{self.path}: {problem}")


def unexpected_error(path: str | Path, what: str, exc: BaseException) -> CaraFileError:
    """The error of a reader's last-resort net: an exception no check anticipated.

    The contract holds (the caller sees a `CaraFileError` naming the file), and
    ``internal`` is set so that tests and the fuzz benchmark can count these: each one
    is a check that should be made precise.
    """
    err = CaraFileError(path, f"{what} ({type(exc).__name__}: {exc})")
    err.internal = True
    return err
