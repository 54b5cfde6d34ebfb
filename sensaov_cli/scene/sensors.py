"""The objective and inspection cameras in the scene text sensaov hands to Mitsuba.

Every id in one Mitsuba scene must be unique, films, samplers and filters included, so a
sensor copied for an inspection camera (or a film copied for a look-at camera) loses the ids
of the objects it carried (its ``<ref>``s keep theirs). A film shared between sensors by
``<ref>`` is copied into a sensor before that sensor's film is resized, so resizing one camera
never resizes another.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET

from sensaov_cli.errors import SceneError
from sensaov_cli.job.spec import CameraSpec
from sensaov_cli.scene.naming import child_value, objects_by_id, refs_to, replace_ref
from sensaov_cli.scene.source import detached_copy, where

OBJECTIVE_SENSOR_ID = "sensaov_objective"
MAX_FILM_SIZE = 16384  # the largest width or height a job's resolution may ask for
_SIZE = ("width", "height")
_CROP = ("crop_offset_x", "crop_offset_y", "crop_width", "crop_height")
INSPECTION_PREFIX = "sensaov_inspect_"


def sensor_ids(root: ET.Element) -> tuple[str, ...]:
    """The scene's own sensors (not the ones sensaov added), in document order."""
    return tuple(
        s.get("id", "")
        for s in root.findall("sensor")
        if not s.get("id", "").startswith("sensaov_")
    )


def choose_sensor(root: ET.Element, camera: CameraSpec) -> ET.Element:
    """The camera's sensor, the first where it names none (prepare.py checked that it exists)."""
    sensors = root.findall("sensor")
    if camera.look_at is not None:
        return _add_look_at_sensor(root, camera, sensors[0] if sensors else None)
    return next(s for s in sensors if camera.sensor in (None, s.get("id")))


def add_inspection_sensor(root: ET.Element, camera: CameraSpec, objective: ET.Element) -> str:
    """A sensor of its own for each inspection camera, so resolution overrides stay local."""
    if camera.look_at is not None:
        source = _add_look_at_sensor(root, camera, objective)
    else:
        source = detached_copy(objective if camera.objective else choose_sensor(root, camera))
        root.append(source)
        own_film(root, source)
        if camera.resolution is not None:
            set_film_size(root, source, camera.resolution)
    sensor_id = f"{INSPECTION_PREFIX}{camera.name}"
    source.set("id", sensor_id)
    check_film_size(root, source, f"inspection camera {camera.name!r}")
    return sensor_id


def sample_count(root: ET.Element, sensor: ET.Element) -> int | None:
    """The sensor's sampler's ``sample_count`` as the scene sets it (e.g. its ``$spp``)."""
    sampler = _child_object(root, sensor, "sampler")
    value = child_value(sampler, "sample_count") if sampler is not None else None
    return int(value) if value is not None and value.strip().lstrip("-").isdigit() else None


def own_film(root: ET.Element, sensor: ET.Element) -> ET.Element:
    """The sensor's film as an element of its own (a ``<ref>``'d film is copied in)."""
    film = _child_object(root, sensor, "film")
    if film is None:
        return ET.SubElement(sensor, "film", {"type": "hdrfilm"})
    if sensor.find("film") is None:  # shared by <ref>
        ref = next(c for c in sensor if c.tag == "ref" and c.get("id") == film.get("id"))
        film = detached_copy(film)
        replace_ref(sensor, ref, film)
    return film


def set_film_size(root: ET.Element, sensor: ET.Element, resolution: tuple[int, int]) -> None:
    """Give the sensor's own film this size; a crop window goes, so the image is the size asked
    for (a crop would override it, or not fit in it)."""
    film = own_film(root, sensor)
    for old in [c for c in film if c.get("name") in (*_SIZE, *_CROP)]:
        film.remove(old)
    for name, value in zip(_SIZE, resolution, strict=True):
        ET.SubElement(film, "integer", {"name": name, "value": str(value)})


def check_film_size(root: ET.Element, sensor: ET.Element, what: str) -> None:
    """Refuse a film larger than a job's ``resolution`` may be (e.g. ``$res`` = 99999): it
    would only fail at render time, for want of memory."""
    film = _child_object(root, sensor, "film")
    if film is None:
        return
    for name in _SIZE:
        prop = next((c for c in film if c.get("name") == name and c.tag == "integer"), None)
        if prop is None:
            continue
        text = (prop.get("value") or "").strip()
        if text.lstrip("+-").isdigit() and len(text) < 12 and int(text) > MAX_FILM_SIZE:
            raise SceneError(
                f"{what}: film {name} {int(text)} is larger than {MAX_FILM_SIZE}",
                where=where(prop) or where(film),
                hint="lower it in the scene (or its scene argument), or set the job's "
                "render.resolution",
            )


def _child_object(root: ET.Element, sensor: ET.Element, tag: str) -> ET.Element | None:
    inline = sensor.find(tag)
    if inline is not None:
        return inline
    return next(iter(refs_to(sensor, tag, objects_by_id(root))), None)  # shared by <ref>


def _add_look_at_sensor(
    root: ET.Element, camera: CameraSpec, template: ET.Element | None
) -> ET.Element:
    look_at = camera.look_at
    assert look_at is not None
    sensor = ET.SubElement(root, "sensor", {"type": "perspective", "id": OBJECTIVE_SENSOR_ID})
    ET.SubElement(sensor, "float", {"name": "fov", "value": repr(float(camera.fov))})
    transform = ET.SubElement(sensor, "transform", {"name": "to_world"})
    points = {"origin": look_at.origin, "target": look_at.target, "up": look_at.up}
    lookat = {key: ", ".join(repr(float(v)) for v in xyz) for key, xyz in points.items()}
    ET.SubElement(transform, "lookat", lookat)
    film = _child_object(root, template, "film") if template is not None else None
    if film is not None:
        sensor.append(detached_copy(film))
    else:
        film = ET.SubElement(sensor, "film", {"type": "hdrfilm"})
        ET.SubElement(film, "rfilter", {"type": "box"})
    set_film_size(root, sensor, camera.resolution or (256, 256))
    return sensor
