"""Wire the stages of ``sensaov run``: spec -> scene -> objectives -> adjoint -> buffer -> files."""

from __future__ import annotations

import datetime
import os
import platform
import sys
import time
from dataclasses import dataclass
from importlib.metadata import version
from pathlib import Path
from typing import Any

from sensaov_cli import interrupts
from sensaov_cli.buffer.model import ObjectiveRecord, SensitivityBuffer
from sensaov_cli.buffer.npz import buffer_writer
from sensaov_cli.errors import SensaovError, SpecError
from sensaov_cli.outputs.atomic import atomic_write_all, check_writable
from sensaov_cli.outputs.exr import exr_writer, image_channels
from sensaov_cli.outputs.provenance import made_by, provenance_attributes
from sensaov_cli.progress import Progress
from sensaov_cli.render.adjoint import AdjointResult, run_adjoint
from sensaov_cli.render.inputs import refuse_unsafe_outputs
from sensaov_cli.render.objectives import build_objectives
from sensaov_cli.render.scene import LoadedScene, load_scene
from sensaov_cli.render.scene_xml import check_cameras
from sensaov_cli.spec.model import JobSpec

BUFFER_NAME = "buffer.npz"
PRIMAL_NAME = "primal.exr"


@dataclass(frozen=True)
class RunOutputs:
    buffer: SensitivityBuffer
    buffer_path: Path
    primal_path: Path


def run_job(job: JobSpec, *, allow_python: bool, progress: Progress) -> RunOutputs:
    started = time.perf_counter()
    check_writable(job.output, [BUFFER_NAME, PRIMAL_NAME])
    refuse_unsafe_outputs(job, [job.output / BUFFER_NAME, job.output / PRIMAL_NAME])
    check_cameras(job)  # an unknown inspection camera fails here, not after the render
    with progress.stage("load_s", f"loading {job.scene.name}"):
        loaded = load_scene(job)
    if not loaded.selected:
        raise SpecError(
            "no scene parameter is selected: there is nothing to differentiate",
            where=f"{job.path}: parameters",
            hint="'sensaov params JOB' lists every key and why it was left out",
        )
    if loaded.replaced_integrator is not None:
        progress.note(
            f"the scene's '{loaded.replaced_integrator}' integrator renders other light "
            f"transport than the path replay sensaov differentiates (full paths up to "
            f"max_depth {job.render.max_depth}): M is measured on that image"
        )
    scene_spp = loaded.scene_sample_count
    if scene_spp is not None and scene_spp != job.render.spp:
        progress.note(
            f"the scene's sampler asks for {scene_spp} spp; rendering with the job's "
            f"render.spp = {job.render.spp} (both are recorded in the buffer)"
        )
    width, height = loaded.resolution
    progress.note(
        f"{len(loaded.selected)} parameters over {len(loaded.objects)} objects, "
        f"variant {loaded.variant}, {len(job.objectives)} objective(s)"
    )
    objectives = build_objectives(loaded.mi, job.objectives, (height, width), allow_python)
    result = run_adjoint(
        loaded,
        objectives,
        spp=job.render.spp,
        seed=job.render.seed,
        deterministic=job.render.deterministic,
        progress=progress,
    )
    provenance = _provenance(job, loaded, result, progress.timings, time.perf_counter() - started)
    buffer = _make_buffer(job, loaded, result, provenance)
    buffer_path = job.output / BUFFER_NAME
    primal_path = job.output / PRIMAL_NAME
    interrupts.check()  # a stop asked for during a kernel must not end in written files
    with progress.stage("write_s", f"writing {buffer_path.name} and {primal_path.name}"):
        primal = exr_writer(image_channels(result.image), provenance_attributes(provenance))
        try:
            atomic_write_all([(buffer_path, buffer_writer(buffer)), (primal_path, primal)])
        except OSError as exc:
            raise SensaovError(
                f"cannot write outputs: {exc.strerror or exc}", where=str(job.output)
            ) from exc
    return RunOutputs(buffer, buffer_path, primal_path)


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
    )


def _provenance(
    job: JobSpec, loaded: LoadedScene, result: AdjointResult, timings: dict[str, float], wall: float
) -> dict[str, Any]:
    width, height = loaded.resolution
    return {
        **made_by(" ".join(sys.argv)),
        "mitsuba_version": version("mitsuba"),
        "drjit_version": version("drjit"),
        "variant": loaded.variant,
        "libllvm": os.environ.get("DRJIT_LIBLLVM_PATH", ""),
        "python": platform.python_version(),
        "created_utc": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "job_path": str(job.path),
        "job_hash": job.job_hash(),
        "job": job.to_dict(),
        "scene_path": str(job.scene),
        "scene_fingerprint": loaded.fingerprint,
        "scene_args": dict(loaded.scene_args),  # every $name the scene used, as substituted
        "scene_sample_count": loaded.scene_sample_count,  # the scene's spp; the job's renders
        "integrator": loaded.integrator_type,  # the replay integrator that ran
        "scene_integrator_replaced": loaded.replaced_integrator,
        **result.provenance,  # which integrator differentiated what; the self-checks' figures
        "max_depth": job.render.max_depth,
        "spp": job.render.spp,
        "primal_seed": job.render.seed,
        "gradient_seeds": result.grad_seeds,
        "deterministic": result.deterministic,
        "resolution": [width, height],
        "objective_sensor": loaded.sensor.id(),
        "shared_bsdfs": job.parameters.shared,
        "split_bsdfs": {name: list(shapes) for name, shapes in loaded.split.items()},
        "textures": [
            {"key": key, "file": source.file, "converted_from_8bit": source.converted}
            for key, source in loaded.textures.items()
        ],
        "excluded_parameters": len(loaded.excluded),
        "timings_s": dict(timings),
        "wall_time_s": round(wall, 4),
    }
