"""Wire the stages of ``sensaov run``: spec -> scene -> objectives -> adjoint -> buffer -> files.

The forward passes of the job's forward channels and transport layers run last, at the
backward passes' seeds, and are written beside the buffer in the forward sidecar.
"""

from __future__ import annotations

import datetime
import os
import platform
import sys
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

from sensaov_cli import interrupts
from sensaov_cli.buffer.forward_sidecar import (
    ForwardData,
    ForwardLayer,
    ForwardPass,
    forward_writer,
    ties_of,
)
from sensaov_cli.buffer.model import (
    BUFFER_ID,
    RUN_VERSION,
    ObjectiveRecord,
    SensitivityBuffer,
    new_buffer_id,
)
from sensaov_cli.buffer.npz import buffer_writer, read_buffer
from sensaov_cli.buffer.shards import PRIMAL, pixels_digest
from sensaov_cli.errors import InputFileError, SensaovError, SpecError
from sensaov_cli.job.spec import ChannelSpec, JobSpec, UntilSpec
from sensaov_cli.outputs.atomic import (
    atomic_write_all,
    check_writable,
    made_by,
    provenance_attributes,
    refuse_unsafe_outputs,
)
from sensaov_cli.outputs.exr import exr_writer, image_channels, read_exr
from sensaov_cli.pipeline.resolution import Resolution, resolution
from sensaov_cli.progress import Progress
from sensaov_cli.render.adjoint import (
    AdjointResult,
    ImageEffect,
    adjoint_images,
    batch_plan,
    batches_forward_image,
    combine,
    depth_effect,
    integrator_plan,
    render_batches,
)
from sensaov_cli.render.loading import (
    LoadedScene,
    check_gradients,
    check_render,
    load_scene,
    refuse_non_finite,
    render_bytes,
)
from sensaov_cli.render.objectives import Objective, build_objectives
from sensaov_cli.render.runtime import library_versions
from sensaov_cli.render.verify.repair import repair
from sensaov_cli.render.verify.selfcheck import LINEAR_OBJECTIVES
from sensaov_cli.scene import PreparedScene, prepare_scene
from sensaov_cli.views.channels import direction_values, group_keys, top_objects, transport_views

BUFFER_NAME = "buffer.npz"
PRIMAL_NAME = "primal.exr"
FORWARD_NAME = "forward.npz"  # the forward sidecar, written with its buffer or not at all


@dataclass(frozen=True)
class Task:
    """Which part of a job one process renders: a shard of the samples, some objectives."""

    shard: tuple[int, int] | None = None  # (i, n), 1 <= i <= n: batch i-1 of n (adjoint.py)
    objectives: tuple[str, ...] = ()  # empty: all of the job's

    def file_names(self) -> tuple[str, str]:
        """buffer.npz / primal.exr, or e.g. buffer.shard-2-of-8.objective-mean_luma.npz."""
        middle = f".shard-{self.shard[0]}-of-{self.shard[1]}" if self.shard else ""
        middle += "".join(f".objective-{name}" for name in self.objectives)
        return f"buffer{middle}.npz", f"primal{middle}.exr"

    def describe(self) -> dict[str, dict[str, int] | list[str] | None]:
        """The task as the buffer's provenance records it (``--resume`` compares it)."""
        shard = {"index": self.shard[0], "count": self.shard[1]} if self.shard else None
        return {"shard": shard, "objectives": list(self.objectives) or None}


@dataclass(frozen=True)
class TaskResult:
    """What one task came to: its buffer, written now or found complete."""

    buffer: SensitivityBuffer
    skipped: bool  # --resume found the task's files complete: nothing was rendered or written


def run_job(
    job: JobSpec,
    *,
    allow_python: bool,
    progress: Progress,
    task: Task = Task(),
    resume: bool = False,
) -> SensitivityBuffer:
    """Render the task of ``job`` and write its files (``task.file_names()`` in its output)."""
    done = run_task(job, allow_python=allow_python, progress=progress, task=task, resume=resume)
    return done.buffer


