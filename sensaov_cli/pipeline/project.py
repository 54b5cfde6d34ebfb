"""``sensaov project``: bind a stored buffer to inspection cameras and write layered EXRs.

Reads the buffer, traces primary visibility per camera and paints per-object values: no
derivative is computed here (§3 "Binding"; the deferred-shading half of the paper). Every
picture of a layer saturates at its group's display scale (views/channels.py): one per
(objective, channel) read from the pixels of *every* camera of the job, so each camera's
visibility is traced even when ``--camera`` picks one: farm tasks that each write one camera
derive the very same scales.
"""

from __future__ import annotations

import json
import re
from collections.abc import Mapping
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from sensaov_cli import interrupts
from sensaov_cli.buffer.forward_sidecar import check_belongs, read_forward
from sensaov_cli.buffer.model import (
    STAMP_BUFFER,
    STAMP_JOB,
    SensitivityBuffer,
    buffer_id,
    provenance_id,
    run_version,
    stamp,
)
from sensaov_cli.buffer.npz import read_buffer
from sensaov_cli.buffer.statistics import whole_run
from sensaov_cli.errors import FingerprintMismatch, SensaovError, SpecError, StaleInputError
from sensaov_cli.job.spec import CameraSpec, JobSpec
from sensaov_cli.outputs.atomic import (
    check_writable,
    header_provenance,
    made_by,
    provenance_attributes,
    refuse_unsafe_outputs,
)
from sensaov_cli.outputs.contact_sheets import safe_file_stem, write_fig4_sheet, write_texture_files
from sensaov_cli.outputs.exr import read_exr
from sensaov_cli.outputs.layered_exr import (
    CryptoLayer,
    ScaleGroup,
    SensitivityLayer,
    display_background,
    resolution_metadata,
    with_display,
    write_layered_exr,
)
from sensaov_cli.pipeline.merge import primal_beside
from sensaov_cli.pipeline.run import FORWARD_NAME
from sensaov_cli.progress import Progress
from sensaov_cli.render.loading import LoadedScene, check_job, load_scene, sensor_sizes
from sensaov_cli.render.visibility import (
    TextureProbe,
    objects_without_uv,
    render_beauty,
    texture_probes,
    trace,
)
from sensaov_cli.scene import prepare_scene
from sensaov_cli.views.channels import (
    FOLLOWER,
    REFERENCE,
    ChannelValues,
    DisplayScale,
    ForwardView,
    TransportView,
    channel_values,
    forward_views,
    group_scales,
    paint_pass,
    transport_views,
)
from sensaov_cli.views.coverage import VisibilityPass, ranked
from sensaov_cli.views.texels import (
    FILTERS,
    WRAPS,
    Footprint,
    TexelField,
    TexelPass,
    TextureSampling,
    lookup,
    texel_fields,
    texel_passes,
    texture_footprint,
    texture_keys,
)

DEFAULT_BEAUTY_SPP = 4
PROBE_TOLERANCE = 1e-4  # relative to the texture's largest value; float32 lookups agree to ~1e-6

