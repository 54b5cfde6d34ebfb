"""The exception hierarchy and the exit codes of the command line.

Stage code raises a :class:`SensaovError` subclass carrying *where* the problem is (a key path,
a file, a line) and a *hint* saying how to fix it. Only the CLI turns these into one line on
stderr and an exit code; nothing else prints or exits.
"""

from __future__ import annotations

import difflib
from collections.abc import Iterable

EXIT_OK = 0
EXIT_JOB_FAILED = 1
EXIT_BAD_INPUT = 2
EXIT_ENVIRONMENT = 3
EXIT_HANGUP = 129  # 128 + SIGHUP: the terminal closed, an ssh connection dropped
EXIT_INTERRUPTED = 130  # 128 + SIGINT, what shells report for Ctrl-C
EXIT_TERMINATED = 143  # 128 + SIGTERM, what a farm's scheduler sends before SIGKILL

# What each exit code means, in the words every --help epilog and the README use.
EXIT_MEANINGS: dict[int, str] = {
    EXIT_OK: "success",
    EXIT_JOB_FAILED: "the job failed (rendering, objective, NaN gradients, internal error)",
    EXIT_BAD_INPUT: "bad input (malformed job, unknown key, missing file, corrupt buffer)",
    EXIT_ENVIRONMENT: "the machine cannot render (no usable libLLVM, no CUDA for a cuda variant)",
    EXIT_HANGUP: "stopped by SIGHUP (terminal closed); the message names the outputs replaced",
    EXIT_INTERRUPTED: "interrupted by Ctrl-C (SIGINT); the message names the outputs replaced",
    EXIT_TERMINATED: "stopped by SIGTERM (a farm); the message names the outputs replaced",
}


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


class BadInputError(SensaovError):
    """Base of the errors that are the input's fault, not the job's: exit 2."""

    exit_code = EXIT_BAD_INPUT


class SpecError(BadInputError):
    """The job file is malformed: bad YAML, unknown key, wrong type, missing file."""


class SceneError(BadInputError):
    """The scene cannot be loaded or does not contain what the job names."""


class BufferFormatError(BadInputError):
    """A sensitivity buffer file is corrupt, truncated, foreign or of an unknown version."""


class MergeError(BadInputError):
    """Shards that cannot be merged: other scenes, jobs, parameters or versions, gaps, twins."""


class ObjectiveError(SensaovError):
    """An objective cannot be evaluated (size mismatch, user function failure, NaN)."""


class EnvironmentProblem(SensaovError):
    """The machine cannot run the renderer (no usable libLLVM, no CUDA for a cuda variant)."""

    exit_code = EXIT_ENVIRONMENT


class InputFileError(BadInputError):
    """A file a command reads is missing, not a regular file (a FIFO, a device) or too large."""


class MemoryBudgetError(BadInputError):
    """A setting (resolution, spp, an image's declared size) needs more memory than the budget."""


class OutputError(BadInputError):
    """The output location cannot take the files (not writable, a name taken by a folder)."""


class BufferContentError(SensaovError):
    """A buffer being built is inconsistent: a missing or misshapen array, a duplicate name."""


class NonFiniteGradientError(BufferContentError):
    """A gradient holds NaN or infinity; a buffer never stores one."""

    def __init__(self, objective: str, key: str, bad: int, total: int):
        super().__init__(
            f"gradient of objective {objective!r} w.r.t. parameter {key!r} has {bad} of "
            f"{total} components NaN or infinite",
            hint="more spp or a different seed may help; check the objective for a division "
            "by zero, or leave the parameter out of the selection",
        )
        self.objective = objective
        self.key = key


class UnknownNameError(BadInputError):
    """A name (objective, parameter key, object, type) the buffer does not hold."""

    def __init__(self, kind: str, name: str, valid: Iterable[str]):
        valid = list(valid)
        close = difflib.get_close_matches(name, valid, n=3)
        shown = ", ".join(valid[:12]) + (f", … ({len(valid) - 12} more)" if len(valid) > 12 else "")
        hint = f"did you mean {' or '.join(map(repr, close))}? " if close else ""
        super().__init__(
            f"no {kind} {name!r} in the buffer", hint=f"{hint}known: {shown or 'none'}"
        )


class QueryError(BadInputError):
    """A query option out of range: an unknown aggregation method, weight or grouping."""


class EncodingError(BadInputError, ValueError):
    """An encoding option out of range, or an encoding description that cannot be read."""


class NonFiniteError(SensaovError, ValueError):
    """Sensitivities or pixels that are NaN or infinite: the gradient pass went wrong."""


class CryptomatteError(SensaovError, ValueError):
    """Ranked coverage that cannot become Cryptomatte layers (shape, index, type name)."""


class ExrError(SensaovError, ValueError):
    """An EXR cannot be written as asked (bad shapes, NaN, clashing names) or cannot be read."""


class ExrReadError(ExrError):
    """An EXR a command reads is a special file, corrupt, truncated or declares too many pixels."""

    exit_code = EXIT_BAD_INPUT


class CameraFileError(BadInputError):
    """An inspection camera's EXR that cannot be read, or that holds no CryptoObject layer."""


class PreviewError(SensaovError):
    """The preview cannot be drawn on this machine (OpenImageIO without its fonts)."""

    exit_code = EXIT_ENVIRONMENT


class FingerprintMismatch(SpecError):
    """The buffer was computed on another version of the scene."""


class StaleInputError(BadInputError):
    """An input made from another buffer, or by another version of the job, than the one at
    hand: a preview, an EXR or a buffer that would mix two states in one output."""


class RequestError(BadInputError):
    """A request to ``sensaov view``'s server with a bad value: answered HTTP 400, one line."""


class ServerError(BadInputError):
    """``sensaov view`` cannot listen where it was told to (the port is taken, no such host)."""
