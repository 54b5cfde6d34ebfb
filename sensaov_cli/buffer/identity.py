"""Which buffer an output was made from: the buffer's id and the job version it records.

Every buffer ``run`` or ``merge`` writes carries a fresh random ``buffer_id`` in its provenance,
and ``run_version``: the hash of what ``run`` read of the job (``JobSpec.run_hash``). Every
output made from a buffer (EXRs, previews, the report) records both, so a command that reads
outputs together refuses to mix two states (docs/buffer-format.md, "Identity").
"""

from __future__ import annotations

import hashlib
import json
import uuid
from typing import Any

from sensaov_cli.buffer.model import SensitivityBuffer

BUFFER_ID = "buffer_id"
RUN_VERSION = "run_version"
LEGACY_PREFIX = "legacy-"  # a buffer written before ids existed: named by its provenance


def new_buffer_id() -> str:
    """A fresh id for a buffer about to be written (random: two runs never share one)."""
    return uuid.uuid4().hex[:16]


def buffer_id(buf: SensitivityBuffer) -> str:
    """The buffer's id; an older buffer without one is named by a hash of its provenance
    (which holds its creation time and timings, so two runs still differ)."""
    return provenance_id(buf.provenance)


def provenance_id(provenance: dict[str, Any]) -> str:
    recorded = provenance.get(BUFFER_ID)
    if isinstance(recorded, str) and recorded:
        return recorded
    text = json.dumps(provenance, sort_keys=True, default=str)
    return LEGACY_PREFIX + hashlib.sha256(text.encode()).hexdigest()[:16]


def run_version(buf: SensitivityBuffer) -> str | None:
    """The job version the buffer was made from, or None for a buffer older than the field."""
    recorded = buf.provenance.get(RUN_VERSION)
    return recorded if isinstance(recorded, str) and recorded else None


# What every output made from a buffer records (EXR header attributes, PNG text chunks, the
# previews' manifests): the buffer's id, the run version it records and the job_hash of the
# job that made the output (project's job may differ from run's in cameras and channels).
STAMP_BUFFER = "sensaov/buffer_id"
STAMP_RUN = "sensaov/run_version"
STAMP_JOB = "sensaov/job_hash"


def stamp(buf: SensitivityBuffer, job_hash: str) -> dict[str, str]:
    """The attributes an output made from ``buf`` by a job hashing to ``job_hash`` records."""
    return {STAMP_BUFFER: buffer_id(buf), STAMP_RUN: run_version(buf) or "", STAMP_JOB: job_hash}