Scales = dict[tuple[str, str], DisplayScale]  # (camera, scale group) -> its display scale


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
    every = list(job.projected_cameras())
    chosen = _chosen(every, cameras)
    prepared = prepare_scene(job, tuple(every))  # every camera: the shared scales read them all
    check_fingerprint(job, buffer, buffer_path, prepared.fingerprint, force)
    if not force:
        check_buffer_of_job(job, buffer, buffer_path, override="pass --force to project it anyway")
    texel_stage = any(channel.kind == "texel" for channel in job.channels)
    exrs = [f"{camera.name}.exr" for camera in chosen]
    folders = ["textures/"] * texel_stage + ["previews/"] * png
    check_writable(job.output, exrs + folders)
    read = [*job.input_files(), *prepared.files, buffer_path, buffer_path.with_name(FORWARD_NAME)]
    read.append(primal_beside(buffer_path))
    written = [job.output / name for name in exrs]
    refuse_unsafe_outputs(read, written, [job.output / f for f in folders], where=str(job.path))
    passes = channel_values(buffer, job.channels, untrusted=job.views.untrusted)
    forward = forward_layers(job, buffer, buffer_path, progress)  # the objective camera's
    for index, channel in enumerate(job.channels):  # one selecting no texture: refused now
        if channel.kind == "texel":
            texture_keys(buffer, channel, index)
    progress.plan(2 + texel_stage + len(chosen))  # load, visibility, texels, one per view
    with progress.stage("load_s", f"loading {job.scene.name} with {len(every)} camera(s)"):
        loaded = load_scene(prepared, variant=job.variant, parameters=job.parameters)
    check_objects(buffer, loaded, buffer_path)
    _check_views(job, loaded, bool(forward))  # before the first view writes a file
    texels: list[TexelField] = []
    if texel_stage:
        with progress.stage("texels_s", "texel fields and <output>/textures"):
            texels = prepare_texel_fields(job, buffer, loaded)
            if texels:
                write_texture_files(job.output / "textures", texels, buffer_path)
    with progress.stage("visibility_s", f"visibility of {len(every)} camera(s) and scales"):
        traced = {c.name: trace_camera(job, buffer, loaded, c, bool(texels)) for c in every}
        raw = {c.name: _raw_layers(passes, traced[c.name], c, forward, texels) for c in every}
        scales = _scales(job, raw)
    # Not with --force: the scene may have changed since the run (nor is the primal read then).
    reuse = any(camera.objective for camera in chosen) and not force
    reused = run_beauty(buffer, buffer_path, beauty_spp, progress) if reuse else None
    views = []
    for camera in chosen:
        stage = f"view_{camera.name}_s"
        with progress.stage(stage, f"view '{camera.name}'"):
            view = _project_camera(
                job, buffer, buffer_path, loaded, camera, raw[camera.name], scales, png,
                beauty_spp, reused if camera.objective else None,
            )  # fmt: skip
        views.append(replace(view, seconds=progress.timings[stage]))
    return views


# --- which outputs belong together (docs/buffer-format.md, "Identity"): what project, report,
# rank --exr and view refuse, in one line with exit 2, rather than mix two states.

# The job's top-level keys, as `run` reads them; a mismatch names the ones that differ.
_RUN_KEYS = ("scene", "scene_args", "variant", "render", "parameters", "objective_camera",
             "objectives", "forward", "channels")  # fmt: skip


def check_buffer_of_job(
    job: JobSpec, buffer: SensitivityBuffer, path: Path, *, override: str = ""
) -> None:
    """Refuse a buffer that ``run`` made from another version of ``job`` (or another job).

    The same version is the same ``run_version``, or (a job moved beside its scene, or a buffer
    older than ``run_version``) the same values of every key ``run`` reads, paths absolute.
    ``override`` names the command's way past the check, for the hint."""
    if run_version(buffer) == job.run_hash():
        return
    stored = buffer.provenance.get("job")
    differ = _differing(stored, json.loads(json.dumps(job.to_dict())))
    if isinstance(stored, Mapping) and not differ:
        return
    what = f" ({', '.join(differ)} differ)" if differ else " (it records no job)"
    raise StaleInputError(
        f"the buffer was made by another version of {job.path.name}{what}",
        where=str(path),
        hint=f"re-run 'sensaov run {job.path}'" + (f", or {override}" if override else ""),
    )


def check_made_from(
    attributes: Mapping[str, Any],
    buffer: SensitivityBuffer,
    where: str,
    *,
    remake: str,
    job: JobSpec | None = None,
) -> None:
    """Refuse an output (its EXR header or PNG text) not made from ``buffer`` or, given ``job``,
    made by another version of it (other cameras, channels, views)."""
    made = attributes.get(STAMP_BUFFER)
    if made is None:
        said = "records no buffer (an older sensaov made it)"
    elif made != buffer_id(buffer):
        said = f"was made from another buffer ({made}, not {buffer_id(buffer)})"
    elif job is not None and attributes.get(STAMP_JOB) != job.job_hash():
        said = f"was made by another version of {job.path.name}"
    else:
        return
    raise StaleInputError(said, where=where, hint=f"re-run '{remake}'")


def _differing(stored: Any, current: Mapping[str, Any]) -> list[str]:
    """The keys ``run`` reads whose values differ (a transport channel is read by ``run``,
    every other channel only later)."""
    if not isinstance(stored, Mapping):
        return []

    def read_by_run(job: Mapping[str, Any], key: str) -> Any:
        if key == "channels":
            return [c for c in job.get(key) or () if c.get("kind") == "transport"]
        return job.get(key)

    return [key for key in _RUN_KEYS if read_by_run(stored, key) != read_by_run(current, key)]


