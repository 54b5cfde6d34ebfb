"""Rewrite a Mitsuba 3 scene description before loading it (pure XML, no Mitsuba import).

The user's file is never modified: the rewritten text is handed to ``mitsuba.load_string``.
What changes, and why:

- every integrator is replaced by ``prb`` with the job's ``max_depth`` (``path`` costs memory
  that grows with spp under AD; ``prb`` is constant-memory, MITSUBA-NOTES);
- bitmap textures load as float (``format = variant``) so their texels receive gradients
  (8-bit textures load as non-differentiable integers by default);
- with ``shared: split``, a BSDF used by several shapes is copied into each of them, so each
  object gets its own gradient (the copies' gradients sum to the shared one);
- unnamed top-level objects get stable ids (otherwise Mitsuba keys them by pointer);
- the objective camera is chosen, added (inline ``look_at``) or resized.
"""

from __future__ import annotations

import copy
import hashlib
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

from sensaov_cli.errors import SceneError
from sensaov_cli.spec.model import CameraSpec

OBJECTIVE_SENSOR_ID = "sensaov_objective"
_NAMED_TAGS = ("shape", "emitter", "bsdf", "texture", "sensor", "medium")


INSPECTION_PREFIX = "sensaov_inspect_"


@dataclass(frozen=True)
class PreparedXml:
    text: str
    sensor_id: str
    inspection_ids: dict[str, str]  # inspection camera name -> sensor id in the prepared scene
    split: dict[str, tuple[str, ...]]  # shared BSDF id -> the shapes that received a copy
    bitmap_files: tuple[str, ...]  # filename values of bitmap textures, as written
    materials: dict[str, str]  # shape id -> the BSDF id it uses, as the user named it


def parse_scene(path: Path) -> ET.Element:
    try:
        root = ET.parse(path).getroot()
    except FileNotFoundError as exc:
        raise SceneError("scene file not found", where=str(path)) from exc
    except ET.ParseError as exc:
        line = exc.position[0]
        raise SceneError(f"malformed XML: {exc.msg}", where=f"{path}:{line}") from exc
    except OSError as exc:
        raise SceneError(f"cannot read scene: {exc.strerror}", where=str(path)) from exc
    if root.tag != "scene":
        raise SceneError(f"root element is <{root.tag}>, expected <scene>", where=str(path))
    return root


def scene_fingerprint(path: Path) -> str:
    """sha256 over the scene file and every file it names, so edits to a texture count too."""
    digest = hashlib.sha256(path.read_bytes())
    root = parse_scene(path)
    names = sorted(
        {el.get("value", "") for el in root.iter("string") if el.get("name") == "filename"}
    )
    for name in names:
        referenced = path.parent / name
        digest.update(name.encode())
        if referenced.is_file():
            digest.update(referenced.read_bytes())
    return digest.hexdigest()


def prepare_scene_xml(
    path: Path,
    *,
    max_depth: int,
    camera: CameraSpec,
    resolution: tuple[int, int] | None,
    shared: str,
    inspection: tuple[CameraSpec, ...] = (),
) -> PreparedXml:
    root = parse_scene(path)
    _name_top_level(root)
    _replace_integrator(root, max_depth)
    bitmaps = _bitmaps_as_float(root)
    materials = _materials(root)  # before splitting: copies keep the name the user gave
    split = _split_shared_bsdfs(root) if shared == "split" else {}
    sensor = _choose_sensor(root, camera, path)
    if resolution is not None:
        _set_film_size(sensor, resolution)
    inspection_ids = {
        cam.name: _add_inspection_sensor(
            root, cam, sensor, path, f"inspection camera {cam.name!r}: sensor"
        )
        for cam in inspection
    }
    text = ET.tostring(root, encoding="unicode")
    return PreparedXml(text, sensor.get("id", ""), inspection_ids, split, bitmaps, materials)


def _name_top_level(root: ET.Element) -> None:
    counts: dict[str, int] = {}
    for element in root:
        if element.tag in _NAMED_TAGS and not element.get("id"):
            index = counts.get(element.tag, 0)
            counts[element.tag] = index + 1
            element.set("id", f"{element.tag}_{index}")


def _replace_integrator(root: ET.Element, max_depth: int) -> None:
    for element in root.findall("integrator"):
        root.remove(element)
    integrator = ET.Element("integrator", {"type": "prb"})
    ET.SubElement(integrator, "integer", {"name": "max_depth", "value": str(max_depth)})
    root.insert(0, integrator)


def _bitmaps_as_float(root: ET.Element) -> tuple[str, ...]:
    files = []
    for texture in root.iter("texture"):
        if texture.get("type") != "bitmap":
            continue
        children = {child.get("name"): child for child in texture}
        if "filename" in children:
            files.append(children["filename"].get("value", ""))
        if "format" not in children:
            ET.SubElement(texture, "string", {"name": "format", "value": "variant"})
    return tuple(files)


