"""Mitsuba 0.5/0.6 constructs that Mitsuba 3.9.1 does not read: upgraded, or refused, listed.

Mitsuba 3 upgrades old files only by renaming camelCase properties. Scenes exported for 0.5/0.6
(Bitterli's interiors, say) also use plugins and properties that 3.9.1 refuses; each is
upgraded where Mitsuba 3 has a counterpart, with a :class:`Change` at its file and line, or
refused where it has none. Which properties 3.9.1 refuses was measured by loading each plugin
with each 0.5 property (tests/test_legacy.py repeats it).
"""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from collections.abc import Callable

from sensaov_cli.scene.source import MITSUBA, Change, Refusals, is_object, new_element, where

# (tag, 0.5 type) -> (3.9.1 type, why, alters the image)
_RENAMED_PLUGINS = {
    ("film", "ldrfilm"): (
        "hdrfilm",
        "sensaov measures radiance; the tone mapping is unused",
        False,
    ),
    ("sampler", "halton"): ("independent", "the same image in expectation", False),
    ("sampler", "hammersley"): ("independent", "the same image in expectation", False),
    ("sampler", "sobol"): ("independent", "the same image in expectation", False),
    ("emitter", "sun"): ("sunsky", "a sunsky with sky_scale 0 is the sun alone", False),
    ("emitter", "sky"): ("sunsky", "a sunsky with sun_scale 0 is the sky alone", False),
    ("bsdf", "roughdiffuse"): ("diffuse", "its Oren-Nayar roughness is dropped", True),
}
# Properties 3.9.1 refuses that make no difference to the image sensaov renders.
_DROPPED = {
    "bitmap": ("max_anisotropy", "cache"),
    "envmap": ("cache",),
    "hdrfilm": ("attach_log", "high_quality_edges", "gamma", "exposure", "tonemap_method",
                "key", "burn"),
    "stratified": ("dimension",), "ldsampler": ("dimension",), "independent": ("scramble",),
    "obj": ("collapse",), "ply": ("srgb",), "sunsky": ("resolution",),
    "heterogeneous": ("method", "step_size"),
}  # fmt: skip
# Properties with no counterpart: the scene is refused (what they do cannot be rendered).
_UNSUPPORTED = {
    "bitmap": ("channel",),
    "homogeneous": ("material",),
    "heterogeneous": ("orientation",),
}
_IOR_OWNERS = ("dielectric", "thindielectric", "roughdielectric", "plastic", "roughplastic")
_DISTRIBUTIONS = {"phong": "beckmann", "as": "ggx"}
_SUN_APERTURE = 0.5358  # degrees: Mitsuba 3's default sun_aperture, 0.5's sunRadiusScale 1
_SRGB_LIKE = ("-1", "2.2")  # gamma values that are the sRGB curve 3.9.1 applies by default
_UV_NAMES = ("uoffset", "voffset", "uscale", "vscale")


def upgrade_legacy(
    root: ET.Element, legacy_files: set[str], changes: list[Change], refusals: Refusals
) -> None:
    """Upgrade every object read from one of ``legacy_files`` (paths as read): Mitsuba's own
    renaming first, then what 3.9.1 lacks of 0.5/0.6, listed in ``changes``."""
    for element in list(root.iter()):
        if is_object(element) and where(element).rpartition(":")[0] in legacy_files:
            _mitsuba_upgrade(element)
            _upgrade_object(element, changes, refusals)


def _mitsuba_upgrade(element: ET.Element) -> None:
    # A child's name is a property of this object, so this object's file version decides.
    diffuse = element.tag == "bsdf" and element.get("type") == "diffuse"
    for child in element:
        if child.get("name"):
            child.set("name", snake_case(child.get("name", "")))
        if diffuse and child.get("name") == "diffuse_reflectance":
            child.set("name", "reflectance")
    found = {c.get("name"): c for c in element if c.get("name") in _UV_NAMES}
    if not found:
        return
    for child in found.values():
        element.remove(child)
    first = next(iter(found.values()))
    transform = new_element("transform", {"name": "to_uv"}, like=first)
    # Mitsuba builds scale(s) * translate(o): the translation applies first, as written here.
    for tag, names in (("translate", ("uoffset", "voffset")), ("scale", ("uscale", "vscale"))):
        axes = zip("xy", names, strict=True)
        values = {axis: found[name].get("value", "") for axis, name in axes if name in found}
        transform.append(new_element(tag, values, like=first))
    element.append(transform)