# --- checks before anything is written --------------------------------------------------------


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


def _chosen(cameras: list[CameraSpec], names: tuple[str, ...]) -> list[CameraSpec]:
    """The cameras named (a name given twice renders once), or all of them."""
    known = {camera.name: camera for camera in cameras}
    unknown = [name for name in names if name not in known]
    if unknown:
        raise SpecError(
            f"no inspection camera named {unknown[0]!r}",
            where="--camera",
            hint=f"cameras of this job: {', '.join(known)}",
        )
    return [known[name] for name in dict.fromkeys(names)] or cameras


def _check_views(job: JobSpec, loaded: LoadedScene, forward: bool) -> None:
    """What a view would refuse, refused before the first one writes its EXR (exit 2 means
    nothing was written): settings over the memory budget, forward layers at another size."""
    sizes = sensor_sizes(loaded)
    check_job(job, sizes)
    objective = next((c.name for c in job.projected_cameras() if c.objective), None)
    if forward and objective is not None and sizes[objective] != loaded.resolution:
        raise SpecError(
            "forward and transport layers are rendered at render.resolution, "
            "but the objective inspection camera has another resolution",
            where=f"inspection_cameras: {objective}",
            hint="leave that camera's resolution null",
        )


# --- forward and transport layers: the objective camera's, from run's sidecar (§4, §7) -------


def forward_layers(
    job: JobSpec, buffer: SensitivityBuffer, buffer_path: Path, progress: Progress
) -> list[SensitivityLayer]:
    """The objective camera's forward and transport layers, each in its display scale group:
    a forward channel alone, a transport entry's layers per objective, a transport channel's
    top objects per (objective, channel)."""
    if not job.wants_forward:
        return []
    if not whole_run(buffer.provenance):
        progress.note(
            "no forward or transport layers: this buffer is a shard, an objective task or a "
            "merge; those are rendered by whole runs only (docs/farm.md)"
        )
        return []
    path = buffer_path.with_name(FORWARD_NAME)
    if not path.exists():  # a FIFO or a folder there is refused by read_forward, by name
        raise SpecError(
            f"the job asks for forward channels but {path.name} is missing",
            where=str(path),
            hint="re-run 'sensaov run' (it writes the buffer and its forward images together)",
        )
    data = read_forward(path)
    check_belongs(data, buffer, path)
    layers = []
    for f in forward_views(buffer, data):
        if f.data is None:
            progress.note(f"warning: no layer forward.{f.name}: Mitsuba failed: {f.failure}")
            continue
        meta = _forward_metadata(f)
        group = ScaleGroup(f"forward/{f.name}")
        layers.append(
            SensitivityLayer("forward", f.name, f.data, meta, kind="forward", group=group)
        )
    for t in transport_views(buffer, data):
        meta = _forward_metadata(t)
        meta.update(
            forward_sum=repr(t.forward_sum),
            reverse=repr(t.reverse),
            duality_residual=repr(t.residual),
            duality_tolerance=repr(t.tolerance),
        )
        group = ScaleGroup(f"{t.objective}/{_transport_group(job, t.source, t.name)}")
        layers.append(SensitivityLayer(
            t.objective, t.name, t.data, meta, kind="transport", group=group,
            duality_agrees=t.agrees,
        ))  # fmt: skip
    return layers


def _transport_group(job: JobSpec, source: str, name: str) -> str:
    """A transport channel's layers share their channel's scale; an entry's has its own."""
    match = re.match(r"channels\[(\d+)\]", source)
    if match and int(match.group(1)) < len(job.channels):
        return job.channels[int(match.group(1))].name
    return name


def _forward_metadata(view: ForwardView | TransportView) -> dict[str, str]:
    """A forward or transport layer's own metadata (the sidecar it came from is the file's
    provenance: ``forward_file``)."""
    return {
        "keys": json.dumps(list(view.keys)),
        "direction": view.direction,
        "seed": str(view.seed),
        "encoding": "none (linear)",
        "unverified": json.dumps(list(view.unverified)),
        "aliases": json.dumps(list(view.aliases)),
    }


