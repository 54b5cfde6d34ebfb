"""Wire ``sensaov validate``: spec -> prepared scene, every camera checked; Mitsuba not loaded."""

from __future__ import annotations

from sensaov_cli.job.spec import JobSpec
from sensaov_cli.render.loading import check_job
from sensaov_cli.scene import PreparedScene, prepare_scene


def validate_job(job: JobSpec) -> PreparedScene:
    """The job's scene prepared as ``run`` and ``project`` prepare it, with every inspection
    camera placed: what they would refuse before rendering is refused here, settings over the
    memory budget included (where the job states the film's size)."""
    prepared = prepare_scene(job, job.inspection_cameras)
    check_job(job)
    return prepared