def snake_case(name: str) -> str:
    """Mitsuba's camel_to_underscore_case, character for character."""
    out: list[str] = []
    i = 0
    while i < len(name):
        if i > 0 and name[i - 1].islower() and name[i].isupper():
            out.append("_" + name[i].lower())
            while i + 1 < len(name) and name[i + 1].isupper():
                i += 1
                out.append(name[i].lower())
        else:
            out.append(name[i])
        i += 1
    return "".join(out)


def _upgrade_object(element: ET.Element, changes: list[Change], refusals: Refusals) -> None:
    _rename_plugin(element, changes)
    kind = element.get("type", "")
    for name in _DROPPED.get(kind, ()):
        for child in _removed(element, name):
            changes.append(Change(f"{kind} property {name!r} dropped", _NO_EFFECT, where(child)))
    for name in _UNSUPPORTED.get(kind, ()):
        for child in _named(element, name):
            refusals.add(f"{kind} property {name!r} has no counterpart in {MITSUBA}", where(child))
    if kind in _RULES:
        _RULES[kind](element, changes)


_NO_EFFECT = f"{MITSUBA} has no such property; it makes no difference to the image rendered"


def _rename_plugin(element: ET.Element, changes: list[Change]) -> None:
    found = _RENAMED_PLUGINS.get((element.tag, element.get("type", "")))
    if found is None:
        return
    old, (new, why, alters) = element.get("type", ""), found
    element.set("type", new)
    if old in ("sun", "sky"):
        off = "sky_scale" if old == "sun" else "sun_scale"
        element.append(new_element("float", {"name": off, "value": "0"}, like=element))
    if element.tag == "film":
        _removed(element, "file_format")  # ldrfilm's png/jpeg: hdrfilm has neither
    message = f"{element.tag} {old!r} -> {new!r}"
    changes.append(Change(message, f"{MITSUBA} has no '{old}': {why}", where(element), alters))


def _named(element: ET.Element, name: str) -> list[ET.Element]:
    return [child for child in element if child.get("name") == name and child.tag != "ref"]


def _removed(element: ET.Element, name: str) -> list[ET.Element]:
    found = _named(element, name)
    for child in found:
        element.remove(child)
    return found


def _bitmap(element: ET.Element, changes: list[Change]) -> None:
    for child in _named(element, "filter_type"):
        if child.get("value") in ("trilinear", "ewa"):
            old = child.get("value")
            child.set("value", "bilinear")
            why = f"{MITSUBA} filters bitmaps bilinearly or not at all (no MIP maps)"
            changes.append(Change(f"bitmap filter_type {old!r} -> 'bilinear'", why, where(child)))
    _wrap_modes(element, changes)
    for child in _named(element, "gamma"):
        _gamma(element, child, changes)


def _wrap_modes(element: ET.Element, changes: list[Change]) -> None:
    u, v = _removed(element, "wrap_mode_u"), _removed(element, "wrap_mode_v")
    if u or v:
        first = (u or v)[0]
        kept = new_element("string", {"name": "wrap_mode", "value": first.get("value", "")}, first)
        element.append(kept)
        differ = bool(u and v and u[0].get("value") != v[0].get("value"))
        why = f"{MITSUBA} has one wrap mode for both axes"
        why += ": they differ, the u axis's is used" if differ else ""
        changes.append(Change("bitmap wrap_mode_u/_v -> wrap_mode", why, where(first), differ))
    for child in _named(element, "wrap_mode"):
        if child.get("value") in ("zero", "one"):
            why = f"{MITSUBA} has no '{child.get('value')}' wrap mode: edge texels are repeated"
            changes.append(Change(f"bitmap wrap_mode {child.get('value')!r} -> 'clamp'", why,
                                  where(child), True))  # fmt: skip
            child.set("value", "clamp")


def _gamma(element: ET.Element, child: ET.Element, changes: list[Change]) -> None:
    value = (child.get("value") or "").strip()
    element.remove(child)
    if _number(value) == 1.0:
        element.append(new_element("boolean", {"name": "raw", "value": "true"}, child))
        changes.append(Change("bitmap gamma 1 -> raw true", "the file's values are linear",
                              where(child)))  # fmt: skip
        return
    srgb = value in _SRGB_LIKE or _number(value) == 2.2
    why = f"{MITSUBA} decodes 8-bit bitmaps with the sRGB curve"
    why += "" if srgb else f"; gamma {value} cannot be expressed, the sRGB curve is used"
    changes.append(Change(f"bitmap gamma {value} dropped", why, where(child), not srgb))


def _number(text: str) -> float | None:
    try:
        return float(text)
    except ValueError:
        return None