# --- texel fields: from the buffer, looked up as the scene's textures are --------------------


def prepare_texel_fields(
    job: JobSpec, buffer: SensitivityBuffer, loaded: LoadedScene
) -> list[TexelField]:
    """Every texel field of the job's texel channels, with the scene's lookup settings."""
    channels = [(i, c) for i, c in enumerate(job.channels) if c.kind == "texel"]
    if not channels:
        return []
    keys = tuple(dict.fromkeys(k for i, c in channels for k in texture_keys(buffer, c, i)))
    probes = texture_probes(loaded.mi, loaded.params, keys, loaded.prepared.bitmap_options)
    samplings = {key: sampling_of(probe) for key, probe in probes.items()}
    no_uv = set(objects_without_uv(loaded.mi, loaded.scene, buffer.objects))
    fields = []
    for field in (f for i, c in channels for f in texel_fields(buffer, c, i, samplings)):
        if missing := sorted(no_uv.intersection(field.record.owners)):
            note = (
                f"{', '.join(missing)} has no UV coordinates: Mitsuba looks the texture up at each "
                "triangle's barycentric (b1, b2), so the field repeats per triangle"
            )
            field = replace(field, notes=(*field.notes, note))
        fields.append(field)
    return fields


def sampling_of(probe: TextureProbe) -> TextureSampling:
    """The filter and wrap whose lookup reproduces the texture's own values at the probes.

    The scene XML's settings are preferred when they match; a texture whose values cannot tell
    the modes apart (a uniform one) keeps the XML's; one no mode reproduces (a spectral
    variant's upsampled colours) keeps them too, with a note saying the lookup is unconfirmed.
    """
    matrix = np.array(probe.to_uv, np.float64)
    stated = (probe.filter, probe.wrap)
    peak = float(np.abs(probe.values).max()) or 1.0
    errors = {}
    for mode in [(f, w) for f in FILTERS for w in WRAPS]:
        got = lookup(probe.texels, probe.uv, TextureSampling(*mode, to_uv=matrix))
        errors[mode] = float(np.abs(got - probe.values).max()) / peak
    matching = [mode for mode, error in errors.items() if error <= PROBE_TOLERANCE]
    if stated in matching:  # confirmed: any doubt the XML match left is settled
        return TextureSampling(*stated, to_uv=matrix)
    if not matching:
        error = min(errors.values())
        note = f"lookup not confirmed against Mitsuba (error {error:.1e}); {probe.note}"
        return TextureSampling(*stated, to_uv=matrix, note=note.rstrip("; "))
    chosen = matching[0]
    return TextureSampling(*chosen, to_uv=matrix, note="filter and wrap read from Mitsuba's lookup")


@dataclass(frozen=True)
class _TexelPanels:
    """One texel field in one camera: Fig. 4's three panels and the layers they become."""

    field: TexelField
    passes: list[TexelPass]
    layers: list[SensitivityLayer]


def _texel_panels(fields: list[TexelField], visibility: VisibilityPass) -> list[_TexelPanels]:
    """Per field, its three panels and their layers. A panel's display scale is shared by every
    texture of its (objective, channel) and every camera; the joint panel's is fixed at 1, its
    meaning (the object's value spread evenly)."""
    result = []
    footprints: dict[tuple[str, str], Footprint] = {}  # one per texture and lookup, not per field
    for field in fields:
        look = (field.record.key, field.sampling.describe())
        if look not in footprints:
            footprints[look] = texture_footprint(field, visibility)
        passes = texel_passes(field, visibility, footprints[look])
        layers = []
        for texel_pass in passes:
            metadata = {
                **texel_pass.metadata,
                "selection": f"texture={field.record.key}",
                "aggregate": "none (per texel component)",
                "weight": field.channel.weight,
                "keys": json.dumps([field.record.key]),
            }
            group = ScaleGroup(
                f"{field.objective}/{field.channel.name}/{texel_pass.panel}",
                REFERENCE,
                1.0 if texel_pass.panel == "joint" else None,
            )
            neutral = texel_pass.neutral
            layers.append(SensitivityLayer(
                field.objective, texel_pass.pass_name, texel_pass.data, metadata, kind="texel",
                group=group, invisible=(), neutral=neutral,
                scale_data=None if neutral is None else np.where(
                    neutral if texel_pass.data.ndim == 2 else neutral[..., None], 0.0,
                    texel_pass.data),
            ))  # fmt: skip
        result.append(_TexelPanels(field, passes, layers))
    return result


