"""Save a viewpoint of ``sensaov view`` as a job's camera: printed YAML, or a job copy.

The copy is ``<output>/<job stem>_view.yaml``: the job with every camera saved so far appended
(a later save appends to it), paths rewritten to hold from there. It is validated as a job
before it replaces anything, written atomically, and never over a file the job reads; nothing
is written anywhere else.
"""

from __future__ import annotations

from pathlib import Path

from sensaov_cli.errors import RequestError
from sensaov_cli.job.cameras import CameraSpec
from sensaov_cli.job.job_copy import camera_names, camera_yaml, check_camera_name, job_copy_text
from sensaov_cli.job.load import load_job
from sensaov_cli.job.spec import JobSpec
from sensaov_cli.live.query import ViewRequest
from sensaov_cli.outputs.atomic import atomic_write, check_writable, refuse_unsafe_outputs

SAVED_VIS_SPP = 16  # project's default for an inspection camera


def viewpoint_camera(request: ViewRequest, name: str) -> CameraSpec:
    return CameraSpec(
        name,
        look_at=request.pose.look_at,
        fov=request.pose.fov,
        resolution=(request.width, request.height),
        vis_spp=SAVED_VIS_SPP,
    )


def viewpoint_yaml(request: ViewRequest, name: str) -> str:
    return camera_yaml(viewpoint_camera(request, name))


def copy_path(job: JobSpec) -> Path:
    return job.output / f"{job.path.stem}_view.yaml"


def save_viewpoint(
    job: JobSpec, request: ViewRequest, name: str, buffer: Path, inputs: tuple[Path, ...]
) -> Path:
    """Append the request's camera, named ``name``, to the job's copy; returns the copy."""
    copy = copy_path(job)
    # Before the copy is read as the base of the next save: a copy that is a link to the
    # buffer or a scene file, or a FIFO, is refused, never parsed or waited on.
    refuse_unsafe_outputs(inputs, [copy], where=str(job.path))
    check_writable(job.output, [copy.name])
    base = copy if copy.is_file() else job.path
    if base == copy:  # a copy edited since into no job at all: refused at its line, not parsed
        load_job(copy)
    problem = check_camera_name(name, camera_names(base))
    if problem is not None:
        raise RequestError(problem, hint="choose another name")
    text = job_copy_text(job, base, [viewpoint_camera(request, name)], copy, buffer)

    def write(tmp: Path) -> None:
        tmp.write_text(text)
        load_job(tmp)  # a copy that is not a valid job never replaces anything

    atomic_write(copy, write)
    return copy