def _ior_names(element: ET.Element, changes: list[Change]) -> None:
    for side in ("int", "ext"):
        for child in _named(element, f"{side}_eta"):
            child.set("name", f"{side}_ior")
            why = f"{MITSUBA} names a dielectric's indices int_ior and ext_ior"
            changes.append(Change(f"{side}_eta -> {side}_ior", why, where(child)))
    _distribution(element, changes)


def _conductor(element: ET.Element, changes: list[Change]) -> None:
    for child in _removed(element, "ext_eta"):
        value = (child.get("value") or "").strip().lower()
        air = value in ("vacuum", "air") or _number(value) == 1.0
        why = f"{MITSUBA}'s conductors reflect against air"
        why += "" if air else f"; an exterior index of {value} cannot be expressed"
        changes.append(Change(f"conductor ext_eta {value!r} dropped", why, where(child), not air))
    _distribution(element, changes)


def _distribution(element: ET.Element, changes: list[Change]) -> None:
    for child in _named(element, "distribution"):
        old = child.get("value", "")
        if old in _DISTRIBUTIONS:
            child.set("value", _DISTRIBUTIONS[old])
            why = f"{MITSUBA} has the beckmann and ggx distributions only"
            changes.append(Change(f"distribution {old!r} -> {_DISTRIBUTIONS[old]!r}", why,
                                  where(child), True))  # fmt: skip


def _sunsky(element: ET.Element, changes: list[Change]) -> None:
    for child in _removed(element, "scale"):
        for name in ("sun_scale", "sky_scale"):
            _scale_float(element, name, child.get("value", "1"), like=child)
        changes.append(Change("sunsky scale -> sun_scale and sky_scale", _SCALES, where(child)))
    for child in _removed(element, "sun_radius_scale"):
        aperture = _SUN_APERTURE * (_number(child.get("value", "1")) or 1.0)
        element.append(new_element("float", {"name": "sun_aperture", "value": f"{aperture:g}"},
                                   like=child))  # fmt: skip
        why = f"{MITSUBA} sizes the sun by its aperture, {_SUN_APERTURE} degrees at scale 1"
        changes.append(Change(f"sun_radius_scale -> sun_aperture {aperture:g}", why, where(child)))
    for child in _removed(element, "stretch"):
        stretched = _number(child.get("value", "1")) != 1.0
        why = f"{MITSUBA}'s sky ends at the horizon"
        changes.append(Change("sunsky stretch dropped", why, where(child), stretched))


_SCALES = f"{MITSUBA} scales the sun and the sky separately; 0.5's scale multiplied both"


def _scale_float(element: ET.Element, name: str, factor: str, like: ET.Element) -> None:
    existing = _removed(element, name)
    base = _number(existing[0].get("value", "1")) if existing else 1.0
    value = (base if base is not None else 1.0) * (_number(factor) or 1.0)
    element.append(new_element("float", {"name": name, "value": f"{value:g}"}, like=like))


def _mesh(element: ET.Element, changes: list[Change]) -> None:
    for child in _removed(element, "max_smooth_angle"):
        why = f"{MITSUBA} does not rebuild smoothed normals: the mesh's own normals are used"
        changes.append(Change("mesh max_smooth_angle dropped", why, where(child), True))


def _homogeneous(element: ET.Element, changes: list[Change]) -> None:
    for child in _named(element, "density_multiplier"):
        child.set("name", "scale")
        changes.append(Change("density_multiplier -> scale", "renamed in Mitsuba 3", where(child)))
    absorbing, scattering = _named(element, "sigma_a"), _named(element, "sigma_s")
    if not (absorbing and scattering):
        return
    a, s = _values(absorbing[0]), _values(scattering[0])
    if a is None or s is None or len(a) != len(s):
        return  # textured coefficients: left for Mitsuba to refuse, naming them
    t = [x + y for x, y in zip(a, s, strict=True)]
    albedo = [y / x if x else 0.0 for x, y in zip(t, s, strict=True)]
    for child in (absorbing[0], scattering[0]):
        element.remove(child)
    for name, values in (("sigma_t", t), ("albedo", albedo)):
        text = ", ".join(f"{v:g}" for v in values)
        element.append(new_element("rgb", {"name": name, "value": text}, like=absorbing[0]))
    why = f"{MITSUBA} takes sigma_t = sigma_a + sigma_s and albedo = sigma_s / sigma_t"
    changes.append(Change("sigma_a, sigma_s -> sigma_t, albedo", why, where(absorbing[0])))


