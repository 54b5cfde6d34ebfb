"""Wire the stages of ``sensaov check``: spec -> scene -> one objective -> finite differences.

The job's objective (the first, or the one named) is built for the objective camera and
:func:`~sensaov_cli.render.fdcheck.check_gradients` compares its reverse-mode gradients with
central finite differences; :func:`exit_code` says whether the result is a failure.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from sensaov_cli.buffer.model import SensitivityBuffer
from sensaov_cli.buffer.statistics import single_pass
from sensaov_cli.errors import EXIT_JOB_FAILED, EXIT_OK, FingerprintMismatch, SpecError
from sensaov_cli.render.duality import FD_TOLERANCE, DualityCheck, check_duality  # noqa: F401 - re-exported for the CLI
from sensaov_cli.render.fdcheck import GradientCheck, check_gradients
from sensaov_cli.render.objectives import build_objectives
from sensaov_cli.render.scene import load_scene
from sensaov_cli.spec.model import JobSpec, ObjectiveSpec

DEFAULT_SEEDS = 6
DEFAULT_TOP = 3
DEFAULT_DIRECTIONS = 2  # random directions per parameter, besides ones


def check_job(
    job: JobSpec,
    *,
    objective: str | None = None,
    spp: int | None = None,
    seeds: int = DEFAULT_SEEDS,
    keys: Sequence[str] = (),
    allow_python: bool,
) -> list[GradientCheck]:
    """Check one objective's gradients over seeds ``0 .. seeds-1`` at ``spp`` (default: the job's).

    ``keys`` names the parameters to check; without them, one of each kind in the selection.
    """
    loaded = load_scene(job)
    chosen = _objective(job, objective)
    width, height = loaded.resolution
    (built,) = build_objectives(loaded.mi, (chosen,), (height, width), allow_python)
    return check_gradients(
        loaded,
        built,
        spp=spp or job.render.spp,
        seeds=list(range(seeds)),
        keys=list(keys) or None,
    )


def duality_job(
    job: JobSpec,
    buffer_path: Path,
    *,
    keys: Sequence[str] = (),
    top: int = DEFAULT_TOP,
    directions: int = DEFAULT_DIRECTIONS,
    allow_python: bool,
) -> list[DualityCheck]:
    """The stored buffer against forward mode and central differences, every objective."""
    buffer = SensitivityBuffer.load(buffer_path)
    if buffer.provenance.get("job_hash") != job.job_hash():
        raise FingerprintMismatch(
            "the buffer was written by another version of this job (job hash differs)",
            where=str(buffer_path),
            hint="re-run 'sensaov run' first: the check replays the buffer's own passes",
        )
    if not single_pass(buffer.provenance):
        raise FingerprintMismatch(
            "the duality check replays one backward pass; this buffer is a shard, an objective "
            "task or the mean of several batches or shards",
            where=str(buffer_path),
            hint="check a single-batch run of the job (render.batches: 1, no --shard)",
        )
    loaded = load_scene(job)
    if buffer.provenance.get("scene_fingerprint") != loaded.fingerprint:
        raise FingerprintMismatch(
            f"the buffer was made from another version of {job.scene.name}",
            where=str(buffer_path),
            hint="re-run 'sensaov run' first",
        )
    width, height = loaded.resolution
    built = build_objectives(loaded.mi, job.objectives, (height, width), allow_python)
    return check_duality(
        loaded, built, buffer, keys=list(keys) or None, top=top, random_directions=directions
    )


def exit_code(checks: Sequence[GradientCheck], duality: Sequence[DualityCheck] = ()) -> int:
    """A failure when a parameter the verification table trusts disagrees, or the buffer
    disagrees with forward mode at its own seed; else success."""
    contradicted = any(c.claimed_verified and c.verdict == "disagrees" for c in checks)
    return EXIT_JOB_FAILED if contradicted or any(d.failed for d in duality) else EXIT_OK


def _objective(job: JobSpec, name: str | None) -> ObjectiveSpec:
    """The job's first objective, or the one called ``name``."""
    for spec in job.objectives:
        if name in (None, spec.name):
            return spec
    names = ", ".join(o.name for o in job.objectives)
    raise SpecError(
        f"no objective named {name!r}", where="--objective", hint=f"objectives: {names}"
    )
