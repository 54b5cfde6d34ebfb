"""Load a job's scene and decide which parameters enter the sensitivity buffer.

Mitsuba types stay inside this stage and the adjoint stage; what leaves is the buffer's own
:class:`~sensaov_cli.buffer.model.ParamRecord` for each selected parameter (plain data) next to
the live scene objects the adjoint needs.
"""

from __future__ import annotations

import fnmatch
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np

from sensaov_cli.buffer.model import ExcludedParam, ParamRecord, TextureSource
from sensaov_cli.errors import SceneError
from sensaov_cli.render.runtime import import_mitsuba
from sensaov_cli.render.scene_xml import files_fingerprint, prepare_scene_xml
from sensaov_cli.render.texture_modes import bitmap_options
from sensaov_cli.render.trust import verification_status
from sensaov_cli.spec.model import JobSpec

# The slot a parameter fills, whatever its storage ("white.reflectance.value" and
# "wall.bsdf.reflectance.data" are both reflectance): the paper's horizontal cut.
TYPE_ALIASES = {
    "alpha": "roughness",
    "alpha_u": "roughness",
    "alpha_v": "roughness",
    "diffuse_reflectance": "reflectance",
    "base_color": "reflectance",
    "specular_reflectance": "specular",
    "specular_transmittance": "transmittance",
    "intensity": "radiance",
    "irradiance": "radiance",
    "int_ior": "eta",
    "ext_ior": "eta",
}
# Emitter slots that scale what it emits: an envmap's ``data`` is its radiance map and
# ``scale`` multiplies it; a spot or projector light's ``texture`` modulates its intensity.
_EMITTER_SLOT_TYPES = {"data": "radiance", "scale": "radiance", "texture": "radiance"}
# Spectral variants store an RGB colour (a value, a bitmap's texels) as the coefficients of
# its spectral upsampling, not as the colour: θ·∂M/∂θ over them is no proportional change.
SPECTRAL_COEFFICIENTS_NOTE = (
    "in spectral variants Mitsuba stores this colour as spectral-upsampling coefficients, so "
    "its scores are not a proportional change of the colour; use an RGB variant for colours"
)
# Mitsuba class names of the common plugins -> the plugin names users write in XML.
PLUGIN_NAMES = {
    "SmoothDiffuse": "diffuse",
    "SmoothPlastic": "plastic",
    "SmoothDielectric": "dielectric",
    "SmoothConductor": "conductor",
    "ThinDielectric": "thindielectric",
    "BlendBSDF": "blendbsdf",
    "MaskBSDF": "mask",
    "Principled": "principled",
    "AreaLight": "area",
    "PointLight": "point",
    "SpotLight": "spot",
    "ConstantBackgroundEmitter": "constant",
    "EnvironmentMapEmitter": "envmap",
    "DirectionalEmitter": "directional",
}
GEOMETRY_FIELDS = ("to_world", "position", "direction", "faces")


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
    objects: tuple[str, ...]
    fingerprint: str
    resolution: tuple[int, int]
    split: dict[str, tuple[str, ...]]
    inspection_sensors: dict[str, Any]  # inspection camera name -> its own sensor
    materials: dict[str, str]  # object -> material (BSDF id) name, for the material Cryptomatte
    scene_args: dict[str, str]  # every $name the scene used and the value it got
    scene_sample_count: int | None  # the scene's own spp (a default: the job's spp renders)
    replaced_integrator: str | None  # the scene's integrator when it renders other transport
    # bitmap file base name -> (filter_type, wrap_mode, note), for texel fields
    bitmap_options: dict[str, tuple[str, str, str]] = field(default_factory=dict)

    @property
    def integrator_type(self) -> str:
        """The plugin name of the replay integrator: "prb", or "prbvolpath" for media."""
        return "prbvolpath" if type(self.integrator).__name__ == "PRBVolpathIntegrator" else "prb"


def load_scene(job: JobSpec, *, with_inspection_cameras: bool = False) -> LoadedScene:
    """Load the job's scene; with ``with_inspection_cameras`` every inspection camera too."""
    mi = import_mitsuba(job.variant)
    prepared = prepare_scene_xml(
        job.scene,
        max_depth=job.render.max_depth,
        camera=job.objective_camera,
        resolution=job.render.resolution,
        shared=job.parameters.shared,
        inspection=job.inspection_cameras if with_inspection_cameras else (),
        scene_args=job.scene_args,
    )
    try:
        with _resolving_from(mi, prepared.search_path):
            scene = mi.load_string(prepared.text, optimize=False)
    except Exception as exc:  # Mitsuba raises plain RuntimeError with a long message
        message, where = prepared.locate(str(exc))
        raise SceneError(message, where=where or str(job.scene)) from exc
    sensors = {sensor.id(): sensor for sensor in scene.sensors()}
    sensor = sensors[prepared.sensor_id]
    ownership = _ownership(mi, scene, prepared.instances)
    params = mi.traverse(scene)
    sources = {Path(name).name: job.scene.parent / name for name in prepared.bitmap_files}
    selected, excluded, textures = _select(mi, job, params, ownership, sources)
    size = sensor.film().crop_size()
    return LoadedScene(
        mi=mi,
        scene=scene,
        params=params,
        sensor=sensor,
        integrator=scene.integrator(),
        variant=mi.variant(),
        selected=selected,
        excluded=excluded,
        textures=textures,
        objects=ownership.objects,
        fingerprint=files_fingerprint(prepared.files, job.scene_args, job.scene.parent),
        resolution=(int(size[0]), int(size[1])),
        split=prepared.split,
        inspection_sensors={name: sensors[sid] for name, sid in prepared.inspection_ids.items()},
        materials=prepared.materials,
        scene_args={name: arg.value for name, arg in prepared.scene_args.items()},
        scene_sample_count=prepared.sample_count,
        replaced_integrator=prepared.replaced_integrator,
        bitmap_options=bitmap_options(prepared.text),
    )