# --- each camera's layers and the scales they share --------------------------------------------


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
    """One camera's visibility and sensitivity layers before their display scales are known."""

    visibility: VisibilityPass
    layers: list[SensitivityLayer]
    texel_panels: list[_TexelPanels]


def _raw_layers(
    passes: list[ChannelValues],
    visibility: VisibilityPass,
    camera: CameraSpec,
    forward: list[SensitivityLayer],
    texels: list[TexelField],
) -> _RawLayers:
    layers = [_layer(p, visibility) for p in passes]
    if camera.objective:
        layers += forward  # its size was checked before any view was written (_check_views)
    panels = _texel_panels(texels, visibility)
    layers += [layer for panel in panels for layer in panel.layers]
    return _RawLayers(visibility, layers, panels)


def _layer(values: ChannelValues, visibility: VisibilityPass) -> SensitivityLayer:
    """The encoded pass, in its (objective, channel) display scale group. What every layer of
    the file shares (camera, buffer, visibility samples) is the file's provenance."""
    painted = paint_pass(values, visibility)
    encoding = painted.encoding
    metadata = {
        "selection": values.selection,
        "aggregate": encoding.aggregate,
        "weight": encoding.weight,
        "encoding": encoding.describe(),
        "scale": painted.scale.describe(),
        "keys": json.dumps(list(values.keys)),
        "unverified": json.dumps(list(values.unverified)),
        "estimators": json.dumps(values.estimators),
        **resolution_metadata(values),
    }
    role = FOLLOWER if values.part == "untrusted" else REFERENCE
    return SensitivityLayer(
        values.objective,
        values.pass_name,
        painted.data,
        metadata,
        group=ScaleGroup(values.scale_group, role),
        part=values.part,
        invisible=painted.invisible,
        left_out=values.left_out or {},
        zero_valued=values.zero_valued or {},
        neutral=painted.neutral,
        scale_data=painted.scale_data,
    )


def _scales(job: JobSpec, raw: dict[str, _RawLayers]) -> Scales:
    """Every (camera, scale group)'s display scale, under the job's ``views`` settings."""
    entries = {
        camera: [
            (layer.group.name, layer.group.role or REFERENCE, layer.scale_pixels())
            for layer in found.layers
        ]
        for camera, found in raw.items()
    }
    fixed = {
        layer.group.name: layer.group.fixed
        for found in raw.values()
        for layer in found.layers
        if layer.group.fixed is not None
    }
    return group_scales(
        entries, percentile=job.views.percentile, scope=job.views.scale, fixed=fixed
    )


# --- the beauty under a view ---------------------------------------------------------------------


@dataclass(frozen=True)
class RunBeauty:
    """The run's primal, read once before the views: the objective camera sees exactly what
    ``sensaov run`` rendered, so reading it costs milliseconds where the quick path trace costs
    more than the rest of the view."""

    rgb: np.ndarray  # (H, W, 3) float32
    made: str  # what it is, for the view's ``beauty``


def run_beauty(
    buffer: SensitivityBuffer, buffer_path: Path, spp: int, progress: Progress
) -> RunBeauty | None:
    """The primal written with this very buffer, if it can stand in for a ``spp``-sample beauty:
    none beside the buffer is passed over silently, one unusable in one line saying why."""
    path = primal_beside(buffer_path)
    if spp <= 0 or not path.is_file():
        return None
    try:
        channels, header = read_exr(path, "run's primal image")
    except SensaovError as error:
        progress.note(f"{path.name} not used as the objective camera's beauty: {error}")
        return None
    provenance = header_provenance(header)
    recorded = int(provenance.get("spp") or 0) if provenance is not None else 0
    # A mono variant's primal (Y) is shown grey, as the quick pass shows it.
    rgb = ("R", "G", "B") if {"R", "G", "B"} <= channels.keys() else ("Y", "Y", "Y")
    if provenance is None or provenance_id(provenance) != buffer_id(buffer):
        reason = "it was not written with this buffer"
    elif recorded < spp:
        reason = f"it has {recorded} spp, fewer than the {spp} asked for"
    elif rgb[0] not in channels:
        reason = "it has no R, G, B or Y channels"
    else:
        image = np.stack([channels[name] for name in rgb], axis=-1).astype(np.float32)
        return RunBeauty(image, f"{path.name} of the buffer's run ({recorded} spp)")
    progress.note(f"{path.name} not used as the objective camera's beauty: {reason}")
    return None


