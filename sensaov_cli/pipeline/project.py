"""``sensaov project``: bind a stored buffer to inspection cameras and write layered EXRs.

Reads the buffer, traces primary visibility per camera and paints per-object values: no
derivative is computed here (§3 "Binding"; the deferred-shading half of the paper). Shared
colour scales come from the object values, so cameras rendered in separate farm tasks agree.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from sensaov_cli import interrupts
from sensaov_cli.buffer.model import SensitivityBuffer
from sensaov_cli.buffer.npz import read_buffer
from sensaov_cli.errors import FingerprintMismatch, SpecError
from sensaov_cli.outputs.atomic import check_writable
from sensaov_cli.outputs.layered_exr import CryptoLayer, SensitivityLayer, write_layered_exr
from sensaov_cli.outputs.overwrite import refuse_unsafe_outputs
from sensaov_cli.outputs.provenance import made_by, provenance_attributes
from sensaov_cli.pipeline import project_texels
from sensaov_cli.pipeline.project_forward import projected_layers
from sensaov_cli.progress import Progress
from sensaov_cli.render.beauty import render_beauty
from sensaov_cli.render.loading import LoadedScene, load_scene
from sensaov_cli.render.scene import prepare_scene
from sensaov_cli.render.visibility import trace
from sensaov_cli.spec.job import CameraSpec, JobSpec
from sensaov_cli.views.channels import ChannelValues, channel_values
from sensaov_cli.views.coverage import VisibilityPass, ranked
from sensaov_cli.views.painting import paint_pass
from sensaov_cli.views.texel_fields import TexelField

DEFAULT_BEAUTY_SPP = 4  # a quick reference for the compositor; it is a full path trace
OBJECTIVE_CAMERA = CameraSpec("objective", objective=True)


@dataclass(frozen=True)
class ProjectedView:
    camera: str
    path: Path
    width: int
    height: int
    vis_spp: int
    seconds: float  # wall time of the view: visibility, beauty, painting, files
    previews: tuple[Path, ...]


def project_job(
    job: JobSpec,
    *,
    buffer_path: Path,
    cameras: tuple[str, ...] = (),
    force: bool = False,
    png: bool = False,
    beauty_spp: int = DEFAULT_BEAUTY_SPP,
    progress: Progress,
) -> list[ProjectedView]:
    buffer = read_buffer(buffer_path)
    chosen = _cameras(job, tuple(dict.fromkeys(cameras)))  # a camera named twice renders once
    prepared = prepare_scene(job, tuple(chosen))
    check_fingerprint(job, buffer, buffer_path, prepared.fingerprint, force)
    check_writable(job.output, [f"{camera.name}.exr" for camera in chosen])
    refuse_unsafe_outputs(
        (*job.input_files(), *prepared.files, buffer_path),
        [job.output / f"{camera.name}.exr" for camera in chosen],
        folders=[job.output / "previews"] if png else [],
        where=str(job.path),
    )
    passes = channel_values(buffer, job.channels)  # camera-independent: computed once
    forward = projected_layers(job, buffer, buffer_path, progress)  # the objective camera's
    project_texels.check_texel_channels(job, buffer)
    with progress.stage("load_s", f"loading {job.scene.name} with {len(chosen)} camera(s)"):
        loaded = load_scene(prepared, variant=job.variant, parameters=job.parameters)
    check_objects(buffer, loaded, buffer_path)
    texels = project_texels.project_fields(job, buffer, loaded, buffer_path, progress)
    views = []
    for camera in chosen:
        stage = f"view_{camera.name}_s"
        with progress.stage(stage, f"view '{camera.name}'"):
            view = _project_camera(
                job, buffer, buffer_path, loaded, camera, passes, png, beauty_spp,
                forward if camera.objective else [], texels,
            )  # fmt: skip
        views.append(replace(view, seconds=progress.timings[stage]))
    return views


def check_fingerprint(
    job: JobSpec, buffer: SensitivityBuffer, path: Path, fingerprint: str, force: bool
) -> None:
    if buffer.provenance.get("scene_fingerprint") != fingerprint and not force:
        raise FingerprintMismatch(
            f"the buffer was made from another version of {job.scene.name} (fingerprint differs)",
            where=str(path),
            hint="re-run 'sensaov run', or pass --force to project it anyway",
        )


def check_objects(buffer: SensitivityBuffer, loaded: LoadedScene, path: Path) -> None:
    missing = sorted(set(buffer.objects) - set(loaded.objects))
    if missing:
        raise FingerprintMismatch(
            f"objects in the buffer are not in the scene: {', '.join(missing[:5])}",
            where=str(path),
            hint="the buffer belongs to another scene",
        )


def _cameras(job: JobSpec, names: tuple[str, ...]) -> list[CameraSpec]:
    """The job's inspection cameras plus the objective camera (once), or the named ones."""
    cameras = list(job.inspection_cameras)
    if not any(camera.objective for camera in cameras):
        cameras.insert(0, OBJECTIVE_CAMERA)
    if not names:
        return cameras
    known = {camera.name: camera for camera in cameras}
    unknown = [name for name in names if name not in known]
    if unknown:
        raise SpecError(
            f"no inspection camera named {unknown[0]!r}",
            where="--camera",
            hint=f"cameras of this job: {', '.join(known)}",
        )
    return [known[name] for name in names]