@contextmanager
def _resolving_from(mi: ModuleType, folders: tuple[Path, ...]) -> Iterator[None]:
    """Resolve names still relative in the prepared text against ``folders`` first (the main
    file's ``<path>`` folders and its own folder, as load_file would), then restore the
    process-wide resolver (tests and the bench load many scenes in one process)."""
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


@dataclass(frozen=True)
class _Ownership:
    """Which objects own each scene node, by node identity (never by key strings: key names
    depend on declaration order). ``nodes`` keeps the nodes alive, so their ids stay valid."""

    objects: tuple[str, ...]
    owners: dict[int, tuple[str, ...]]  # id(node) -> owning objects, sorted
    nodes: tuple[Any, ...]

    def of(self, node: Any) -> tuple[str, ...]:
        return self.owners.get(id(node), ())


def _ownership(mi: ModuleType, scene: Any, instances: Mapping[str, str]) -> _Ownership:
    """Every object (shape, instance, or emitter not attached to a shape) and the nodes it owns.

    An instance owns its shapegroup's shapes, BSDFs and textures (``instances`` maps instance
    ids to shapegroup ids, from the XML: Mitsuba exposes no link), so a BSDF used only inside
    a shapegroup belongs to every instance of it.
    """
    groups = _shapegroups(mi, scene)
    owned: dict[str, list[Any]] = {}
    for index, shape in enumerate(scene.shapes()):
        nodes = list(mi.traverse(shape).hierarchy)
        group = groups.get(instances.get(shape.id(), ""))
        if group is not None:
            nodes += list(mi.traverse(group).hierarchy)
        owned[shape.id() or f"shape_{index}"] = nodes
    for index, emitter in enumerate(scene.emitters()):
        if emitter.get_shape() is None:
            owned[emitter.id() or f"emitter_{index}"] = list(mi.traverse(emitter).hierarchy)
    owners: dict[int, set[str]] = {}
    for name, nodes in owned.items():
        for node in nodes:
            owners.setdefault(id(node), set()).add(name)
    alive = tuple(node for nodes in owned.values() for node in nodes)
    return _Ownership(
        tuple(sorted(owned)), {key: tuple(sorted(v)) for key, v in owners.items()}, alive
    )


def _shapegroups(mi: ModuleType, scene: Any) -> dict[str, Any]:
    """Shapegroup nodes by id (they are not shapes of the scene, only parents in its graph)."""
    hierarchy = mi.traverse(scene).hierarchy
    return {
        node.id(): node
        for node in hierarchy
        if isinstance(node, mi.Shape) and node.class_name() == "ShapeGroupPlugin"
    }


def _select(
    mi: ModuleType,
    job: JobSpec,
    params: Any,
    ownership: _Ownership,
    sources: dict[str, Path],
) -> tuple[tuple[ParamRecord, ...], tuple[ExcludedParam, ...], dict[str, TextureSource]]:
    selected, excluded, textures = [], [], {}
    for key in params.keys():
        _, _, node, flags = params.properties[key]
        reason = _exclusion_reason(mi, job, key, params[key], node, flags)
        owners = ownership.of(node) if reason is None else ()
        if reason is None and not owners:
            reason = "owned by no object in the scene"
        if reason is None:
            record = _describe(mi, key, params, owners)
            selected.append(record)
            if record.is_texture:
                textures[key] = _texture_source(mi, params.properties[key][2], sources)
        else:
            excluded.append(ExcludedParam(key, reason))
    return tuple(selected), tuple(excluded), textures


def _explicitly_included(key: str, include: tuple[str, ...]) -> bool:
    """Geometry needs a glob that names the field itself (``*.to_world``), not just ``*``."""
    return any(
        fnmatch.fnmatchcase(key, glob) and not any(c in glob.rsplit(".", 1)[-1] for c in "*?[")
        for glob in include
    )


