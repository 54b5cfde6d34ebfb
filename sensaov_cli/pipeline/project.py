"""``sensaov project``: bind a stored buffer to inspection cameras and write layered EXRs.

Reads the buffer, traces primary visibility per camera and paints per-object values: no
derivative is computed here (§3 "Binding"; the deferred-shading half of the paper). Every
picture of a layer saturates at its group's display scale (views/display_scale.py): one per
(objective, channel) read from the pixels of *every* camera of the job, so each camera's
visibility is traced even when ``--camera`` picks one (primary rays only, a fraction of a view's
cost): farm tasks that each write one camera derive the very same scales.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from sensaov_cli import interrupts
from sensaov_cli.buffer.identity import stamp
from sensaov_cli.buffer.model import SensitivityBuffer
from sensaov_cli.buffer.npz import read_buffer
from sensaov_cli.errors import FingerprintMismatch, SpecError
from sensaov_cli.job.spec import CameraSpec, JobSpec
from sensaov_cli.outputs.atomic import check_writable, refuse_unsafe_outputs
from sensaov_cli.outputs.display_layers import display_background, scale_of, with_display
from sensaov_cli.outputs.layered_exr import CryptoLayer, SensitivityLayer, write_layered_exr
from sensaov_cli.outputs.provenance import made_by, provenance_attributes
from sensaov_cli.pipeline import project_texels
from sensaov_cli.pipeline.consistency import check_buffer_of_job
from sensaov_cli.pipeline.merge import primal_beside
from sensaov_cli.pipeline.project_beauty import RunBeauty, run_beauty, view_beauty
from sensaov_cli.pipeline.project_forward import projected_layers
from sensaov_cli.pipeline.run import FORWARD_NAME
from sensaov_cli.progress import Progress
from sensaov_cli.render.loading import LoadedScene, load_scene
from sensaov_cli.render.memory import check_job, sensor_sizes
from sensaov_cli.render.visibility import trace
from sensaov_cli.scene import prepare_scene
from sensaov_cli.views.channels import ChannelValues, channel_values
from sensaov_cli.views.coverage import VisibilityPass, ranked
from sensaov_cli.views.display_scale import (
    FOLLOWER,
    REFERENCE,
    DisplayScale,
    group_scales,
    signed_pixels,
)
from sensaov_cli.views.painting import paint_pass
from sensaov_cli.views.texel_fields import TexelField
from sensaov_cli.views.texel_passes import TexelPass

# The quick pass's spp: a reference for the compositor, and a full path trace. The objective
# camera shows run's own primal instead when it can (project_beauty.py).
DEFAULT_BEAUTY_SPP = 4


@dataclass(frozen=True)
class ProjectedView:
    camera: str
    path: Path
    width: int
    height: int
    vis_spp: int
    seconds: float  # wall time of the view: beauty, display layers, files (not visibility)
    previews: tuple[Path, ...]
    beauty: str = ""  # what the beauty is: run's primal, a quick trace at N spp, or none


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
    every = _cameras(job, ())
    chosen = _cameras(job, tuple(dict.fromkeys(cameras)))  # a camera named twice renders once
    prepared = prepare_scene(job, tuple(every))  # every camera: the shared scales read them all
    check_fingerprint(job, buffer, buffer_path, prepared.fingerprint, force)
    if not force:
        check_buffer_of_job(job, buffer, buffer_path, override="pass --force to project it anyway")
    texel_folder = ["textures/"] if any(c.kind == "texel" for c in job.channels) else []
    folders = texel_folder + ["previews/"] * png
    check_writable(job.output, [f"{camera.name}.exr" for camera in chosen] + folders)
    refuse_unsafe_outputs(
        (
            *job.input_files(),
            *prepared.files,
            buffer_path,
            buffer_path.with_name(FORWARD_NAME),
            primal_beside(buffer_path),
        ),  # fmt: skip
        [job.output / f"{camera.name}.exr" for camera in chosen],
        folders=[job.output / folder for folder in folders],
        where=str(job.path),
    )
    passes = channel_values(buffer, job.channels, untrusted=job.views.untrusted)
    forward = projected_layers(job, buffer, buffer_path, progress)  # the objective camera's
    project_texels.check_texel_channels(job, buffer)
    texel_stage = any(channel.kind == "texel" for channel in job.channels)
    progress.plan(2 + texel_stage + len(chosen))  # load, visibility, texels, one per view
    with progress.stage("load_s", f"loading {job.scene.name} with {len(every)} camera(s)"):
        loaded = load_scene(prepared, variant=job.variant, parameters=job.parameters)
    check_objects(buffer, loaded, buffer_path)
    _check_views(job, every, loaded, bool(forward))  # before the first view writes a file
    texels = project_texels.project_fields(job, buffer, loaded, buffer_path, progress)
    with progress.stage("visibility_s", f"visibility of {len(every)} camera(s) and scales"):
        traced = {c.name: trace_camera(job, buffer, loaded, c, bool(texels)) for c in every}
        raw = {
            c.name: _raw_layers(passes, traced[c.name], buffer_path, c, forward, texels)
            for c in every
        }
        scales = _scales(job, raw)
    objective_chosen = any(camera.objective for camera in chosen)
    # Not with --force: the scene may have changed since the run (nor is the primal read then).
    reuse = objective_chosen and not force
    reused = run_beauty(buffer, buffer_path, beauty_spp, progress) if reuse else None
    views = []
    for camera in chosen:
        stage = f"view_{camera.name}_s"
        with progress.stage(stage, f"view '{camera.name}'"):
            view = _project_camera(
                job, buffer, buffer_path, loaded, camera, traced[camera.name],
                raw[camera.name], scales, png, beauty_spp, reused if camera.objective else None,
            )  # fmt: skip
        views.append(replace(view, seconds=progress.timings[stage]))
    return views


def _check_views(
    job: JobSpec, cameras: list[CameraSpec], loaded: LoadedScene, forward: bool
) -> None:
    """What a view would refuse, refused before the first one writes its EXR (exit 2 means
    nothing was written): settings over the memory budget, forward layers at another size."""
    sizes = sensor_sizes(loaded)
    check_job(job, sizes)
    objective = next((c.name for c in cameras if c.objective), None)
    if forward and objective is not None and sizes[objective] != loaded.resolution:
        raise SpecError(
            "forward and transport layers are rendered at render.resolution, "
            "but the objective inspection camera has another resolution",
            where=f"inspection_cameras: {objective}",
            hint="leave that camera's resolution null",
        )


def trace_camera(
    job: JobSpec, buffer: SensitivityBuffer, loaded: LoadedScene, camera: CameraSpec, uv: bool
) -> VisibilityPass:
    """``camera``'s visibility pass as ``project`` paints and scales it (``view`` reuses it)."""
    sensor = loaded.inspection_sensors[camera.name]
    return trace(
        loaded.mi, loaded.scene, sensor, buffer.objects, camera.vis_spp,
        seed=job.render.seed, with_uv=uv,
    )  # fmt: skip


