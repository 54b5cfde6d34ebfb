"""Load a prepared scene into Mitsuba and select the parameters the buffer stores; what a render
will allocate, estimated from its settings before anything is allocated."""

from __future__ import annotations

from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np

from sensaov_cli.buffer.model import ExcludedParam, ParamRecord, TextureSource
from sensaov_cli.errors import MemoryBudgetError, SceneError
from sensaov_cli.job.spec import CameraSpec, JobSpec, ParameterSpec
from sensaov_cli.limits import check_memory, resident_bytes, size_text
from sensaov_cli.render.runtime import import_mitsuba
from sensaov_cli.render.selection import ownership_of, select_parameters
from sensaov_cli.render.verify.trust import Context
from sensaov_cli.scene import PreparedScene, prepare_scene
from sensaov_cli.scene.source import locate_load_error


@dataclass
class LoadedScene:
    """The live scene plus the plain-data description of its selected parameters."""

    mi: ModuleType
    scene: Any
    params: Any  # mi.SceneParameters of the whole scene; only `selected` get gradients
    sensor: Any
    integrator: Any
    variant: str
    selected: tuple[ParamRecord, ...]  # exactly the records the buffer stores
    excluded: tuple[ExcludedParam, ...]
    textures: dict[str, TextureSource]  # texture parameter key -> its bitmap file
    routes: dict[str, str]  # key -> "prb" (the scene's replay) or "path" (trust.py)
    contexts: dict[str, tuple[Context, ...]]  # key -> the composite BSDFs it sits in (trust.py)
    objects: tuple[str, ...]
    resolution: tuple[int, int]
    inspection_sensors: dict[str, Any]  # inspection camera name -> its own sensor
    prepared: PreparedScene  # what was loaded: the text, files, fingerprint, changes
    # The gradient-enabled leaf the scene holds for each selected key, and the keys of the
    # backward pass that made them (None: a pass makes fresh ones); adjoint.pass_leaves.
    leaves: dict[str, Any] = field(default_factory=dict)
    held_keys: frozenset[str] | None = None

    @property
    def integrator_type(self) -> str:  # the replay's plugin: "prb", or "prbvolpath" for media
        return "prbvolpath" if type(self.integrator).__name__ == "PRBVolpathIntegrator" else "prb"


def load_scene(prepared: PreparedScene, *, variant: str, parameters: ParameterSpec) -> LoadedScene:
    """Load a prepared scene with Mitsuba (``variant``: a job's, e.g. "auto") and select the
    parameters ``parameters`` names."""
    mi = import_mitsuba(variant)
    try:
        with _resolving_from(mi, prepared.search_path):
            scene = mi.load_string(prepared.text, optimize=False)
    except Exception as exc:  # Mitsuba raises plain RuntimeError with a long message
        message, where = locate_load_error(str(exc), prepared.line_sources)
        named = (f for f in prepared.files[1:] if f'"{f.name}"' in message or f'"{f}"' in message)
        culprit = next(named, None)  # a file Mitsuba's message names in quotes
        if culprit is not None:  # a mesh's or an image's own fault: that file is where
            raise SceneError(f"{message} (used at {where})", where=str(culprit)) from exc
        raise SceneError(message, where=where or str(prepared.path)) from exc
    sensors = {sensor.id(): sensor for sensor in scene.sensors()}
    sensor = sensors[prepared.sensor_id]
    ownership = ownership_of(mi, scene, prepared.instances)
    params = mi.traverse(scene)
    sources = {Path(name).name: prepared.path.parent / name for name in prepared.bitmap_files}
    media = None if prepared.integration.replay == "prbvolpath" else prepared.integration.scene_kind
    selection = select_parameters(mi, parameters, params, ownership, sources, media)
    size = sensor.film().crop_size()
    return LoadedScene(
        mi=mi,
        scene=scene,
        params=params,
        sensor=sensor,
        integrator=scene.integrator(),
        variant=mi.variant(),
        selected=selection.selected,
        excluded=selection.excluded,
        textures=selection.textures,
        routes=selection.routes,
        contexts=selection.contexts,
        objects=ownership.objects,
        resolution=(int(size[0]), int(size[1])),
        inspection_sensors={name: sensors[sid] for name, sid in prepared.inspection_ids.items()},
        prepared=prepared,
    )


def refuse_non_finite(loaded: LoadedScene) -> None:
    """A selected parameter holding NaN or an infinity (an EXR texture's texel, say) is bad
    input named by its key and file: the render would fail later, blaming the objective."""
    for info in loaded.selected:
        value = np.asarray(loaded.params[info.key], dtype=np.float64)
        bad = int(np.count_nonzero(~np.isfinite(value)))
        if bad:
            source = loaded.textures.get(info.key)
            raise SceneError(
                f"parameter {info.key!r} holds {bad} NaN or infinite value(s) of {value.size}",
                where=(source and source.file) or str(loaded.prepared.path),
                hint="write finite values, or leave the parameter out of the selection",
            )


def load_job_scene(job: JobSpec, cameras: tuple[CameraSpec, ...] = ()) -> LoadedScene:
    """Prepare and load a job's scene in one call, for scripts, tests and benchmarks."""
    prepared = prepare_scene(job, cameras)
    return load_scene(prepared, variant=job.variant, parameters=job.parameters)


@contextmanager
def _resolving_from(mi: ModuleType, folders: tuple[Path, ...]) -> Iterator[None]:
    """Resolve names still relative in the prepared text against ``folders`` first (as
    load_file would), then restore the process-wide resolver."""
    resolver = mi.file_resolver()
    saved = [str(resolver[i]) for i in range(len(resolver))]
    for folder in reversed(folders):
        resolver.prepend(str(folder))
    try:
        yield
    finally:
        resolver.clear()
        for entry in saved:
            resolver.append(entry)


