"""User-facing errors.

Every failure a user can cause (bad input, a missing file, an occupied output folder) raises
:class:`MRVMError` with a one-line message naming the problem. The CLI prints it as
``error: <message>`` and exits non-zero; operators show it with ``self.report({'ERROR'}, ...)``.
Anything else escaping is a bug and keeps its traceback.
"""

from __future__ import annotations


class MRVMError(Exception):
    """A problem the user can fix; the message is one line and names the problem."""

    exit_code = 2


class InputError(MRVMError):
    """Bad arguments or unreadable input files."""


class OutputError(MRVMError):
    """The output location cannot be used (not writable, holds another dataset, ...)."""


class CameraConventionError(MRVMError):
    """A camera that the target convention cannot express (skew, negative focal, ...)."""


class Cancelled(MRVMError):
    """The user cancelled long work; what was finished is kept."""

    exit_code = 130


class TrainingStopped(MRVMError):
    """Training cannot go on (a NaN loss); the checkpoints written so far are kept."""
