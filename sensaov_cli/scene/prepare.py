"""A user's scene prepared for differentiation: expanded once, rewritten, fingerprinted.

The user's files are never modified: the scene is expanded as Mitsuba's parser reads it,
rewritten, and the text handed to ``mitsuba.load_string``; what the rewrite changes, and why,
is listed in ``PreparedScene.changes``. A top-level texture used through ``<ref>`` is written
where it is used, since Mitsuba keys a top-level bitmap by memory address and a nested one by
the path of its user (``floor_mat.reflectance.data``). A scene argument is never rewritten: to
change what the scene itself says (its film size, often ``$res``), set the argument.
"""

from __future__ import annotations

import copy
import hashlib
import os
import re
import xml.etree.ElementTree as ET
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from sensaov_cli.errors import SceneError, SpecError
from sensaov_cli.job.spec import CameraSpec, JobSpec, LookAt
from sensaov_cli.scene import naming
from sensaov_cli.scene.expand import expand_scene
from sensaov_cli.scene.integrator import IntegratorPlan, plan_integrator
from sensaov_cli.scene.source import Change, detached_copy, user_attributes, where, write_xml

_CHUNK = 1 << 20  # files are hashed a MiB at a time, never read whole
DEFAULT_FILTER, DEFAULT_WRAP = "bilinear", "repeat"  # a bitmap's lookup when the scene sets none


@dataclass(frozen=True)
class PreparedScene:
    path: Path  # the user's scene file
    text: str  # what Mitsuba loads
    sensor_id: str  # the objective camera's sensor in ``text``
    sensor_ids: tuple[str, ...]  # the scene's own sensors, unnamed ones named
    inspection_ids: dict[str, str]  # inspection camera name -> sensor id in ``text``
    split: dict[str, tuple[str, ...]]  # shared BSDF id -> the shapes that received a copy
    bitmap_files: tuple[str, ...]  # bitmap texture files, absolute where found
    bitmap_options: dict[str, tuple[str, str, str]]  # file base name -> filter, wrap, note
    materials: dict[str, str]  # shape id -> the BSDF id it uses, as the user named it
    instances: dict[str, str]  # instance shape id -> the shapegroup id it instantiates
    shapegroups: dict[str, tuple[str, ...]]  # shapegroup id -> ids of its member shapes
    textures: dict[str, tuple[str, ...]]  # top-level texture id -> "object.slot" of each use
    scene_args: dict[str, str]  # each $name the scene used and the value it got
    sample_count: int | None  # the objective sensor's sampler sample_count, as the scene says
    files: tuple[Path, ...]  # every file the scene reads
    search_path: tuple[Path, ...]  # folders Mitsuba resolves names still relative against
    line_sources: tuple[str | None, ...]  # line of `text` -> the user's file:line it came from
    integration: IntegratorPlan  # the scene's integrator and depth, and the replay's
    fingerprint: str  # sha256 of every file the scene reads and of the job's arguments
    changes: tuple[Change, ...]  # what was rewritten and why

    @property
    def replaced_integrator(self) -> str | None:
        """The scene's integrator when it renders other light transport than the replay."""
        return None if self.integration.same_transport else self.integration.scene_kind


def prepare_scene(job: JobSpec, cameras: tuple[CameraSpec, ...] = ()) -> PreparedScene:
    """The job's scene, prepared once for a command, with a sensor for each of ``cameras``.

    Every camera the job names is checked here, those not in ``cameras`` too, so ``validate``
    and ``run`` refuse a camera the scene lacks (or a film too large) before anything renders.
    """
    return prepare_xml(
        job.scene,
        max_depth=job.render.max_depth,
        camera=job.objective_camera,
        resolution=job.render.resolution,
        shared=job.parameters.shared,
        inspection=cameras,
        scene_args=job.scene_args,
        job=job,
    )


