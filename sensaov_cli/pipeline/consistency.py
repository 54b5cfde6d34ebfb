"""Which outputs belong together: the checks ``project``, ``report`` and ``rank --exr`` share.

A buffer records the job version it was made from (``run_version``, :meth:`JobSpec.run_hash`);
every EXR, preview and manifest made from a buffer records the buffer's id and the hash of the
job that made it (:func:`sensaov_cli.buffer.model.stamp`). A command that reads outputs
together refuses, in one line with exit 2, anything that would mix two states: a buffer from
another version of the job, an EXR or a preview from another buffer (docs/buffer-format.md,
"Identity").
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from sensaov_cli.buffer.model import (
    STAMP_BUFFER,
    STAMP_JOB,
    SensitivityBuffer,
    buffer_id,
    run_version,
)
from sensaov_cli.errors import StaleInputError
from sensaov_cli.job.spec import JobSpec

# The job's top-level keys, as `run` reads them; a mismatch names the ones that differ.
_RUN_KEYS = ("scene", "scene_args", "variant", "render", "parameters", "objective_camera",
             "objectives", "forward", "channels")  # fmt: skip


def check_buffer_of_job(
    job: JobSpec, buffer: SensitivityBuffer, path: Path, *, override: str = ""
) -> None:
    """Refuse a buffer that ``run`` made from another version of ``job`` (or another job).

    The same version is the same ``run_version``, or (a job moved beside its scene, or a buffer
    older than ``run_version``) the same values of every key ``run`` reads, paths absolute.
    ``override`` names the command's way past the check, for the hint."""
    if run_version(buffer) == job.run_hash():
        return
    stored = buffer.provenance.get("job")
    differ = _differing(stored, json.loads(json.dumps(job.to_dict())))
    if isinstance(stored, Mapping) and not differ:
        return
    what = f" ({', '.join(differ)} differ)" if differ else " (it records no job)"
    raise StaleInputError(
        f"the buffer was made by another version of {job.path.name}{what}",
        where=str(path),
        hint=f"re-run 'sensaov run {job.path}'" + (f", or {override}" if override else ""),
    )


def check_made_from(
    attributes: Mapping[str, Any], buffer: SensitivityBuffer, where: str, *, remake: str
) -> None:
    """Refuse an output (its EXR header or PNG text) not made from ``buffer``."""
    made = attributes.get(STAMP_BUFFER)
    if made == buffer_id(buffer):
        return
    said = "records no buffer (an older sensaov made it)" if made is None else (
        f"was made from another buffer ({made}, not {buffer_id(buffer)})"
    )  # fmt: skip
    raise StaleInputError(said, where=where, hint=f"re-run '{remake}'")


def check_made_by(attributes: Mapping[str, Any], job: JobSpec, where: str, *, remake: str) -> None:
    """Refuse an output made by another version of ``job`` (other cameras, channels, views)."""
    if attributes.get(STAMP_JOB) != job.job_hash():
        raise StaleInputError(
            f"was made by another version of {job.path.name}",
            where=where,
            hint=f"re-run '{remake}'",
        )


def _differing(stored: Any, current: Mapping[str, Any]) -> list[str]:
    """The keys ``run`` reads whose values differ (a transport channel is read by ``run``,
    every other channel only later)."""
    if not isinstance(stored, Mapping):
        return []

    def read_by_run(job: Mapping[str, Any], key: str) -> Any:
        if key == "channels":
            return [c for c in job.get(key) or () if c.get("kind") == "transport"]
        return job.get(key)

    return [key for key in _RUN_KEYS if read_by_run(stored, key) != read_by_run(current, key)]