# --- one camera's files --------------------------------------------------------------------------


def _project_camera(
    job: JobSpec,
    buffer: SensitivityBuffer,
    buffer_path: Path,
    loaded: LoadedScene,
    camera: CameraSpec,
    raw: _RawLayers,
    scales: Scales,
    png: bool,
    beauty_spp: int,
    reused: RunBeauty | None,
) -> ProjectedView:
    visibility = raw.visibility
    beauty: np.ndarray | None = None  # RGBA, alpha the visibility coverage
    if beauty_spp <= 0:
        made = "none (--beauty-spp 0)"
    elif reused is not None and reused.rgb.shape[:2] == (visibility.height, visibility.width):
        alpha = visibility.coverage_hit[..., None].astype(np.float32)
        beauty, made = np.concatenate([reused.rgb, alpha], axis=2), reused.made
    else:
        sensor = loaded.inspection_sensors[camera.name]
        beauty = render_beauty(loaded, sensor, visibility, beauty_spp, job.render.seed)
        made = f"path trace at {beauty_spp} spp"
    shown = [(layer, scales[(camera.name, layer.group.name)]) for layer in raw.layers]
    background = display_background(visibility.coverage_hit)  # once per view, every layer's
    pairs = [with_display(layer, scale, background) for layer, scale in shown]
    crypto = CryptoLayer(
        "CryptoObject", buffer.objects, visibility.rank_index, visibility.rank_coverage,
        ordered=True,  # coverage.ranked builds them in Cryptomatte's order
    )  # fmt: skip
    material = _material_cryptomatte(visibility, loaded.prepared.materials)
    path = job.output / f"{camera.name}.exr"
    made_from = stamp(buffer, job.job_hash())
    forward = any(layer.kind in ("forward", "transport") for layer in raw.layers)
    attributes = provenance_attributes(
        {
            **made_by("project"),
            "camera": camera.name,
            "vis_spp": camera.vis_spp,
            "beauty_spp": beauty_spp,
            "beauty": made,
            "buffer": str(buffer_path),
            **({"forward_file": str(buffer_path.with_name(FORWARD_NAME))} if forward else {}),
            "buffer_provenance": buffer.provenance,
        },
        relative_to=job.output,
    )
    interrupts.raise_if_stopped()
    write_layered_exr(
        path,
        beauty=beauty,
        cryptomattes=[crypto, material],
        layers=[layer for pair in pairs for layer in pair],
        attributes={**attributes, **made_from},
    )
    previews = _write_previews(job, camera, raw, scales, shown, beauty, made_from) if png else ()
    return ProjectedView(
        camera.name, path, visibility.width, visibility.height, visibility.spp, 0.0, previews, made
    )


def _write_previews(
    job: JobSpec,
    camera: CameraSpec,
    raw: _RawLayers,
    scales: Scales,
    shown: list[tuple[SensitivityLayer, DisplayScale]],
    beauty: np.ndarray | None,
    made_from: dict[str, str],
) -> tuple[Path, ...]:
    """The camera's PNG previews, its Fig. 4 sheets (``<camera>_<objective>_<texture>_fig4.png``
    per texel field) and, last, its manifest (report's index)."""
    from sensaov_cli.outputs.contact_sheets import PreviewFile, write_manifest, write_previews

    folder = job.output / "previews"
    files = write_previews(folder, camera.name, shown, beauty, raw.visibility, made_from)
    for panels in raw.texel_panels:
        field = panels.field
        stem = f"{camera.name}_{field.objective}_{field.channel.name}"
        path = folder / f"{stem}_{safe_file_stem(field.record.key)}_fig4.png"
        values = [scales[(camera.name, layer.group.name)].value for layer in panels.layers]
        write_fig4_sheet(path, camera.name, field, panels.passes, values, made_from)
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