def _project_camera(
    job: JobSpec,
    buffer: SensitivityBuffer,
    buffer_path: Path,
    loaded: LoadedScene,
    camera: CameraSpec,
    passes: list[ChannelValues],
    png: bool,
    beauty_spp: int,
    forward: list[tuple[SensitivityLayer, float]],
    texels: list[TexelField],
) -> ProjectedView:
    sensor = loaded.inspection_sensors[camera.name]
    visibility = trace(
        loaded.mi,
        loaded.scene,
        sensor,
        buffer.objects,
        camera.vis_spp,
        seed=job.render.seed,
        with_uv=bool(texels),
    )
    beauty = render_beauty(loaded, sensor, visibility, beauty_spp, job.render.seed)
    layers = [_layer(p, visibility, buffer_path, camera) for p in passes]
    layers += [f for f in forward if f[0].data.shape[:2] == (visibility.height, visibility.width)]
    if len(layers) < len(passes) + len(forward):
        raise SpecError(
            "forward and transport layers are rendered at render.resolution, "
            "but the objective inspection camera has another resolution",
            where=f"inspection_cameras: {camera.name}",
            hint="leave that camera's resolution null",
        )
    panels = project_texels.camera_layers(texels, visibility, buffer_path, camera.name)
    layers += [layer for _, texel_layers in panels for layer in texel_layers]
    crypto = CryptoLayer(
        "CryptoObject", buffer.objects, visibility.rank_index, visibility.rank_coverage
    )
    material = _material_cryptomatte(visibility, loaded.prepared.materials)
    path = job.output / f"{camera.name}.exr"
    attributes = _attributes(buffer, buffer_path, camera, beauty_spp)
    interrupts.check()
    write_layered_exr(
        path,
        width=visibility.width,
        height=visibility.height,
        beauty=beauty,
        cryptomattes=[crypto, material],
        layers=[layer for layer, _ in layers],
        attributes=attributes,
    )
    previews: tuple[Path, ...] = ()
    if png:
        from sensaov_cli.outputs.contact_sheets import write_previews

        previews = write_previews(job.output / "previews", camera.name, layers, beauty, visibility)
        previews += project_texels.write_fig4_sheets(
            job.output / "previews", camera.name, texels, panels
        )
    return ProjectedView(
        camera.name, path, visibility.width, visibility.height, visibility.spp, 0.0, previews
    )


def _material_cryptomatte(visibility: VisibilityPass, materials: dict[str, str]) -> CryptoLayer:
    """CryptoMaterial: the object coverage regrouped by the BSDF each object uses."""
    names = sorted({materials.get(obj, obj) for obj in visibility.objects})
    group_of = np.array(
        [names.index(materials.get(obj, obj)) for obj in visibility.objects], np.int32
    )
    coverage = visibility.coverage.regroup(group_of)
    index, amount = ranked(coverage, (visibility.height, visibility.width), visibility.spp)
    return CryptoLayer("CryptoMaterial", tuple(names), index, amount)


def _layer(
    values: ChannelValues, visibility: VisibilityPass, buffer_path: Path, camera: CameraSpec
) -> tuple[SensitivityLayer, float]:
    """The encoded pass and the value at which its preview saturates in this camera."""
    painted = paint_pass(values, visibility)
    encoding = painted.encoding
    metadata = {
        "selection": values.selection,
        "aggregate": encoding.aggregate,
        "weight": encoding.weight,
        "encoding": encoding.describe(),
        "scale": painted.scale.describe(),
        "spp": str(visibility.spp),
        "buffer": str(buffer_path),
        "camera": camera.name,
        "keys": json.dumps(list(values.keys)),
        "unverified": json.dumps(list(values.unverified)),
        "estimators": json.dumps(values.estimators),
        "invisible": json.dumps(list(painted.invisible)),
        "original_name": f"{values.objective}.{values.pass_name}",
    }
    layer = SensitivityLayer(values.objective, values.pass_name, painted.data, metadata)
    return layer, painted.preview_scale


def _attributes(
    buffer: SensitivityBuffer, buffer_path: Path, camera: CameraSpec, beauty_spp: int
) -> dict[str, str]:
    made = {
        **made_by("project"),
        "camera": camera.name,
        "vis_spp": camera.vis_spp,
        "beauty_spp": beauty_spp,
        "buffer": str(buffer_path),
        "buffer_provenance": buffer.provenance,
    }
    return provenance_attributes(made)