def _exclusion_reason(
    mi: ModuleType, job: JobSpec, key: str, value: Any, node: Any, flags: int
) -> str | None:
    import drjit as dr

    if flags & int(mi.ParamFlags.NonDifferentiable):
        return "not differentiable (Mitsuba flags it NonDifferentiable)"
    if not (dr.is_array_v(value) and dr.is_diff_v(value) and dr.is_float_v(value)):
        return "not a differentiable floating-point value"
    if isinstance(node, mi.Sensor | mi.Film | mi.Sampler):
        return "camera parameter (prb gives cameras no gradient)"
    field = key.rsplit(".", 1)[-1]
    is_geometry = (
        isinstance(node, mi.Shape) or field in GEOMETRY_FIELDS or field.startswith("vertex_")
    )
    if is_geometry and not _explicitly_included(key, job.parameters.include):
        return "geometry (excluded by default; include it by naming the field, e.g. '*.to_world')"
    if not any(fnmatch.fnmatchcase(key, glob) for glob in job.parameters.include):
        return "not matched by parameters.include"
    for glob in job.parameters.exclude:
        if fnmatch.fnmatchcase(key, glob):
            return f"excluded by parameters.exclude {glob!r}"
    return None


def _describe(mi: ModuleType, key: str, params: Any, owners: tuple[str, ...]) -> ParamRecord:
    _, _, node, flags = params.properties[key]
    parts = key.split(".")
    is_texture_node = isinstance(node, mi.Texture)
    slot, holder = _slot_and_holder(mi, parts, node, params.hierarchy)
    plugin = _plugin_name(holder)
    ptype = _EMITTER_SLOT_TYPES.get(slot, slot) if isinstance(holder, mi.Emitter) else slot
    ptype = TYPE_ALIASES.get(ptype, ptype)
    is_texture = is_texture_node and parts[-1] == "data"
    trust, note = verification_status(plugin, ptype)
    shape = value_shape(np.asarray(params[key]))
    if is_texture_node and "spectral" in mi.variant() and shape[-1:] == (3,):
        trust, note = "unverified", SPECTRAL_COEFFICIENTS_NOTE
    flag_names = ("discontinuous",) if flags & int(mi.ParamFlags.Discontinuous) else ()
    return ParamRecord(
        key=key,
        type=ptype,
        owners=owners,
        shape=shape,
        is_texture=is_texture,
        plugin=plugin,
        flags=flag_names,
        trust=trust,
        note=note,
    )


def _slot_and_holder(
    mi: ModuleType, parts: list[str], node: Any, hierarchy: Any
) -> tuple[str, Any]:
    """The slot a parameter fills in the plugin that is not a texture (or volume), and that plugin.

    A texture's parameters take the slot of the outermost texture: in
    ``glaze.roughness.color0.value`` the uniform ``color0`` sits in a checkerboard that fills
    the BSDF's ``roughness``, so its type is roughness, whatever the nesting.
    """
    levels = 0
    holder = node
    while isinstance(holder, mi.Texture | mi.Volume):  # a medium's albedo is a volume
        levels += 1
        parent = hierarchy.get(holder)
        if parent is None:
            break
        holder = parent[0]
    if levels == 0 or len(parts) <= levels:
        return parts[-1], node
    return parts[-1 - levels], holder


def value_shape(array: Any) -> tuple[int, ...]:
    """The shape a value is stored with: colours (3, 1) in Dr.Jit become (3,)."""
    shape = tuple(int(n) for n in array.shape)
    return shape[:1] if len(shape) == 2 and shape[1] == 1 else shape


def _plugin_name(node: Any) -> str:
    name = node.class_name() if node is not None else "unknown"
    return PLUGIN_NAMES.get(name, name.lower())


def _texture_source(mi: ModuleType, node: Any, sources: dict[str, Path]) -> TextureSource:
    """The file behind a bitmap texture, and whether it was stored as 8-bit integers."""
    import re

    # A bitmap texture prints the base name of its file; the XML pass knows the full paths.
    match = re.search(r'name = "([^"]*)"', str(node))
    path = sources.get(match.group(1)) if match else None
    if path is None or not path.is_file():
        return TextureSource(match.group(1) if match else None, converted=False)
    converted = mi.Bitmap(str(path)).component_format() == mi.Struct.Type.UInt8
    return TextureSource(str(path), converted)


def assign(loaded: LoadedScene, key: str, array: np.ndarray) -> None:
    """Set a selected parameter to ``array`` (in its recorded shape), for finite differences."""
    import drjit as dr

    current = loaded.params[key]
    flat = np.ascontiguousarray(array, dtype=np.float32)
    if dr.is_tensor_v(current):
        replacement = type(current)(flat)
    elif dr.size_v(current) == 3:  # a colour: one value per channel
        replacement = type(current)(*[float(v) for v in flat.reshape(-1)])
    else:
        replacement = type(current)(flat.reshape(-1))
    loaded.params[key] = replacement
    loaded.params.update()