@dataclass(frozen=True)
class _RawLayers:
    """One camera's sensitivity layers before their display scales are known."""

    layers: list[SensitivityLayer]
    fields: list[TexelField]
    texel_panels: list[tuple[list[TexelPass], list[SensitivityLayer]]]  # per field


def _raw_layers(
    passes: list[ChannelValues],
    visibility: VisibilityPass,
    buffer_path: Path,
    camera: CameraSpec,
    forward: list[SensitivityLayer],
    texels: list[TexelField],
) -> _RawLayers:
    layers = [_layer(p, visibility, buffer_path, camera) for p in passes]
    if camera.objective:
        layers += forward  # its size was checked before any view was written (_check_views)
    panels = project_texels.camera_layers(texels, visibility, buffer_path, camera.name)
    layers += [layer for _, texel_layers in panels for layer in texel_layers]
    return _RawLayers(layers, texels, panels)


def _scales(job: JobSpec, raw: dict[str, _RawLayers]) -> dict[tuple[str, str], DisplayScale]:
    """Every (camera, scale group)'s display scale, under the job's ``views`` settings."""
    entries = {
        camera: [
            (
                layer.metadata["scale_group"],
                layer.metadata.get("scale_role", REFERENCE),
                signed_pixels(layer.data, layer.metadata.get("kind", "")),
            )
            for layer in found.layers
        ]  # fmt: skip
        for camera, found in raw.items()
    }
    fixed = {
        layer.metadata["scale_group"]: float(layer.metadata["scale_fixed"])
        for found in raw.values()
        for layer in found.layers
        if "scale_fixed" in layer.metadata
    }
    return group_scales(
        entries, percentile=job.views.percentile, scope=job.views.scale, fixed=fixed
    )


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
    cameras = list(job.projected_cameras())
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
    visibility: VisibilityPass,
    raw: _RawLayers,
    scales: dict[tuple[str, str], DisplayScale],
    png: bool,
    beauty_spp: int,
    reused: RunBeauty | None,
) -> ProjectedView:
    sensor = loaded.inspection_sensors[camera.name]
    beauty, made = view_beauty(loaded, sensor, visibility, beauty_spp, job.render.seed, reused)
    shown = [(layer, scale_of(scales, camera.name, layer)) for layer in raw.layers]
    background = display_background(visibility.coverage_hit)  # once per view, every layer's
    pairs = [with_display(layer, scale, background) for layer, scale in shown]
    crypto = CryptoLayer(
        "CryptoObject", buffer.objects, visibility.rank_index, visibility.rank_coverage,
        ordered=True,  # coverage.ranked builds them in Cryptomatte's order
    )  # fmt: skip
    material = _material_cryptomatte(visibility, loaded.prepared.materials)
    path = job.output / f"{camera.name}.exr"
    made_from = stamp(buffer, job.job_hash())
    attributes = {**_attributes(buffer, buffer_path, camera, beauty_spp, made), **made_from}
    interrupts.check()
    write_layered_exr(
        path,
        width=visibility.width,
        height=visibility.height,
        beauty=beauty,
        cryptomattes=[crypto, material],
        layers=[layer for pair in pairs for layer in pair],
        attributes=attributes,
    )
    previews: tuple[Path, ...] = ()
    if png:
        previews = _write_previews(job, camera, raw, scales, shown, beauty, visibility, made_from)
    return ProjectedView(
        camera.name, path, visibility.width, visibility.height, visibility.spp, 0.0, previews, made
    )


