"""Wire the stages of ``sensaov check``: spec -> scene -> finite differences and duality."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from sensaov_cli.buffer.model import SensitivityBuffer
from sensaov_cli.buffer.npz import read_buffer
from sensaov_cli.buffer.statistics import whole_run
from sensaov_cli.errors import EXIT_JOB_FAILED, EXIT_OK, FingerprintMismatch
from sensaov_cli.job.spec import JobSpec
from sensaov_cli.outputs.tables import format_table
from sensaov_cli.pipeline.run import BUFFER_NAME, Task, task_job
from sensaov_cli.progress import Progress
from sensaov_cli.render.loading import load_scene
from sensaov_cli.render.objectives import build_objectives
from sensaov_cli.render.verify.fdcheck import (
    FD_TOLERANCE,
    DualityCheck,
    GradientCheck,
    audit,
    check_duality,
    plan_audit,
)
from sensaov_cli.scene import prepare_scene

__all__ = ["CheckReport", "checks_text", "duality_text", "exit_code", "run_check"]

FULL_DIRECTIONS = 2  # random directions per parameter besides ones, with --full (else 0)


@dataclass(frozen=True)
class CheckReport:
    gradients: list[GradientCheck]  # reverse mode against finite differences, per kind
    duality: list[DualityCheck]  # the stored buffer against forward mode; [] without one
    buffer_path: Path | None  # the buffer the duality column checked; None: there is none
    not_measured: tuple[tuple[str, str], ...] = ()  # (key, why) of kinds left out
    notes: tuple[str, ...] = ()  # what changed how kinds are checked (Russian roulette)

    def as_json(self) -> dict[str, list[Any]]:
        """What ``sensaov check --json`` prints."""
        duality = [
            {**asdict(d), "duality_error": d.duality_error, "central_error": d.central_error,
             "verdict": d.verdict}
            for d in self.duality
        ]  # fmt: skip
        return {
            "finite_differences": [asdict(r) for r in self.gradients],
            "not_measured": [{"key": k, "why": why} for k, why in self.not_measured],
            "notes": list(self.notes),
            "duality": duality,
        }


def run_check(
    job: JobSpec,
    *,
    objective: str | None,
    spp: int | None,
    seeds: int,
    keys: Sequence[str],
    buffer_path: Path | None,
    top: int,
    directions: int | None,
    full: bool,
    allow_python: bool,
    progress: Progress,
) -> CheckReport:
    """One objective's gradients against central finite differences, then, when the job's
    buffer (or ``buffer_path``) exists, its ``top`` parameters per objective against forward
    mode (``sensaov check --help`` says how); the scene is prepared and loaded once."""
    if directions is None:
        directions = FULL_DIRECTIONS if full else 0
    task = Task(objectives=() if objective is None else (objective,))
    chosen = task_job(job, task).objectives[0]  # the command's own options are checked first
    path = buffer_path or job.output / BUFFER_NAME
    buffer = _checkable_buffer(job, path) if path.is_file() else None
    prepared = prepare_scene(job)
    if buffer is not None and buffer.provenance.get("scene_fingerprint") != prepared.fingerprint:
        raise FingerprintMismatch(
            f"the buffer was made from another version of {job.scene.name}",
            where=str(path),
            hint="re-run 'sensaov run' first",
        )
    loaded = load_scene(prepared, variant=job.variant, parameters=job.parameters)
    width, height = loaded.resolution
    (built,) = build_objectives(loaded.mi, (chosen,), (height, width), allow_python)
    plan = plan_audit(loaded, list(keys) or None, full)
    gradients = audit(
        loaded, built, plan, spp=spp or job.render.spp, seeds=range(seeds), progress=progress
    )
    if buffer is None:
        return CheckReport(gradients, [], None, plan.skipped, plan.notes)
    every = build_objectives(loaded.mi, job.objectives, (height, width), allow_python)
    duality = check_duality(
        loaded, every, buffer, keys=list(keys) or None, top=top, random_directions=directions,
        progress=progress, central=full,
    )  # fmt: skip
    return CheckReport(gradients, duality, path, plan.skipped, plan.notes)


def _checkable_buffer(job: JobSpec, path: Path) -> SensitivityBuffer:
    """The buffer, if the duality check can replay its passes; refused before any render."""
    buffer = read_buffer(path)
    if buffer.provenance.get("job_hash") != job.job_hash():
        raise FingerprintMismatch(
            "the buffer was written by another version of this job (job hash differs)",
            where=str(path),
            hint="re-run 'sensaov run' first: the check replays the buffer's own passes",
        )
    if not whole_run(buffer.provenance):
        raise FingerprintMismatch(
            "the duality check replays the run's batches; this buffer is a shard, an objective "
            "task or a merge of shards",
            where=str(path),
            hint="check a buffer 'sensaov run JOB' wrote (no --shard, no --objective)",
        )
    return buffer


def exit_code(checks: Sequence[GradientCheck], duality: Sequence[DualityCheck] = ()) -> int:
    """A failure when a parameter the verification table trusts disagrees, or the buffer
    disagrees with forward mode at its own seed; else success. "inconclusive" and "noisy" are
    no contradiction: the check could not decide, and says why (docs/verification.md)."""
    contradicted = any(c.claimed_verified and c.verdict == "disagrees" for c in checks)
    return EXIT_JOB_FAILED if contradicted or any(d.failed for d in duality) else EXIT_OK


def checks_text(checks: Sequence[GradientCheck]) -> str:
    rows = [
        ("key", "plugin", "type", "table", "method", "adjoint", "finite diff", "std err", "verdict")
    ]
    for c in checks:
        error = "-" if c.method == "same seed" else f"{c.standard_error:.1e}"
        contradicts = c.claimed_verified and c.verdict == "disagrees"
        verdict = c.verdict + ("  <-- CONTRADICTS THE TABLE" if contradicts else "")
        # c.claimed: the table's own label (biased kinds say biased)
        numbers = (f"{c.adjoint:+.3e}", f"{c.finite_difference:+.3e}", error, verdict)
        rows.append((c.key, c.plugin, c.type, c.claimed, c.method, *numbers))
    reasons = [f"{c.verdict}: {c.key}: {c.reason}" for c in checks if c.reason]
    return "\n".join([*format_table(rows), *reasons])


def duality_text(rows: Sequence[DualityCheck], buffer: Path) -> str:
    """The duality column of ``check``: the buffer against forward mode and central differences."""
    head = (
        f"duality at the buffer's gradient seeds ({buffer}): forward <dM/dI, Jv> vs stored "
        f"<g, v> (tolerance {rows[0].tolerance:.1e} at this size); central differences of "
        f"the image at the same seed (tolerance {FD_TOLERANCE:.0%}; n/a: discontinuous parameter)"
    )
    table = [
        ("objective", "key", "v", "trust", "<g,v>", "forward", "err", "central", "err", "verdict")
    ]
    for d in rows:
        central = "n/a" if d.central is None else f"{d.central:+.4e}"
        central = central if d.central_asked else "(--full)"
        error = "" if d.central_error is None else f"{d.central_error:.1e}"
        duality = (f"{d.reverse:+.4e}", f"{d.forward:+.4e}", f"{d.duality_error:.1e}")
        table.append(
            (d.objective, d.key, d.direction, d.trust, *duality, central, error, d.verdict)
        )
    return "\n".join([head, *format_table(table)])