def run_task(
    job: JobSpec,
    *,
    allow_python: bool,
    progress: Progress,
    task: Task = Task(),
    resume: bool = False,
) -> TaskResult:
    """:func:`run_job`, and whether ``resume`` skipped the task (its files were complete)."""
    started = time.perf_counter()
    whole, job = job, task_job(job, task)  # provenance records the whole job: shards compare
    buffer_name, primal_name = task.file_names()
    buffer_path, primal_path = job.output / buffer_name, job.output / primal_name
    prepared = prepare_scene(job)  # every camera checked: a bad one fails before the render
    if resume:
        done = completed(whole, task, buffer_path, primal_path, prepared.fingerprint)
        if done is not None:
            progress.note(f"{buffer_path.name} is complete for this job: skipped (--resume)")
            return TaskResult(done, skipped=True)
    # Duality needs the forward passes at the backward's samples: every batch of the whole job.
    forward_wanted = job.wants_forward and task.shard is None and not task.objectives
    check_writable(job.output, [buffer_name, primal_name] + [FORWARD_NAME] * forward_wanted)
    outputs = [buffer_path, primal_path] + [job.output / FORWARD_NAME] * forward_wanted
    inputs = (*job.input_files(), *prepared.files)
    refuse_unsafe_outputs(inputs, outputs, where=str(job.path))
    with progress.stage("load_s", f"loading {job.scene.name}"):
        loaded = load_scene(prepared, variant=job.variant, parameters=job.parameters)
    refuse_non_finite(loaded)
    if not loaded.selected:
        raise SpecError(
            "no scene parameter is selected: there is nothing to differentiate",
            where=f"{job.path}: parameters",
            hint="'sensaov params JOB' lists every key and why it was left out",
        )
    if prepared.replaced_integrator is not None:
        progress.note(
            f"the scene's '{prepared.replaced_integrator}' integrator renders other light "
            f"transport than the path replay sensaov differentiates (full paths up to "
            f"max_depth {_depth(prepared.integration.max_depth)}): M is measured on that image"
        )
    scene_spp = prepared.sample_count
    if scene_spp is not None and scene_spp != job.render.spp:
        progress.note(
            f"the scene's sampler asks for {scene_spp} spp; rendering with the job's "
            f"render.spp = {job.render.spp} (both are recorded in the buffer)"
        )
    width, height = loaded.resolution
    check_render(  # the objective camera's passes, at the film the scene gave
        width * height,
        job.render.spp,
        objectives=len(job.objectives) * job.render.batch_count,
        setting=f"render.spp = {job.render.spp} at {width}x{height}",
        where=str(job.path),
    )
    progress.note(
        f"{len(loaded.selected)} parameters over {len(loaded.objects)} objects, "
        f"variant {loaded.variant}, {len(job.objectives)} objective(s)"
    )
    objectives = build_objectives(loaded.mi, whole.objectives, (height, width), allow_python)
    # An objective keeps its index in the whole job (its gradient seed) when a task picks it.
    objectives = [o for o in objectives if o.spec in job.objectives]
    plan_forward(job, loaded)  # an entry selecting nothing fails here, before any render
    if job.wants_forward and not forward_wanted:
        progress.note(
            "forward channels and transport layers are rendered by whole runs only, "
            "not by a shard or an --objective task (docs/farm.md)"
        )
    spp, seed, batches = job.render.spp, job.render.seed, job.render.batch_count
    if task.shard is not None:  # shard i of n: batch i-1 of the job's n-batch plan, one batch
        spp, seed = batch_plan(spp, seed, task.shard[1])[task.shard[0] - 1]
        batches = 1
    until = job.render.until if task.shard is None and not task.objectives else None
    if job.render.until is not None and until is None:
        progress.note("render.until is ignored by a shard or an --objective task (docs/farm.md)")
    # A large texture's gradients outweigh the passes: refused here, before any pass runs
    # (render.until's rounds keep every batch until the combine: counted at their most).
    rounds = 1 if until is None else -(-until.max_spp // spp)
    check_gradients(
        loaded.selected,
        objectives=len(objectives),
        batches=batches * rounds,
        passes=render_bytes(width * height, spp, objectives=len(objectives)),
        where=str(job.path),
    )
    passes = len(integrator_plan(loaded)) * len(objectives)
    # Every pass counts: a transport channel's top objects are only known after the backward
    # passes, so its passes are planned at their most and the ones not needed skipped then.
    planned_forward = forward_bound(job, len(objectives)) if forward_wanted else 0
    measured = prepared.integration.scene_image is not None  # the depth effect's pass
    progress.plan(batches * (1 + passes) + planned_forward + 1 + measured)
    effects = _note_depth_effect(prepared, loaded, objectives, job.render.seed, progress)
    plan = batch_plan(spp, seed, batches)
    determinism = job.render.deterministic
    rendered = render_batches(loaded, objectives, plan, determinism, progress)
    result = combine(loaded, objectives, rendered)
    outcome = None
    if until is not None:
        result, outcome = sample_until(
            job, until, loaded, objectives, rendered, result, progress,
            after=planned_forward + 1,
        )  # fmt: skip
        batches = len(result.provenance["batches"])
    del rendered  # every batch's arrays: the mean is all that is kept
    # The repairs' plan is the whole job's: a shard renders its batch's share of the seeds.
    result = repair(
        loaded, objectives, result, job.repair, seed=job.render.seed,
        spp=job.render.spp if task.shard else result.spp,
        batches=task.shard[1] if task.shard else batches,
        shard=task.shard[0] - 1 if task.shard else None,
        passes=len(integrator_plan(loaded)) * len(whole.objectives),
        progress=progress, stages_after=planned_forward + 1, until_resolved=until is not None,
    )  # fmt: skip
    provenance = _provenance(whole, loaded, result, progress.timings, time.perf_counter() - started)
    if outcome is not None:
        outcome = until_outcome(job, loaded, result, outcome, progress)
    provenance["task"] = task.describe()
    # What primal this buffer was written with: --resume and merge recognise one put in its place.
    primal_channels = image_channels(result.image)
    provenance[PRIMAL] = {"file": primal_name, "sha256": pixels_digest(primal_channels)}
    provenance["batches_setting"] = job.render.batches  # "auto" or the job's count
    if outcome is not None:
        provenance["until"] = outcome.figures()
    provenance["image_effects"] = [asdict(effect) for effect in effects]
    buffer = _make_buffer(job, loaded, result, provenance)
    forward = None
    if forward_wanted:
        forward = run_forward(job, loaded, objectives, buffer, result, progress)
        progress.skip(planned_forward - len(forward.passes))
        # The buffer's times cover every pass of the run, forward passes included.
        timed = {**buffer.provenance, "timings_s": dict(progress.timings),
                 "wall_time_s": round(time.perf_counter() - started, 4)}  # fmt: skip
        buffer = replace(buffer, provenance=timed, _copy_arrays=False)
    interrupts.raise_if_stopped()  # a stop asked for during a kernel must not end in written files
    with progress.stage("write_s", f"writing {buffer_path.name} and {primal_path.name}"):
        attributes = provenance_attributes(buffer.provenance, relative_to=job.output)
        primal = exr_writer(primal_channels, attributes)
        files = [(buffer_path, buffer_writer(buffer)), (primal_path, primal)]
        if forward is not None:  # the forward sidecar is written with its buffer, or neither
            files.append((job.output / FORWARD_NAME, forward_writer(forward)))
        try:
            atomic_write_all(files)
        except OSError as exc:
            raise SensaovError(
                f"cannot write outputs: {exc.strerror or exc}", where=str(job.output)
            ) from exc
    return TaskResult(buffer, skipped=False)


@dataclass(frozen=True)
class UntilOutcome:
    """What ``render.until`` did: the samples spent and what they resolved."""

    setting: UntilSpec
    spp: int  # spent in all, the first render.spp included
    rounds: int
    resolution: Resolution

    def figures(self) -> dict[str, Any]:
        """The buffer's provenance record (docs/job-spec.md, render.until)."""
        return {
            "resolved": self.setting.resolved,
            "max_spp": self.setting.max_spp,
            "spp_spent": self.spp,
            "rounds": self.rounds,
            "batches": self.resolution.batches,
            "outcome": "resolved" if self.resolution.done else "open",
            "resolved_objects": [list(pair) for pair in self.resolution.resolved],
            "open": [
                {"objective": o.objective, "name": o.name, "what": o.what}
                for o in self.resolution.open
            ],
        }


def sample_until(
    job: JobSpec,
    until: UntilSpec,
    loaded: LoadedScene,
    objectives: list[Objective],
    rendered: list[AdjointResult],
    result: AdjointResult,
    progress: Progress,
    *,
    after: int,
) -> tuple[AdjointResult, UntilOutcome]:
    """Add rounds of batches (render.spp split as the first, at seeds no round used) until the
    top ``until.resolved`` objects of every objective are resolved or ``until.max_spp`` is
    spent; ``rendered`` (the first round's batches) grows. ``after``: stages planned after."""
    spp, seed, count = job.render.spp, job.render.seed, job.render.batch_count
    passes = len(integrator_plan(loaded)) * len(objectives)
    rounds, spent = 1, result.spp
    found = resolution(_make_buffer(job, loaded, result, {}), until.resolved)
    while not found.done:
        more = []
        for batch in batch_plan(spp, seed, count, first=rounds * count):
            if spent + batch[0] > until.max_spp:
                break
            more.append(batch)
            spent += batch[0]
        if not more:
            break
        progress.note(
            f"render.until: {len(found.open)} signs or orders of the top {until.resolved} "
            f"open after {result.spp} spp; adding {len(more)} batches "
            f"({sum(n for n, _ in more)} spp)"
        )
        progress.plan(len(more) * (1 + passes) + after)
        numbered = (len(rendered) + 1, len(rendered) + len(more))
        rendered += render_batches(
            loaded, objectives, more, job.render.deterministic, progress, numbered
        )
        result = combine(loaded, objectives, rendered)
        rounds += 1
        found = resolution(_make_buffer(job, loaded, result, {}), until.resolved)
    return result, UntilOutcome(until, result.spp, rounds, found)


def until_outcome(
    job: JobSpec,
    loaded: LoadedScene,
    result: AdjointResult,
    outcome: UntilOutcome,
    progress: Progress,
) -> UntilOutcome:
    """What the finished run resolved, repairs in place (the rounds judged reverse mode's
    gradients: a repair is too costly to repeat each round), said and returned."""
    found = resolution(_make_buffer(job, loaded, result, {}), outcome.setting.resolved)
    names = ", ".join(f"{o}: {n}" for o, n in found.resolved) or "none"
    progress.note(f"render.until: resolved signs: {names}")
    if found.done:
        progress.note(
            f"render.until: the top {outcome.setting.resolved} objects of every objective are "
            f"resolved (signs and order) at {outcome.spp} spp in {found.batches} batches"
        )
    else:
        reached = outcome.spp + job.render.spp // job.render.batch_count > outcome.setting.max_spp
        why = f"max_spp {outcome.setting.max_spp} reached" if reached else "repairs reopened"
        progress.note(
            f"render.until: {why} at {outcome.spp} spp ({found.batches} batches); still open: "
            + "; ".join(item.describe() for item in found.open)
        )
    return replace(outcome, resolution=found)


def _depth(depth: int) -> str:
    return "unbounded" if depth < 0 else str(depth)


def _note_depth_effect(
    prepared: PreparedScene,
    loaded: LoadedScene,
    objectives: list[Objective],
    seed: int,
    progress: Progress,
) -> list[ImageEffect]:
    """Warn that the job's max_depth changes the scene's image, by how much M changes."""
    plan = prepared.integration
    if plan.scene_image is None:
        return []
    with progress.stage("depth_effect_s", "measuring what the job's max_depth changes"):
        effects = depth_effect(loaded, objectives, plan.scene_image, seed)
    figures = ", ".join(
        f"{e.objective!r} {e.value:.4g} against {e.scene_value:.4g} ({e.relative:+.1%})"
        for e in effects
    )
    progress.note(
        f"the job's render.max_depth {_depth(plan.max_depth)} replaces the scene's "
        f"{_depth(plan.scene_max_depth)}: M is measured on another image than the scene "
        f"renders ({figures} at {effects[0].spp if effects else 0} spp, one seed); leave "
        "max_depth out of the job to differentiate the scene's own image"
    )
    return effects


def _make_buffer(
    job: JobSpec, loaded: LoadedScene, result: AdjointResult, provenance: dict[str, Any]
) -> SensitivityBuffer:
    objectives = tuple(
        ObjectiveRecord(
            name=spec.name,
            definition=spec.definition(),
            value=result.objective_values[spec.name],
            grad_seed=result.grad_seeds[spec.name],
        )
        for spec in job.objectives
    )
    return SensitivityBuffer(
        provenance=provenance,
        objects=loaded.objects,
        params=result.params,  # the selected records, labelled by the run's self-checks
        objectives=objectives,
        values=result.values,
        grads=result.grads,
        statistics=result.statistics,
        repairs=result.repairs,
    )


def task_job(job: JobSpec, task: Task) -> JobSpec:
    """The job restricted to the task's objectives (each named once, in the job's order)."""
    if task.shard is not None and task.shard[1] > job.render.spp:
        raise SpecError(
            f"{task.shard[1]} shards cannot split render.spp = {job.render.spp}", where="--shard"
        )
    if not task.objectives:
        return job
    known = [spec.name for spec in job.objectives]
    unknown = [name for name in task.objectives if name not in known]
    if unknown:
        raise SpecError(
            f"no objective named {unknown[0]!r}",
            where="--objective",
            hint=f"objectives: {', '.join(known)}",
        )
    chosen = tuple(spec for spec in job.objectives if spec.name in task.objectives)
    return replace(job, objectives=chosen)


def completed(
    job: JobSpec, task: Task, buffer_path: Path, primal_path: Path, fingerprint: str
) -> SensitivityBuffer | None:
    """The task's buffer if it and its primal (an EXR of the whole film: a cut one is rendered
    again) are complete and made by this very job from the scene whose ``fingerprint`` is given.
    A whole primal other than the one the buffer records writing is refused (exit 2): another
    job's file was put in its place, and rendering over it would hide that."""
    if not (buffer_path.is_file() and primal_path.is_file()):
        return None
    try:
        buffer = read_buffer(buffer_path)
        channels, _ = read_exr(primal_path)
    except SensaovError:
        return None  # unreadable: render it again
    made = buffer.provenance
    same = made.get("job_hash") == job.job_hash() and made.get("task") == task.describe()
    same = same and made.get("scene_fingerprint") == fingerprint
    resolution = made.get("resolution")
    shape = tuple(reversed(resolution)) if isinstance(resolution, list) else None
    whole = bool(channels) and all(c.shape == shape for c in channels.values())
    if not (same and whole):
        return None
    recorded = made.get(PRIMAL)
    if not isinstance(recorded, dict) or recorded.get("sha256") is None:
        return None  # written before buffers recorded their primal: render it again
    if recorded.get("file") != primal_path.name or recorded["sha256"] != pixels_digest(channels):
        raise InputFileError(
            f"not the primal {buffer_path.name} was written with (its pixels differ from the "
            "ones the buffer records): another job's or another shard's file",
            where=str(primal_path),
            hint=f"delete it and {buffer_path.name}, then run the task again",
        )
    return buffer


def _provenance(
    job: JobSpec, loaded: LoadedScene, result: AdjointResult, timings: dict[str, float], wall: float
) -> dict[str, Any]:
    width, height = loaded.resolution
    return {
        **made_by(" ".join(sys.argv)),
        BUFFER_ID: new_buffer_id(),  # every output made from this buffer records it
        RUN_VERSION: job.run_hash(),  # what run read of the job: project and report compare it
        **library_versions(loaded.mi),
        "variant": loaded.variant,
        "libllvm": os.environ.get("DRJIT_LIBLLVM_PATH", ""),
        "python": platform.python_version(),
        "created_utc": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "job_path": str(job.path),
        "job_hash": job.job_hash(),
        "job": job.to_dict(),
        "scene_path": str(job.scene),
        "scene_fingerprint": loaded.prepared.fingerprint,
        "scene_files": [str(path) for path in loaded.prepared.files],  # never an output's name
        "scene_args": loaded.prepared.scene_args,  # every $name the scene used
        "scene_sample_count": loaded.prepared.sample_count,  # the scene's spp; the job's renders
        "integrator": loaded.integrator_type,  # the replay integrator that ran
        "scene_integrator_replaced": loaded.prepared.replaced_integrator,
        "scene_changes": [asdict(change) for change in loaded.prepared.changes],
        **result.provenance,  # which integrator differentiated what; the self-checks' figures
        "max_depth": loaded.prepared.integration.max_depth,  # -1: unbounded
        "scene_max_depth": loaded.prepared.integration.scene_max_depth,
        "spp": result.spp,  # this task's: a shard renders its share of render.spp
        "job_spp": job.render.spp,
        "primal_seed": result.provenance["batches"][0]["seed"],
        "gradient_seeds": result.grad_seeds,
        "deterministic": result.deterministic,
        "resolution": [width, height],
        "objective_sensor": loaded.sensor.id(),
        "shared_bsdfs": job.parameters.shared,
        "split_bsdfs": {name: list(shapes) for name, shapes in loaded.prepared.split.items()},
        "textures": [
            {"key": key, "file": source.file, "converted_from_8bit": source.converted}
            for key, source in loaded.textures.items()
        ],
        "excluded_parameters": len(loaded.excluded),
        "timings_s": dict(timings),
        "wall_time_s": round(wall, 4),
    }


# --- forward passes: the job's forward channels and transport layers (§4, §7) ----------------
#
# Groups are resolved before anything renders (plan_forward). After the backward passes,
# run_forward pushes each group once per seed it needs: a forward channel at the first
# objective's gradient seed, a transport layer at its own objective's gradient seed, the seed the
# buffer's gradient was computed at, so that the layer's duality check can hold to float32
# rounding. Identical (keys, direction, seed) passes render once.


@dataclass(frozen=True)
class _ForwardGroup:
    name: str
    keys: tuple[str, ...]
    direction: str
    transport: bool
    source: str


def plan_forward(job: JobSpec, loaded: LoadedScene) -> list[_ForwardGroup]:
    """The job's forward entries as key groups; an entry that selects nothing fails here."""
    groups = []
    for index, spec in enumerate(job.forward):
        where = f"forward[{index}]"
        keys = group_keys(loaded.selected, spec, where)
        groups.append(_ForwardGroup(spec.name, keys, spec.direction, spec.transport, where))
    return groups


def forward_bound(job: JobSpec, objectives: int) -> int:
    """The most forward passes the job can need with ``objectives`` objectives: one per forward
    entry, one per other objective for a transport entry, a transport channel's top objects for
    every objective (fewer when objects score 0 or passes coincide: skipped after the run)."""
    entries = sum(objectives if spec.transport else 1 for spec in job.forward)
    tops = sum(c.top * objectives for c in job.channels if c.kind == "transport")
    return entries + tops


def batch_seeds(result: AdjointResult) -> dict[str, tuple[tuple[int, int], ...]]:
    """Objective -> (spp, gradient seed) of each batch: where its forward passes replay."""
    spps = [int(batch["spp"]) for batch in result.provenance["batches"]]
    names = result.batch_grad_seeds[0] if result.batch_grad_seeds else result.grad_seeds
    return {
        name: tuple(
            (n, seeds[name]) for n, seeds in zip(spps, result.batch_grad_seeds, strict=True)
        )
        for name in names
    }


def transport_objectives(objectives: list[Objective], batches: int) -> list[str]:
    """The objectives whose transport layers keep duality: all with one batch; with several,
    those linear in the image (one dM/dI for every batch: the sidecar stores one)."""
    return [o.spec.name for o in objectives if batches == 1 or o.spec.type in LINEAR_OBJECTIVES]


def run_forward(
    job: JobSpec,
    loaded: LoadedScene,
    objectives: list[Objective],
    buffer: SensitivityBuffer,
    result: AdjointResult,
    progress: Progress,
) -> ForwardData:
    """Render every forward pass the job asks for, each batch at its own seeds."""
    primal = result.image
    seeds = batch_seeds(result)
    first = buffer.objectives[0].name
    number = "" if len(seeds[first]) == 1 else "_batch1"
    backward_s = progress.timings.get(f"backward_{first}{number}_s", 0.0) * len(seeds[first])
    transported = transport_objectives(objectives, len(seeds[first]))
    if len(transported) < len(objectives) and (
        any(g.transport for g in plan_forward(job, loaded))
        or any(c.kind == "transport" for c in job.channels)
    ):
        skipped = ", ".join(o.spec.name for o in objectives if o.spec.name not in transported)
        progress.note(
            f"no transport layers for {skipped}: an objective non-linear in the image has one "
            "dM/dI per batch, so its layers' duality cannot hold against the batch mean; "
            "render.batches: 1 renders them (docs/farm.md)"
        )
    layers: list[ForwardLayer] = []
    runner = _Passes(loaded, buffer, job, primal.shape, progress, backward_s)
    for group in plan_forward(job, loaded):
        index = runner.get(group, seeds[first])
        layers.append(ForwardLayer("forward", group.name, None, index, group.source))
        if group.transport:
            for objective in transported:
                index = runner.get(group, seeds[objective])
                name = f"transport_{group.name}"
                layers.append(ForwardLayer("transport", name, objective, index, group.source))
    for position, channel in enumerate(job.channels):
        if channel.kind == "transport":
            chosen = {name: seeds[name] for name in transported}
            layers += _top_layers(runner, chosen, channel, position)
    data = ForwardData(
        ties=ties_of(buffer),
        provenance={
            **made_by(" ".join(sys.argv)),
            "created_utc": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
            "spp": result.spp,
            "batches": len(seeds[first]),
            "max_depth": loaded.prepared.integration.max_depth,
            "backward_s": backward_s,
            "forward_s": [round(p.seconds, 4) for p in runner.passes],
        },
        adjoints=adjoint_images(loaded, objectives, primal),
        passes=tuple(runner.passes),
        layers=_unique_layers(layers),
    )
    for view in transport_views(buffer, data):
        if not view.agrees:
            progress.note(
                f"warning: transport layer {view.objective}.{view.name}: duality "
                f"residual {view.residual:.2e} exceeds {view.tolerance:.1e} (layer marked)"
            )
    return data


def _unique_layers(layers: list[ForwardLayer]) -> tuple[ForwardLayer, ...]:
    """One layer per EXR name: a repeat of the same pass is dropped, another pass numbered."""
    kept: dict[tuple[str, str | None, str], ForwardLayer] = {}
    for layer in layers:
        name = layer.name
        while (layer.kind, layer.objective, name) in kept:
            if kept[(layer.kind, layer.objective, name)].pass_index == layer.pass_index:
                break
            name += "_2"
        else:
            kept[(layer.kind, layer.objective, name)] = replace(layer, name=name)
    return tuple(kept.values())


def _top_layers(
    runner: _Passes,
    seeds: dict[str, tuple[tuple[int, int], ...]],
    channel: ChannelSpec,
    position: int,
) -> list[ForwardLayer]:
    """``<objective>.<channel>_<object>`` for the channel's top objects of every objective."""
    direction = "value" if channel.weight == "value" else "ones"
    layers = []
    for objective in seeds:
        for name in top_objects(runner.buffer, objective, channel.top, channel.weight):
            keys = tuple(p.key for p in runner.buffer.params if name in p.owners)
            source = f"channels[{position}] (top {channel.top} of {objective})"
            group = _ForwardGroup(name, keys, direction, True, source)
            index = runner.get(group, seeds[objective])
            layer_name = f"{channel.name}_{name}"
            layers.append(ForwardLayer("transport", layer_name, objective, index, source))
    return layers


@dataclass
class _Passes:
    """Forward passes rendered so far, one per (keys, direction, seed)."""

    loaded: LoadedScene
    buffer: SensitivityBuffer
    job: JobSpec
    shape: tuple[int, ...]
    progress: Progress
    backward_s: float
    passes: list[ForwardPass] = field(default_factory=list)
    index: dict[tuple[tuple[str, ...], str, tuple[tuple[int, int], ...]], int] = field(
        default_factory=dict
    )

    def get(self, group: _ForwardGroup, batches: tuple[tuple[int, int], ...]) -> int:
        """The pass of ``group`` at ``batches`` ((spp, gradient seed) each); the pass records
        the first batch's seed, the objective's gradient seed in the buffer."""
        key = (tuple(sorted(group.keys)), group.direction, batches)
        if key in self.index:
            return self.index[key]
        seed = batches[0][1]
        v = direction_values(self.buffer, group.keys, group.direction)
        n = len(self.passes)
        at = f"seed {seed}" if len(batches) == 1 else f"{len(batches)} batches"
        label = f"forward pass {n + 1} '{group.name}' ({len(group.keys)} parameters, {at})"
        with self.progress.stage(f"forward_{n}_s", label):
            result = batches_forward_image(
                self.loaded, v, batches=batches, shape=self.shape,
                deterministic=self.job.render.deterministic,
            )  # fmt: skip
        ratio = result.seconds / self.backward_s if self.backward_s > 0 else float("nan")
        self.progress.note(
            f"forward '{group.name}' ({group.source}): {result.seconds:.2f} s, "
            f"{ratio:.2f}x one backward pass"
        )
        if result.failure:
            self.progress.note(f"warning: Mitsuba cannot push '{group.name}': {result.failure}")
        self.passes.append(ForwardPass(
            group.keys, group.direction, seed, result.seconds, result.integrators, result.failure,
            result.image,
        ))  # fmt: skip
        self.index[key] = n
        return n