def assign(loaded: LoadedScene, key: str, array: np.ndarray) -> None:
    """Set a selected parameter to ``array`` (in its recorded shape), for finite differences."""
    loaded.params[key] = value_like(loaded.params[key], array)
    loaded.held_keys = None  # the scene no longer holds that leaf
    loaded.params.update()


def value_like(current: Any, array: np.ndarray) -> Any:
    """``array`` (a parameter's recorded shape) as a Dr.Jit value of ``current``'s type."""
    import drjit as dr

    flat = np.ascontiguousarray(array, dtype=np.float32)
    if dr.is_tensor_v(current):
        return type(current)(flat)
    if dr.size_v(current) == 3:  # a colour: one value per channel
        return type(current)(*[float(v) for v in flat.reshape(-1)])
    return type(current)(flat.reshape(-1))


# --- memory: a setting too large (a vis_spp of a million, a 16384² film) would crash the process
# with no message: the settings that size memory are multiplied out and checked against the
# budget (limits.check_memory, SENSAOV_MEMORY_BUDGET), a setting over it refused in one line
# that names it. The figures are measured upper bounds (peak RSS, CPU backend), not exact.

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
# Bytes per selected parameter component (a texel's channel counts one), measured as peak RSS
# over a tiny texture's run (a 512² and a 1024² RGB texture, 1-4 objectives, 1-16 batches; CPU
# backend) and rounded up. One batch: the scene's value, Dr.Jit's gradient leaf and its copy to
# numpy, the self-checks'. Several: each batch keeps its gradients per objective (and Dr.Jit
# holds its pass's arrays) until the float64 mean and the statistics are taken.
GRADIENT_BYTES = 48
GRADIENT_BYTES_PER_OBJECTIVE = 8
BATCHED_GRADIENT_BYTES = 64  # more than one batch: the float64 mean and its statistics
BATCH_GRADIENT_BYTES = 36
BATCH_GRADIENT_BYTES_PER_OBJECTIVE = 4


def check_render(
    pixels: int, spp: int, *, objectives: int, setting: str, where: str | None = None
) -> None:
    """The objective camera's passes: a sub-pass's samples and one adjoint per objective."""
    need = render_bytes(pixels, spp, objectives=objectives)
    check_memory(need, "the primal and backward passes", setting=setting, where=where)


def render_bytes(pixels: int, spp: int, *, objectives: int) -> int:
    """What the objective camera's passes allocate: a sub-pass's samples, the adjoint images."""
    samples = max(pixels, min(pixels * spp, SUBPASS_SAMPLES))
    return (
        samples * RENDER_BYTES_PER_SAMPLE
        + pixels * RENDER_BYTES_PER_PIXEL_AND_OBJECTIVE * objectives
    )


def gradient_bytes(components: int, *, objectives: int, batches: int) -> int:
    """What the gradients of ``components`` parameter components take in a run of ``objectives``
    objectives in ``batches`` batches, at their peak (module constants: measured)."""
    per = GRADIENT_BYTES + GRADIENT_BYTES_PER_OBJECTIVE * objectives
    if batches > 1:
        per = BATCHED_GRADIENT_BYTES + GRADIENT_BYTES_PER_OBJECTIVE * objectives
        per += batches * (BATCH_GRADIENT_BYTES + BATCH_GRADIENT_BYTES_PER_OBJECTIVE * objectives)
    return components * per


def check_gradients(
    selected: tuple[ParamRecord, ...],
    *,
    objectives: int,
    batches: int,
    passes: int,
    where: str | None = None,
) -> None:
    """The selected parameters' gradients (a large texture's dominate) with the ``passes``'
    bytes (:func:`render_bytes`) on top of what the process holds, before any pass runs; the
    refusal names the largest parameter and what to change."""
    sizes = {info.key: int(np.prod(info.shape, dtype=np.int64)) for info in selected}
    components = sum(sizes.values())
    need = gradient_bytes(components, objectives=objectives, batches=batches)
    held = resident_bytes() + passes  # the renderer, the loaded scene, then the passes' arrays
    largest = max(sizes, key=sizes.__getitem__, default=None)
    named = ""
    if largest is not None:
        shape = "x".join(map(str, next(i.shape for i in selected if i.key == largest)))
        named = f"; the largest, {largest!r}, has {sizes[largest]:,} ({shape})"
    check_memory(
        need + held,
        f"the gradients of {components:,} parameter components{named}, for {objectives} "
        f"objective(s) in {batches} batch(es) ({size_text(need)}), beside the "
        f"{size_text(held)} the process holds and its passes take,",
        setting="parameters",
        where=where,
        hint="leave large textures out (parameters: exclude), or use fewer render.batches or "
        "objectives",
    )


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
            objectives=len(job.objectives) * job.render.batch_count,
            setting=f"render.spp = {job.render.spp} at {width}x{height}",
            where=where,
        )
    texels = any(channel.kind == "texel" for channel in job.channels)
    layers = len(job.objectives) * max(len(job.channels), 1)
    for index, camera in enumerate(job.inspection_cameras):
        size = (sizes or {}).get(camera.name) or camera.resolution
        if size is None and camera.objective:
            size = job.render.resolution
        if size is None:
            continue
        key = f"inspection_cameras[{index}].vis_spp = {camera.vis_spp} at {size[0]}x{size[1]}"
        check_view(size[0] * size[1], camera.vis_spp, layers=layers, texels=texels,
                   setting=key, where=where)  # fmt: skip


def sensor_sizes(loaded: LoadedScene) -> dict[str, tuple[int, int]]:
    films = {name: sensor.film().crop_size() for name, sensor in loaded.inspection_sensors.items()}
    return {name: (int(size[0]), int(size[1])) for name, size in films.items()}