def prepare_xml(
    path: Path,
    *,
    max_depth: int | None,
    camera: CameraSpec,
    resolution: tuple[int, int] | None,
    shared: str,
    inspection: tuple[CameraSpec, ...] = (),
    scene_args: Mapping[str, object] | None = None,
    job: JobSpec | None = None,
) -> PreparedScene:
    """A scene file prepared with explicit settings; ``job``, where given, has all its cameras
    checked against the scene, with the job's keys named."""
    expanded = expand_scene(path, scene_args or {})
    root = expanded.root
    named = naming.name_objects(root)
    ids = (s.get("id", "") for s in root.findall("sensor"))
    own_sensors = tuple(i for i in ids if not i.startswith("sensaov_"))  # the prefix is sensaov's
    _check_camera_ids(path, own_sensors, camera, job.inspection_cameras if job else inspection, job)
    _refuse_non_finite_numbers(root)
    changes = list(expanded.changes)  # old formats upgraded, each with its line
    changes += [Change(f"named {e.tag} {i!r}", _UNNAMED, where(e)) for i, e in named.items()]
    integration = plan_integrator(root, max_depth, changes)
    bitmaps = _bitmaps_as_float(root, changes)
    groups = naming.split_shapegroups(root) if shared == "split" else {}  # before the BSDFs
    materials = naming.materials(root)  # before splitting: copies keep the user's name
    textures = naming.place_textures(root, copies=shared == "split")
    split = naming.split_shared_bsdfs(root) if shared == "split" else {}
    placed = _OWN if shared == "split" else _TOP_BITMAP
    changes += [Change(f"shapegroup {g!r} copied for {', '.join(i)}", _OWN, "")
                for g, i in groups.items()]  # fmt: skip
    changes += [Change(f"texture {t!r} written into {', '.join(u)}", placed, "")
                for t, u in textures.items()]  # fmt: skip
    changes += [Change(f"bsdf {b!r} copied into {', '.join(s)}", _OWN, "")
                for b, s in split.items()]  # fmt: skip
    sensor, inspection_ids = _cameras(root, camera, resolution, inspection)
    others = () if job is None else tuple(c for c in job.inspection_cameras if c not in inspection)
    if others:  # cameras this command does not load: placed on a copy, to refuse them early
        _cameras(copy.deepcopy(root), camera, resolution, others)
    text, line_sources = write_xml(root)
    job_args = {name: a.value for name, a in expanded.arguments.items() if a.origin == "job"}
    return PreparedScene(
        path=path,
        text=text,
        sensor_id=sensor.get("id", ""),
        sensor_ids=own_sensors,
        inspection_ids=inspection_ids,
        split=split,
        bitmap_files=bitmaps,
        bitmap_options=_bitmap_options(root),
        materials=materials,
        instances=naming.instances(root),
        shapegroups=naming.shapegroups(root),
        textures=textures,
        scene_args={name: a.value for name, a in expanded.arguments.items()},
        sample_count=sample_count(root, sensor),
        files=expanded.files,
        search_path=expanded.search_path,
        line_sources=line_sources,
        integration=integration,
        fingerprint=_fingerprint(expanded.files, job_args, path.parent),
        changes=tuple(changes),
    )


_UNNAMED = "Mitsuba keys an unnamed object by its memory address, new on every run"
_EIGHT_BIT = "format = variant: an 8-bit texture would load as integers, which get no gradient"
_OWN = "each use gets its own parameters, so each object its own gradient (shared: split)"
_TOP_BITMAP = "Mitsuba keys a top-level bitmap by memory address"


# --- cameras: ids are global in one Mitsuba scene (films, samplers and filters too), so a sensor
# copied for an inspection camera (or a film copied for a look-at camera) loses the ids of the
# objects it carried (its <ref>s keep theirs). A film shared between sensors by <ref> is copied
# into a sensor before that sensor's film is resized, so resizing one camera never resizes
# another.

OBJECTIVE_SENSOR_ID = "sensaov_objective"
MAX_FILM_SIZE = 16384  # the largest width or height a job's resolution may ask for
_SIZE = ("width", "height")
_CROP = ("crop_offset_x", "crop_offset_y", "crop_width", "crop_height")
INSPECTION_PREFIX = "sensaov_inspect_"


def _check_camera_ids(
    scene: Path,
    ids: tuple[str, ...],
    camera: CameraSpec,
    inspection: tuple[CameraSpec, ...],
    job: JobSpec | None,
) -> None:
    """Refuse cameras that name a sensor the scene lacks, naming the job's key, before any
    camera is placed (choose_sensor relies on it)."""
    if not ids and camera.look_at is None:
        raise SceneError(
            "the scene has no sensor",
            where=str(scene),
            hint="add one, or give objective_camera a look_at",
        )
    named = [("objective_camera", camera)]
    named += [(f"inspection_cameras[{i}].sensor", c) for i, c in enumerate(inspection)]
    for key, each in named:
        if each.sensor is not None and each.sensor not in ids:
            raise SpecError(
                f"no sensor with id {each.sensor!r} in {scene.name}",
                where=f"{job.path}: {key}" if job is not None else key,
                hint=f"sensors in the scene: {', '.join(ids) or 'none'}",
            )


def _cameras(
    root: ET.Element,
    camera: CameraSpec,
    resolution: tuple[int, int] | None,
    inspection: tuple[CameraSpec, ...],
) -> tuple[ET.Element, dict[str, str]]:
    """The objective sensor, and each inspection camera's own sensor id."""
    sensor = choose_sensor(root, camera)
    if resolution is not None:
        set_film_size(root, sensor, resolution)
    check_film_size(root, sensor, "objective camera")
    return sensor, {c.name: add_inspection_sensor(root, c, sensor) for c in inspection}


def choose_sensor(root: ET.Element, camera: CameraSpec) -> ET.Element:
    """The camera's sensor, the first where it names none (_check_camera_ids checked it exists)."""
    sensors = root.findall("sensor")
    if camera.look_at is not None:
        return _add_look_at_sensor(root, camera, camera.look_at, sensors[0] if sensors else None)
    return next(s for s in sensors if camera.sensor in (None, s.get("id")))


def add_inspection_sensor(root: ET.Element, camera: CameraSpec, objective: ET.Element) -> str:
    """A sensor of its own for each inspection camera, so resolution overrides stay local."""
    if camera.look_at is not None:
        source = _add_look_at_sensor(root, camera, camera.look_at, objective)
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
    value = naming.child_value(sampler, "sample_count") if sampler is not None else None
    return int(value) if value is not None and value.strip().lstrip("-").isdigit() else None


