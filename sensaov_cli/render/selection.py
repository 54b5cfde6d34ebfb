"""Which scene parameters enter the sensitivity buffer, what slot each fills, who owns it.

A parameter's type is the slot it fills, whatever its storage (the paper's horizontal cut).
"""

from __future__ import annotations

import fnmatch
import re
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np

from sensaov_cli.buffer.model import ExcludedParam, ParamRecord, TextureSource
from sensaov_cli.job.spec import ParameterSpec
from sensaov_cli.render.verify.trust import (
    COMPOSITES,
    Context,
    composite_status,
    gradient_integrator,
    verification_status,
    weakest,
)
from sensaov_cli.vocabulary import Trust

TYPE_ALIASES = {
    "alpha": "roughness",
    "nested_texture": "bump",  # a bumpmap's height map
    "normalmap": "normal",  # a normalmap's normals
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
# Mitsuba class names -> the plugin names users write in XML, where not the lowercased name.
PLUGIN_NAMES = {
    "SmoothDiffuse": "diffuse",
    "SmoothPlastic": "plastic",
    "SmoothDielectric": "dielectric",
    "SmoothConductor": "conductor",
    "MaskBSDF": "mask",
    "AreaLight": "area",
    "PointLight": "point",
    "SpotLight": "spot",
    "ConstantBackgroundEmitter": "constant",
    "EnvironmentMapEmitter": "envmap",
    "DirectionalEmitter": "directional",
    "SunskyEmitter": "sunsky",
    "TimedSunskyEmitter": "timed_sunsky",
    "TwoSidedBRDF": "twosided",
    "PolarizedPlastic": "pplastic",
    "HomogeneousMedium": "homogeneous",
    "HeterogeneousMedium": "heterogeneous",
    "HGPhaseFunction": "hg",
    "IsotropicPhaseFunction": "isotropic",
    "RayleighPhaseFunction": "rayleigh",
}
GEOMETRY_FIELDS = ("to_world", "position", "direction", "faces")
# A mesh's own arrays that place it; its other vertex_*/face_* arrays are attributes.
MESH_GEOMETRY = ("faces", "vertex_positions", "vertex_normals", "vertex_texcoords")


@dataclass(frozen=True)
class _Colour:
    """Where a ``mesh_attribute`` texture reads a mesh's attribute: the slot it fills and the
    plugin holding that slot. The attribute is that texture's data, not geometry."""

    slot: str
    holder: Any


@dataclass(frozen=True)
class Selection:
    """What :func:`select_parameters` found: the records the buffer stores and what was left out."""

    selected: tuple[ParamRecord, ...]
    excluded: tuple[ExcludedParam, ...]
    textures: dict[str, TextureSource]  # texture parameter key -> its bitmap file
    routes: dict[str, str]  # key -> the integrator whose backward pass differentiates it
    contexts: dict[str, tuple[Context, ...]]  # key -> the composites its gradient passes


@dataclass(frozen=True)
class Ownership:
    """Which objects own each scene node, by node identity (never by key strings: key names
    depend on declaration order). ``nodes`` keeps the nodes alive, so their ids stay valid."""

    objects: tuple[str, ...]
    owners: dict[int, tuple[str, ...]]  # id(node) -> owning objects, sorted
    nodes: tuple[Any, ...]

    def of(self, node: Any) -> tuple[str, ...]:
        return self.owners.get(id(node), ())


def ownership_of(mi: ModuleType, scene: Any, instances: Mapping[str, str]) -> Ownership:
    """Every object (shape, instance, or emitter not attached to a shape) and the nodes it owns;
    an instance owns its shapegroup's nodes (``instances``: instance id -> shapegroup id, from
    the XML: Mitsuba exposes no link)."""
    groups = {  # shapegroups are no shapes of the scene, only parents in its graph
        node.id(): node
        for node in mi.traverse(scene).hierarchy
        if isinstance(node, mi.Shape) and node.class_name() == "ShapeGroupPlugin"
    }
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
    return Ownership(
        tuple(sorted(owned)), {key: tuple(sorted(v)) for key, v in owners.items()}, alive
    )


def select_parameters(
    mi: ModuleType,
    parameters: ParameterSpec,
    params: Any,
    ownership: Ownership,
    sources: dict[str, Path],
    media: str | None = None,
) -> Selection:
    """The selected records, the parameters left out and why, the bitmap behind each texture
    and the integrator each is differentiated by. ``media``: None where the scene's integrator
    renders media, else that integrator (whose media parameters are left out)."""
    selected, excluded, textures, routes, composition = [], [], {}, {}, {}
    children = _bsdf_children(mi, params.hierarchy)
    colours = _mesh_colours(mi, params)
    for key in params.keys():
        _, _, node, flags = params.properties[key]
        try:
            value = params[key]
        except Exception as exc:  # noqa: BLE001 - Mitsuba's own read fails (hair's unset sigma_a)
            excluded.append(ExcludedParam(key, f"Mitsuba cannot read its value ({exc!s:.80})"))
            continue
        reason = _exclusion_reason(mi, parameters, key, value, node, flags, key in colours)
        holder = _above_textures(mi, node, params.hierarchy)[1] if media is not None else None
        if reason is None and isinstance(holder, mi.Medium | mi.PhaseFunction):  # or in one
            reason = f"medium parameter: the scene's '{media}' integrator renders no media"
        owners = ownership.of(node) if reason is None else ()
        if reason is None and not owners:
            reason = "owned by no object in the scene"
        if reason is None:
            record, contexts = _describe(mi, key, params, owners, children, colours.get(key))
            selected.append(record)
            routes[key] = gradient_integrator(record.plugin, contexts)
            composition[key] = contexts
            if record.is_texture:
                textures[key] = _texture_source(mi, params.properties[key][2], sources)
        else:
            excluded.append(ExcludedParam(key, reason))
    return Selection(tuple(selected), tuple(excluded), textures, routes, composition)


def _explicitly_included(key: str, include: tuple[str, ...]) -> bool:
    """Geometry needs a glob that names the field itself (``*.to_world``), not just ``*``."""
    return any(
        fnmatch.fnmatchcase(key, glob) and not any(c in glob.rsplit(".", 1)[-1] for c in "*?[")
        for glob in include
    )


def _mesh_colours(mi: ModuleType, params: Any) -> dict[str, _Colour]:
    """The mesh attributes a ``mesh_attribute`` texture reads (``vertex_color`` of a PLY), by
    key: a texture of the mesh's colour, whose gradient is the slot's (the texture reads the
    attribute linearly), not the mesh's geometry. Each mesh's own subtree is searched, so a
    BSDF shared by several meshes (``shared: keep``) colours each of them."""
    meshes: dict[int, tuple[Any, str]] = {}  # id(mesh) -> the mesh, its keys' prefix
    for key in params.keys():
        node = params.properties[key][2]
        if isinstance(node, mi.Mesh):
            meshes.setdefault(id(node), (node, key.rsplit(".", 1)[0]))
    keys = set(params.keys())
    colours = {}
    for mesh, prefix in meshes.values():
        inner = mi.traverse(mesh)
        for node, _ in inner.hierarchy.items():
            if node.class_name() != "MeshAttribute":
                continue
            match = re.search(r'name = "([^"]*)"', str(node))
            key = f"{prefix}.{match.group(1)}" if match else None
            if key not in keys:
                continue
            # The slot it fills: its own key's parent (bsdf.reflectance.scale -> reflectance).
            own = next((k for k in inner.keys() if inner.properties[k][2] is node), None)
            slot = own.split(".")[-2] if own and "." in own else "mesh_attribute"
            colours[str(key)] = _Colour(slot, _above_textures(mi, node, inner.hierarchy)[1])
    return colours


def _exclusion_reason(
    mi: ModuleType,
    parameters: ParameterSpec,
    key: str,
    value: Any,
    node: Any,
    flags: int,
    colour: bool = False,
) -> str | None:
    import drjit as dr

    if flags & int(mi.ParamFlags.NonDifferentiable):
        return "not differentiable (Mitsuba flags it NonDifferentiable)"
    if flags & int(mi.ParamFlags.ReadOnly):
        return "read-only (Mitsuba flags it ReadOnly: it is computed from other parameters)"
    if not (dr.is_array_v(value) and dr.is_diff_v(value) and dr.is_float_v(value)):
        return "not a differentiable floating-point value"
    if isinstance(node, mi.Sensor | mi.Film | mi.Sampler):
        return "camera parameter (prb gives cameras no gradient)"
    field = key.rsplit(".", 1)[-1]
    is_geometry = not colour and (
        isinstance(node, mi.Shape) or field in GEOMETRY_FIELDS or field.startswith("vertex_")
    )
    attribute = field.startswith(("vertex_", "face_")) and field not in MESH_GEOMETRY
    if is_geometry and attribute and not _explicitly_included(key, parameters.include):
        return "a mesh attribute no mesh_attribute texture reads: it changes nothing rendered"
    if is_geometry and not _explicitly_included(key, parameters.include):
        return "geometry (excluded by default; include it by naming the field, e.g. '*.to_world')"
    if not any(fnmatch.fnmatchcase(key, glob) for glob in parameters.include):
        return "not matched by parameters.include"
    for glob in parameters.exclude:
        if fnmatch.fnmatchcase(key, glob):
            return f"excluded by parameters.exclude {glob!r}"
    return None


def _describe(
    mi: ModuleType,
    key: str,
    params: Any,
    owners: tuple[str, ...],
    children: dict[int, list[Any]],
    colour: _Colour | None = None,
) -> tuple[ParamRecord, tuple[Context, ...]]:
    _, _, node, flags = params.properties[key]
    parts = key.split(".")
    is_texture_node = isinstance(node, mi.Texture)
    # The slot the parameter fills in the plugin that is not a texture (or volume): in
    # ``glaze.roughness.color0.value`` the type is roughness, whatever the nesting.
    levels, holder = _above_textures(mi, node, params.hierarchy)
    if len(parts) <= levels:
        levels, holder = 0, node
    slot = parts[-1 - levels]
    if colour is not None:  # a mesh's vertex colours: the slot its mesh_attribute texture fills
        slot, holder = colour.slot, colour.holder
    plugin = _plugin_name(holder)
    ptype = _EMITTER_SLOT_TYPES.get(slot, slot) if isinstance(holder, mi.Emitter) else slot
    ptype = TYPE_ALIASES.get(ptype, ptype)
    is_texture = is_texture_node and parts[-1] == "data"
    contexts = _composition(mi, holder, ptype, params.hierarchy, children)
    # A composite's own parameter (a blend's weight) is measured in its context: its children.
    own: tuple[Trust, str] = (
        ("verified", "") if plugin in COMPOSITES else verification_status(plugin, ptype)
    )
    trust, note = weakest(own, composite_status(contexts))
    shape = tuple(int(n) for n in np.asarray(params[key]).shape)
    shape = shape[:1] if len(shape) == 2 and shape[1] == 1 else shape  # colours: (3, 1) -> (3,)
    if is_texture_node and "spectral" in mi.variant() and shape[-1:] == (3,):
        trust, note = "unverified", SPECTRAL_COEFFICIENTS_NOTE
    flag_names: tuple[str, ...] = ()
    flag_names += ("discontinuous",) if flags & int(mi.ParamFlags.Discontinuous) else ()
    flag_names += ("mesh_attribute",) if colour is not None else ()  # a colour, per vertex
    record = ParamRecord(
        key=key,
        type=ptype,
        owners=owners,
        shape=shape,
        is_texture=is_texture,
        plugin=plugin,
        flags=flag_names,
        trust=trust,
        note=note,
        # composites above it may send it to path (trust.py, "composites")
        estimator="reverse-path" if gradient_integrator(plugin, contexts) == "path" else "reverse",
    )
    return record, contexts


def _bsdf_children(mi: ModuleType, hierarchy: Any) -> dict[int, list[Any]]:
    """id(BSDF) -> the BSDFs nested in it (Mitsuba's hierarchy maps a node to its parent)."""
    children: dict[int, list[Any]] = {}
    for node, (parent, *_) in hierarchy.items():
        if isinstance(node, mi.BSDF) and isinstance(parent, mi.BSDF):
            children.setdefault(id(parent), []).append(node)
    return children


def _composition(
    mi: ModuleType, holder: Any, ptype: str, hierarchy: Any, children: dict[int, list[Any]]
) -> tuple[Context, ...]:
    """A context for each composite BSDF the parameter's gradient passes (trust.py): the
    holder itself (its own slot is the role) and every composite it sits in ("child")."""
    contexts = []
    node = holder
    delta = int(mi.BSDFFlags.Delta)
    while isinstance(node, mi.BSDF):
        composite = _plugin_name(node)
        if composite in COMPOSITES:
            smooth = any(int(c.flags()) & delta for c in children.get(id(node), ()))
            role = ptype if node is holder else "child"
            contexts.append((composite, role, "smooth" if smooth else "rough"))
        parent = hierarchy.get(node)
        node = parent[0] if parent is not None else None
    return tuple(contexts)


def _above_textures(mi: ModuleType, node: Any, hierarchy: Any) -> tuple[int, Any]:
    """The texture (or volume) levels above ``node`` and the plugin they fill a slot of, or the
    outermost texture when none holds it."""
    levels, holder = 0, node
    while isinstance(holder, mi.Texture | mi.Volume):
        levels += 1
        parent = hierarchy.get(holder)
        if parent is None:
            break
        holder = parent[0]
    return levels, holder


def _plugin_name(node: Any) -> str:
    name = node.class_name() if node is not None else "unknown"
    return PLUGIN_NAMES.get(name, name.lower())


def _texture_source(mi: ModuleType, node: Any, sources: dict[str, Path]) -> TextureSource:
    """The file behind a bitmap texture (it prints only its base name), and whether it was
    stored as 8-bit integers."""
    match = re.search(r'name = "([^"]*)"', str(node))
    path = sources.get(match.group(1)) if match else None
    if path is None or not path.is_file():
        return TextureSource(match.group(1) if match else None, converted=False)
    converted = mi.Bitmap(str(path)).component_format() == mi.Struct.Type.UInt8
    return TextureSource(str(path), converted)