def _materials(root: ET.Element) -> dict[str, str]:
    """Shape id -> material name for a material Cryptomatte (Mitsuba's default BSDF: "default")."""
    materials = {}
    for shape in root.iter("shape"):
        ref = next((r for r in shape.findall("ref") if r.get("name") in (None, "bsdf")), None)
        inline = shape.find("bsdf")
        if ref is not None:
            name = ref.get("id", "")
        elif inline is not None:
            name = inline.get("id") or f"{shape.get('id', 'shape')}_bsdf"
        else:
            name = "default"
        materials[shape.get("id", "")] = name
    return materials


def _shape_bsdf_refs(
    root: ET.Element, bsdf_ids: set[str]
) -> dict[str, list[tuple[ET.Element, ET.Element]]]:
    """For each top-level BSDF id, the (shape, ref) pairs that use it."""
    uses: dict[str, list[tuple[ET.Element, ET.Element]]] = {}
    for shape in root.iter("shape"):
        for ref in shape.findall("ref"):
            target = ref.get("id", "")
            if target in bsdf_ids and ref.get("name") in (None, "bsdf"):
                uses.setdefault(target, []).append((shape, ref))
    return uses


def _split_shared_bsdfs(root: ET.Element) -> dict[str, tuple[str, ...]]:
    bsdfs = {el.get("id", ""): el for el in root.findall("bsdf")}
    uses = _shape_bsdf_refs(root, set(bsdfs))
    split: dict[str, tuple[str, ...]] = {}
    for bsdf_id, pairs in uses.items():
        if len(pairs) < 2:
            continue
        for shape, ref in pairs:
            clone = copy.deepcopy(bsdfs[bsdf_id])
            for element in clone.iter():
                element.attrib.pop("id", None)  # the copy is keyed under its shape
            index = list(shape).index(ref)
            shape.remove(ref)
            shape.insert(index, clone)
        split[bsdf_id] = tuple(shape.get("id", "") for shape, _ in pairs)
        if not any(ref.get("id") == bsdf_id for ref in root.iter("ref")):
            root.remove(bsdfs[bsdf_id])
    return split


def _choose_sensor(
    root: ET.Element, camera: CameraSpec, path: Path, where: str = "objective_camera"
) -> ET.Element:
    sensors = root.findall("sensor")
    if camera.look_at is not None:
        return _add_look_at_sensor(root, camera, sensors[0] if sensors else None)
    if not sensors:
        raise SceneError(
            "the scene has no sensor",
            where=str(path),
            hint="add one, or give objective_camera a look_at",
        )
    if camera.sensor is None:
        return sensors[0]
    for sensor in sensors:
        if sensor.get("id") == camera.sensor:
            return sensor
    # Sensors this pass added for the objective and inspection cameras are not the user's.
    ids = ", ".join(s.get("id", "?") for s in sensors if not s.get("id", "").startswith("sensaov_"))
    raise SceneError(
        f"no sensor with id {camera.sensor!r} in {path.name}",
        where=where,
        hint=f"sensors in the scene: {ids}",
    )


def _add_inspection_sensor(
    root: ET.Element, camera: CameraSpec, objective: ET.Element, path: Path, where: str
) -> str:
    """A sensor of its own for each inspection camera, so resolution overrides stay local."""
    if camera.look_at is not None:
        source = _add_look_at_sensor(root, camera, objective)
    else:
        source = objective if camera.objective else _choose_sensor(root, camera, path, where)
        source = copy.deepcopy(source)
        root.append(source)
        if camera.resolution is not None:
            _set_film_size(source, camera.resolution)
    sensor_id = f"{INSPECTION_PREFIX}{camera.name}"
    source.set("id", sensor_id)
    return sensor_id


def _vector(values: tuple[float, float, float]) -> str:
    return ", ".join(repr(float(v)) for v in values)


def _add_look_at_sensor(
    root: ET.Element, camera: CameraSpec, template: ET.Element | None
) -> ET.Element:
    assert camera.look_at is not None
    sensor = ET.SubElement(root, "sensor", {"type": "perspective", "id": OBJECTIVE_SENSOR_ID})
    ET.SubElement(sensor, "float", {"name": "fov", "value": repr(float(camera.fov))})
    transform = ET.SubElement(sensor, "transform", {"name": "to_world"})
    ET.SubElement(
        transform,
        "lookat",
        {
            "origin": _vector(camera.look_at.origin),
            "target": _vector(camera.look_at.target),
            "up": _vector(camera.look_at.up),
        },
    )
    film = template.find("film") if template is not None else None
    if film is not None:
        sensor.append(copy.deepcopy(film))
    else:
        film = ET.SubElement(sensor, "film", {"type": "hdrfilm"})
        ET.SubElement(film, "rfilter", {"type": "box"})
    _set_film_size(sensor, camera.resolution or (256, 256))
    return sensor


def _set_film_size(sensor: ET.Element, resolution: tuple[int, int]) -> None:
    film = sensor.find("film")
    if film is None:
        film = ET.SubElement(sensor, "film", {"type": "hdrfilm"})
    for name, value in zip(("width", "height"), resolution, strict=True):
        for old in [c for c in film if c.get("name") == name]:
            film.remove(old)
        ET.SubElement(film, "integer", {"name": name, "value": str(value)})
