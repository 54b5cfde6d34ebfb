"""The exception hierarchy and the exit codes of the command line.

Stage code raises a :class:`SensaovError` subclass carrying *where* the problem is (a key path,
a file, a line) and a *hint* saying how to fix it. Only the CLI turns these into one line on
stderr and an exit code; nothing else prints or exits.
"""

from __future__ import annotations

EXIT_OK = 0
EXIT_JOB_FAILED = 1
EXIT_BAD_INPUT = 2
EXIT_ENVIRONMENT = 3


class SensaovError(Exception):
    """Root of every error sensaov reports to a user."""

    exit_code = EXIT_JOB_FAILED

    def __init__(self, message: str, *, where: str | None = None, hint: str | None = None):
        super().__init__(message)
        self.message = message
        self.where = where
        self.hint = hint

    def __str__(self) -> str:
        text = f"{self.where}: {self.message}" if self.where else self.message
        return f"{text} ({self.hint})" if self.hint else text


class SpecError(SensaovError):
    """The job file is malformed: bad YAML, unknown key, wrong type, missing file."""

    exit_code = EXIT_BAD_INPUT


class SceneError(SensaovError):
    """The scene cannot be loaded or does not contain what the job names."""

    exit_code = EXIT_BAD_INPUT


class BufferFormatError(SensaovError):
    """A sensitivity buffer file is corrupt, truncated, foreign or of an unknown version."""

    exit_code = EXIT_BAD_INPUT


class ObjectiveError(SensaovError):
    """An objective cannot be evaluated (size mismatch, user function failure, NaN)."""

    exit_code = EXIT_JOB_FAILED


class EnvironmentProblem(SensaovError):
    """The machine cannot run the renderer (no usable libLLVM, no CUDA for a cuda variant)."""

    exit_code = EXIT_ENVIRONMENT


class OutputError(SensaovError):
    """The output location cannot take the files (not writable, a name taken by a folder)."""

    exit_code = EXIT_BAD_INPUT
