"""What a render will allocate, estimated from its settings before anything is allocated.

A setting too large (a ``vis_spp`` of a million, a 16384² film) would crash the process with no
message: the settings that size memory are multiplied out and checked against the budget
(:func:`sensaov_cli.limits.check_memory`, ``SENSAOV_MEMORY_BUDGET``), a setting over it refused
in one line that names it. The figures are measured upper bounds (peak RSS, CPU backend), not
exact accounting.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING

from sensaov_cli.errors import MemoryBudgetError
from sensaov_cli.job.spec import CameraSpec, JobSpec
from sensaov_cli.limits import check_memory

if TYPE_CHECKING:
    from sensaov_cli.render.loading import LoadedScene

# Bytes per sample of one primal or backward sub-pass, film and wavefront together.
RENDER_BYTES_PER_SAMPLE = 128
RENDER_BYTES_PER_PIXEL_AND_OBJECTIVE = 64  # the adjoint image dM/dI and its copies
SUBPASS_SAMPLES = 1 << 19  # render/adjoint.py's SAMPLES_PER_SUBPASS
# The visibility pass keeps an object index per sample and sorts a copy; texels add UVs.
VISIBILITY_BYTES_PER_SAMPLE = 16
TEXEL_BYTES_PER_SAMPLE = 48
LAYER_BYTES_PER_PIXEL = 64  # each painted layer: float32 channels, its EXR copy, its preview
# Dr.Jit indexes a pass's samples with 32-bit integers.
MAX_SAMPLES = 2**32 - 1


def check_render(
    pixels: int, spp: int, *, objectives: int, setting: str, where: str | None = None
) -> None:
    """The objective camera's passes: a sub-pass's samples and one adjoint per objective."""
    samples = max(pixels, min(pixels * spp, SUBPASS_SAMPLES))
    need = samples * RENDER_BYTES_PER_SAMPLE
    need += pixels * RENDER_BYTES_PER_PIXEL_AND_OBJECTIVE * objectives
    check_memory(need, "the primal and backward passes", setting=setting, where=where)


def check_view(
    pixels: int, vis_spp: int, *, layers: int, texels: bool, setting: str, where: str | None = None
) -> None:
    """One inspection camera: its visibility pass, its beauty sub-passes, its layers."""
    samples = pixels * vis_spp
    if samples > MAX_SAMPLES:
        raise MemoryBudgetError(
            f"{setting}: {samples:,} visibility samples, more than a pass can index (2^32)",
            where=where,
            hint="lower vis_spp or the camera's resolution",
        )
    per_sample = TEXEL_BYTES_PER_SAMPLE if texels else VISIBILITY_BYTES_PER_SAMPLE
    need = samples * per_sample + pixels * LAYER_BYTES_PER_PIXEL * (layers + 2)
    need += max(pixels, SUBPASS_SAMPLES) * RENDER_BYTES_PER_SAMPLE  # the beauty's sub-passes
    check_memory(need, "the view's visibility pass and layers", setting=setting, where=where)


def check_job(job: JobSpec, sizes: Mapping[str, tuple[int, int]] | None = None) -> None:
    """Every setting of ``job`` whose film size is known (``sizes``: the loaded scene's films of
    the inspection cameras)."""
    where = str(job.path)
    if job.render.resolution is not None:
        width, height = job.render.resolution
        check_render(
            width * height,
            job.render.spp,
            objectives=len(job.objectives) * job.render.batches,
            setting=f"render.spp = {job.render.spp} at {width}x{height}",
            where=where,
        )
    texels = any(channel.kind == "texel" for channel in job.channels)
    layers = len(job.objectives) * max(len(job.channels), 1)
    for index, camera in enumerate(job.inspection_cameras):
        size = (sizes or {}).get(camera.name) or _stated_size(job, camera)
        if size is None:
            continue
        key = f"inspection_cameras[{index}].vis_spp = {camera.vis_spp} at {size[0]}x{size[1]}"
        check_view(size[0] * size[1], camera.vis_spp, layers=layers, texels=texels,
                   setting=key, where=where)  # fmt: skip


def sensor_sizes(loaded: LoadedScene) -> dict[str, tuple[int, int]]:
    """Each inspection camera's film size, as the loaded scene has it."""
    films = {name: sensor.film().crop_size() for name, sensor in loaded.inspection_sensors.items()}
    return {name: (int(size[0]), int(size[1])) for name, size in films.items()}


def _stated_size(job: JobSpec, camera: CameraSpec) -> tuple[int, int] | None:
    if camera.resolution is not None:
        return camera.resolution
    return job.render.resolution if camera.objective else None