def own_film(root: ET.Element, sensor: ET.Element) -> ET.Element:
    """The sensor's film as an element of its own (a ``<ref>``'d film is copied in)."""
    film = _child_object(root, sensor, "film")
    if film is None:
        return ET.SubElement(sensor, "film", {"type": "hdrfilm"})
    if sensor.find("film") is None:  # shared by <ref>
        ref = next(c for c in sensor if c.tag == "ref" and c.get("id") == film.get("id"))
        film = detached_copy(film)
        naming.replace_ref(sensor, ref, film)
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
    return next(
        iter(naming.refs_to(sensor, tag, naming.objects_by_id(root))), None
    )  # shared by <ref>


def _add_look_at_sensor(
    root: ET.Element, camera: CameraSpec, look_at: LookAt, template: ET.Element | None
) -> ET.Element:
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


def _fingerprint(files: tuple[Path, ...], scene_args: Mapping[str, str], base: Path) -> str:
    """sha256 over every file the scene reads and the job's scene arguments: an edit counts."""
    digest = hashlib.sha256()
    for name, value in sorted(scene_args.items()):
        digest.update(f"arg\0{name}\0{value}\0".encode())
    for file in files:
        # Names relative to the scene folder: moving the whole project keeps the fingerprint.
        label = os.path.relpath(file, base.absolute()) if file.is_absolute() else str(file)
        if not file.is_file():
            digest.update(f"missing\0{label}\0".encode())
            continue
        digest.update(f"file\0{label}\0{file.stat().st_size}\0".encode())
        with file.open("rb") as stream:
            while chunk := stream.read(_CHUNK):
                digest.update(chunk)
    return digest.hexdigest()


# --- bitmaps: loaded as float; their lookup settings, which the plugin's binding hides ---


def _bitmaps_as_float(root: ET.Element, changes: list[Change]) -> tuple[str, ...]:
    """Load every bitmap texture that has no ``format`` as float, so its texels receive
    gradients (envmaps load theirs as float already); returns every bitmap's file name."""
    files = []
    for texture in root.iter("texture"):
        if texture.get("type") != "bitmap":
            continue
        filename = naming.child_value(texture, "filename")
        if filename is not None:
            files.append(filename)
        if naming.child_value(texture, "format") is None:
            ET.SubElement(texture, "string", {"name": "format", "value": "variant"})
            name = Path(filename or "(no file)").name
            changes.append(Change(f"bitmap {name} loaded as float", _EIGHT_BIT, where(texture)))
    return tuple(files)


def _bitmap_options(root: ET.Element) -> dict[str, tuple[str, str, str]]:
    """File base name (the name the plugin prints) -> filter_type, wrap_mode of every bitmap, and
    a note where one file is used with several settings (the first is taken)."""
    options: dict[str, tuple[str, str, str]] = {}
    for texture in root.iter("texture"):
        filename = naming.child_value(texture, "filename")
        if texture.get("type") != "bitmap" or filename is None:
            continue
        found = (
            naming.child_value(texture, "filter_type") or DEFAULT_FILTER,
            naming.child_value(texture, "wrap_mode") or DEFAULT_WRAP,
        )
        name = Path(filename).name
        if name in options and options[name][:2] != found:
            note = f"{name} is used with several filter/wrap settings; the first is shown"
            options[name] = (*options[name][:2], note)
        else:
            options.setdefault(name, (*found, ""))
    return options


# --- numbers Mitsuba would read as NaN or infinity ---

_VALUE_TAGS = frozenset(
    "float rgb spectrum point vector translate scale rotate matrix lookat".split()
)
_NOT_NUMBERS = frozenset({"name", "id", "type", "filename"})
_SEPARATORS = re.compile(r"[\s,:]+")
FLOAT32_MAX = 3.4028234663852886e38


def _refuse_non_finite_numbers(root: ET.Element) -> None:
    """Raise :class:`SceneError` at the first value element holding NaN or an infinity.

    Mitsuba reads ``nan`` and ``inf`` (and ``1e39``, infinite as float32) wherever a number
    goes, and loads the scene; the run would then fail at the first objective, blaming it.
    """
    for element in (e for e in root.iter() if e.tag in _VALUE_TAGS):
        for attribute, text in user_attributes(element):
            if attribute in _NOT_NUMBERS:
                continue
            bad = next((t for t in _SEPARATORS.split(text) if _not_finite(t)), None)
            if bad is not None:
                name = element.get("name")
                what = f'<{element.tag} name="{name}">' if name else f"<{element.tag}>"
                raise SceneError(
                    f"{what} {attribute}={bad!r} is not a finite number",
                    where=where(element),
                    hint="Mitsuba would load it and render NaN: write a finite float32, "
                    "at most 3.4e38",
                )


def _not_finite(token: str) -> bool:
    try:
        value = float(token)
    except ValueError:
        return False  # not a number at all: Mitsuba says so itself
    return not abs(value) <= FLOAT32_MAX  # NaN too
