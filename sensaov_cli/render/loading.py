"""Load a prepared scene into Mitsuba and select the parameters the buffer stores."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np

from sensaov_cli.buffer.model import ExcludedParam, ParamRecord, TextureSource
from sensaov_cli.errors import SceneError
from sensaov_cli.job.spec import CameraSpec, JobSpec, ParameterSpec
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
    def integrator_type(self) -> str:
        """The plugin name of the replay integrator: "prb", or "prbvolpath" for media."""
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