def _values(child: ET.Element) -> list[float] | None:
    numbers = [_number(part) for part in re.split(r"[,\s]+", child.get("value", "").strip())]
    if child.tag not in ("float", "rgb", "spectrum") or not numbers or None in numbers:
        return None
    found = [n for n in numbers if n is not None]
    return found * 3 if len(found) == 1 else found


def _heterogeneous(element: ET.Element, changes: list[Change]) -> None:
    for child in _named(element, "density"):
        child.set("name", "sigma_t")
        why = "0.5's density volume is the extinction coefficient Mitsuba 3 calls sigma_t"
        changes.append(Change("heterogeneous density -> sigma_t", why, where(child)))


def _envmap(element: ET.Element, changes: list[Change]) -> None:
    for child in _removed(element, "gamma"):
        value = (child.get("value") or "").strip()
        linear = _number(value) == 1.0
        why = f"{MITSUBA}'s envmap reads HDR files as they are and 8-bit ones with the sRGB curve"
        changes.append(Change(f"envmap gamma {value} dropped", why, where(child), not linear))


_RULES: dict[str, Callable[[ET.Element, list[Change]], None]] = {
    "bitmap": _bitmap,
    "envmap": _envmap,
    **dict.fromkeys(_IOR_OWNERS, _ior_names),
    **dict.fromkeys(("conductor", "roughconductor"), _conductor),
    "sunsky": _sunsky,
    **dict.fromkeys(("obj", "ply", "serialized"), _mesh),
    "homogeneous": _homogeneous,
    "heterogeneous": _heterogeneous,
}


def srgb_element(element: ET.Element, changes: list[Change], refusals: Refusals) -> None:
    """A 0.5 ``<srgb>`` colour (gamma-encoded, or #rrggbb) as the linear ``<rgb>`` of 3.9.1."""
    text = element.get("value", "").strip()
    try:
        if text.startswith("#") and len(text) == 7:
            encoded = [int(text[i : i + 2], 16) / 255 for i in (1, 3, 5)]
        else:
            encoded = [float(part) for part in re.split(r"[,\s]+", text) if part]
    except ValueError:
        refusals.add(f"<srgb> value {text[:60]!r} is not a colour", where(element))
        return
    linear = [c / 12.92 if c <= 0.04045 else ((c + 0.055) / 1.055) ** 2.4 for c in encoded]
    element.tag = "rgb"
    element.set("value", ", ".join(f"{c:.6g}" for c in linear))
    why = f"{MITSUBA} has no <srgb>: the colour is decoded to the linear RGB <rgb> takes"
    changes.append(Change(f"<srgb> {text} -> <rgb> {element.get('value')}", why, where(element)))


# Every plugin Mitsuba 3.9.1 has, by tag (its plugins folder, and the Python integrators);
# integrators are not checked: sensaov replaces the scene's (integrator.py).
_PLUGINS = {
    "bsdf": "blendbsdf bumpmap circular conductor dielectric diffuse hair mask measured "
    "measured_polarized normalmap null plastic polarizer pplastic principled principledthin "
    "retarder roughconductor roughdielectric roughplastic thindielectric twosided",
    "emitter": "area constant directional directionalarea envmap point projector spot sunsky "
    "timed_sunsky",
    "texture": "bitmap checkerboard mesh_attribute volume blackbody d65 irregular rawconstant "
    "regular srgb uniform",
    "film": "hdrfilm specfilm",
    "sampler": "independent stratified multijitter orthogonal ldsampler",
    "rfilter": "box tent gaussian mitchell catmullrom lanczos",
    "sensor": "perspective thinlens orthographic radiancemeter irradiancemeter distant batch",
    "shape": "obj ply serialized sphere cube rectangle disk cylinder instance shapegroup merge "
    "blender bsplinecurve linearcurve sdfgrid ellipsoids ellipsoidsmesh",
    "medium": "homogeneous heterogeneous",
    "phase": "hg isotropic rayleigh blendphase tabphase sggx",
    "volume": "constvolume gridvolume",
}
PLUGINS = {tag: frozenset(names.split()) for tag, names in _PLUGINS.items()}
PLUGINS["spectrum"] = PLUGINS["texture"]


def refuse_unknown_plugins(root: ET.Element, refusals: Refusals) -> None:
    """Every object whose plugin Mitsuba 3.9.1 does not have, named with its line."""
    for element in root.iter():
        known = PLUGINS.get(element.tag)
        kind = element.get("type")
        if known is not None and kind is not None and kind not in known:
            refusals.add(f"{MITSUBA} has no {element.tag} plugin {kind!r}", where(element))