def _write_previews(
    job: JobSpec,
    camera: CameraSpec,
    raw: _RawLayers,
    scales: dict[tuple[str, str], DisplayScale],
    shown: list[tuple[SensitivityLayer, DisplayScale]],
    beauty: np.ndarray | None,
    visibility: VisibilityPass,
    made_from: dict[str, str],
) -> tuple[Path, ...]:
    """The camera's PNG previews, its Fig. 4 sheets and, last, its manifest (report's index)."""
    from sensaov_cli.outputs.contact_sheets import PreviewFile, write_manifest, write_previews

    folder = job.output / "previews"
    files = write_previews(folder, camera.name, shown, beauty, visibility, made_from)
    for path, field in project_texels.write_fig4_sheets(
        folder, camera.name, raw.fields, raw.texel_panels, scales, made_from
    ):
        files.append(PreviewFile(path.name, "fig4", field.objective, field.record.key))
    manifest = write_manifest(folder, camera.name, files, made_from)
    return (*(folder / f.file for f in files), manifest)


def _material_cryptomatte(visibility: VisibilityPass, materials: dict[str, str]) -> CryptoLayer:
    """CryptoMaterial: the object coverage regrouped by the BSDF each object uses."""
    names = sorted({materials.get(obj, obj) for obj in visibility.objects})
    group_of = np.array(
        [names.index(materials.get(obj, obj)) for obj in visibility.objects], np.int32
    )
    coverage = visibility.coverage.regroup(group_of)
    index, amount = ranked(coverage, (visibility.height, visibility.width), visibility.spp)
    return CryptoLayer("CryptoMaterial", tuple(names), index, amount, ordered=True)


def _layer(
    values: ChannelValues, visibility: VisibilityPass, buffer_path: Path, camera: CameraSpec
) -> SensitivityLayer:
    """The encoded pass, in its (objective, channel) display scale group."""
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
        "part": values.part,
        "left_out": json.dumps(values.left_out or {}),
        "zero_valued": json.dumps(values.zero_valued or {}),
        "scale_group": values.scale_group,
        "scale_role": FOLLOWER if values.part == "untrusted" else REFERENCE,
    }
    return SensitivityLayer(values.objective, values.pass_name, painted.data, metadata)


def _attributes(
    buffer: SensitivityBuffer, buffer_path: Path, camera: CameraSpec, beauty_spp: int, beauty: str
) -> dict[str, str]:
    made = {
        **made_by("project"),
        "camera": camera.name,
        "vis_spp": camera.vis_spp,
        "beauty_spp": beauty_spp,
        "beauty": beauty,
        "buffer": str(buffer_path),
        "buffer_provenance": buffer.provenance,
    }
    return provenance_attributes(made)
