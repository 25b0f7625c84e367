"""Errors that describe bad input, as opposed to bugs.

An :class:`InputError` carries the offending path (a file, a folder, or ``"file:line"`` for a row
of a table) and a one-line description of what is wrong with it. The command line prints
``tympani: {path}: {problem}`` and exits with status 2 for these; every other exception is a bug
(exit status 1).
"""

from __future__ import annotations

import os

__all__ = ["InputError", "is_input_error", "one_line"]


class InputError(Exception):
    """Bad input: a missing, unreadable or malformed file, or a value outside its domain.

    Parameters
    ----------
    path : str or os.PathLike
        What the problem is about: a file or folder path, or ``"manifest.csv:7"`` for one line
        of a table.
    problem : str
        One line saying what is wrong, e.g. ``"no decodable frames"``.

    Examples
    --------
    >>> str(InputError("clip.mp4", "no decodable frames"))
    'clip.mp4: no decodable frames'
    """

    def __init__(self, path: str | os.PathLike, problem: str) -> None:
        super().__init__(path, problem)  # args survive pickling across worker processes
        self.path = os.fspath(path) if not isinstance(path, str) else path
        self.problem = " ".join(str(problem).split())  # always one line

    def __str__(self) -> str:
        return f"{self.path}: {self.problem}"


def is_input_error(exc: BaseException) -> bool:
    """Whether ``exc`` reports bad input rather than a bug.

    True for :class:`InputError` and its subclasses, and for exceptions that declare
    themselves input errors with a true class attribute ``input_error`` (for modules that
    define their own error type, such as a registration failure, without subclassing).
    """
    return isinstance(exc, InputError) or bool(getattr(exc, "input_error", False))


def one_line(exc: BaseException) -> str:
    """A one-line description of ``exc``: an input error's own text (it names the file), any other
    exception's type and text."""
    text = " ".join(str(exc).split())
    if is_input_error(exc):
        return text or type(exc).__name__
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__
