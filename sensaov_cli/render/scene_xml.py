"""Rewrite a Mitsuba 3 scene description before loading it (pure XML, no Mitsuba import).

The user's files are never modified. The scene is first expanded as Mitsuba's parser reads it
(scene_expand.py: includes, ``$name`` arguments, ``<path>``, aliases, file names made
absolute), then rewritten, and the text is handed to ``mitsuba.load_string``. What the rewrite
changes, and why:

- every integrator is replaced by ``prb`` (``prbvolpath`` for a ``volpath`` scene, so media
  stay in the image) with the job's ``max_depth`` and the scene's ``hide_emitters`` and
  ``rr_depth`` (``path`` costs memory that grows with spp under AD; ``prb`` is
  constant-memory, MITSUBA-NOTES); an integrator that renders other light transport
  (``direct``, ``aov``, …) is reported, since the objective then sees another image;
- bitmap textures, nested ones too, load as float (``format = variant``) so their texels
  receive gradients (8-bit textures load as non-differentiable integers by default); envmaps
  load their images as float already and take no ``format``;
- unnamed objects get stable ids people recognise (scene_names.py); Mitsuba would key them by
  memory address;
- a top-level texture used through ``<ref>`` is written where it is used: Mitsuba keys a
  top-level bitmap by memory address (its id is lost when the plugin expands), a nested one by
  the path of its user (``floor_mat.reflectance.data``). With ``shared: split`` each use gets
  its own copy (its own parameters, like split BSDFs); with ``keep`` the texture moves into its
  first user and the other uses keep referring to it;
- with ``shared: split``, a BSDF used by several shapes is copied into each of them, so each
  object gets its own gradient (the copies' gradients sum to the shared one); a shapegroup
  used by several instances is copied for each instance first (scene_share.py);
- the objective camera is chosen, added (inline ``look_at``) or resized, and each inspection
  camera gets a sensor of its own (scene_sensors.py).

Scene arguments and the job's render settings: ``scene_args`` fill the scene's ``$name``s as
``mitsuba.load_file(path, **scene_args)`` would, and the values used are recorded
(``PreparedXml.scene_args``). sensaov renders with the job's ``render.spp`` and, when given,
``render.resolution``; the scene's own film size (often ``$res``) is used when the job leaves
the resolution unset, and its sampler's ``sample_count`` (often ``$spp``) is reported as
``PreparedXml.sample_count`` for a job that leaves spp unset. A scene argument is never
rewritten: to change what the scene itself says, set the argument.
"""

from __future__ import annotations

import hashlib
import os
import xml.etree.ElementTree as ET
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from sensaov_cli.errors import SceneError, SpecError
from sensaov_cli.render import scene_names
from sensaov_cli.render.scene_expand import SceneArgument, expand_scene
from sensaov_cli.render.scene_sensors import (
    add_inspection_sensor,
    check_film_size,
    choose_sensor,
    sample_count,
    sensor_ids,
    set_film_size,
)
from sensaov_cli.render.scene_share import (
    place_textures,
    split_shapegroups,
    split_shared_bsdfs,
)
from sensaov_cli.render.scene_source import locate_load_error, write_xml
from sensaov_cli.spec.model import CameraSpec, JobSpec

_CHUNK = 1 << 20  # files are hashed a MiB at a time, never read whole


@dataclass(frozen=True)
class PreparedXml:
    text: str
    sensor_id: str
    inspection_ids: dict[str, str]  # inspection camera name -> sensor id in the prepared scene
    split: dict[str, tuple[str, ...]]  # shared BSDF id -> the shapes that received a copy
    bitmap_files: tuple[str, ...]  # bitmap texture files, absolute where found
    materials: dict[str, str]  # shape id -> the BSDF id it uses, as the user named it
    instances: dict[str, str]  # instance shape id -> the shapegroup id it instantiates
    shapegroups: dict[str, tuple[str, ...]]  # shapegroup id -> ids of its member shapes
    textures: dict[str, tuple[str, ...]]  # top-level texture id -> "object.slot" of each use
    scene_args: dict[str, SceneArgument]  # each $name the scene used, its value and origin
    sample_count: int | None  # the objective sensor's sampler sample_count, as the scene says
    files: tuple[Path, ...]  # every file the scene reads (for the fingerprint)
    search_path: tuple[Path, ...]  # folders Mitsuba resolves names still relative against
    line_sources: tuple[str | None, ...]  # line of `text` -> the user's file:line it came from
    replaced_integrator: str | None  # the scene's integrator, if it renders other transport

    def locate(self, message: str) -> tuple[str, str | None]:
        """Mitsuba's load error on ``text`` -> (one-line message, the user's file:line)."""
        return locate_load_error(message, self.line_sources)


def prepare_scene_xml(
    path: Path,
    *,
    max_depth: int,
    camera: CameraSpec,
    resolution: tuple[int, int] | None,
    shared: str,
    inspection: tuple[CameraSpec, ...] = (),
    scene_args: Mapping[str, str] | None = None,
) -> PreparedXml:
    expanded = expand_scene(path, scene_args or {})
    root = expanded.root
    scene_names.name_objects(root)
    replaced = _replace_integrator(root, max_depth)
    bitmaps = _bitmaps_as_float(root)
    if shared == "split":
        split_shapegroups(root)  # before the BSDFs: a copied group's BSDFs split per shape
    materials = scene_names.materials(root)  # before splitting: copies keep the user's name
    textures = place_textures(root, copies=shared == "split")
    split = split_shared_bsdfs(root) if shared == "split" else {}
    sensor, inspection_ids = _cameras(root, path, camera, resolution, inspection)
    text, line_sources = write_xml(root)
    return PreparedXml(
        text=text,
        sensor_id=sensor.get("id", ""),
        inspection_ids=inspection_ids,
        split=split,
        bitmap_files=bitmaps,
        materials=materials,
        instances=scene_names.instances(root),
        shapegroups=scene_names.shapegroups(root),
        textures=textures,
        scene_args=expanded.arguments,
        sample_count=sample_count(root, sensor),
        files=expanded.files,
        search_path=expanded.search_path,
        line_sources=line_sources,
        replaced_integrator=replaced,
    )


def _cameras(
    root: ET.Element,
    path: Path,
    camera: CameraSpec,
    resolution: tuple[int, int] | None,
    inspection: tuple[CameraSpec, ...],
) -> tuple[ET.Element, dict[str, str]]:
    """The objective sensor, and each inspection camera's own sensor id."""
    sensor = choose_sensor(root, camera, path)
    if resolution is not None:
        set_film_size(root, sensor, resolution)
    check_film_size(root, sensor, "objective camera")
    where = "inspection camera {!r}: sensor"
    return sensor, {
        cam.name: add_inspection_sensor(root, cam, sensor, path, where.format(cam.name))
        for cam in inspection
    }


def scene_sensor_ids(path: Path, scene_args: Mapping[str, str] | None = None) -> tuple[str, ...]:
    """The ids of the scene's sensors, includes followed, unnamed ones named as when loading
    (no Mitsuba import: ``validate`` checks camera ids with it)."""
    root = expand_scene(path, scene_args or {}).root
    scene_names.name_objects(root)
    return sensor_ids(root)


def check_cameras(job: JobSpec) -> tuple[str, ...]:
    """The scene's sensor ids, after refusing a job whose cameras name a sensor it lacks.

    Pure XML, so ``validate`` catches the mistake without Mitsuba, and ``run`` before it
    renders anything (not ``project``, after the expensive part). The scene is then prepared
    as ``run`` and ``project`` prepare it, so what that refuses is refused here too.
    """
    ids = scene_sensor_ids(job.scene, job.scene_args)
    if not ids and job.objective_camera.look_at is None:
        raise SceneError(
            "the scene has no sensor",
            where=str(job.scene),
            hint="add one, or give objective_camera a look_at",
        )
    named = [("objective_camera", job.objective_camera)]
    named += [(f"inspection_cameras[{i}].sensor", c) for i, c in enumerate(job.inspection_cameras)]
    for where, camera in named:
        if camera.sensor is not None and camera.sensor not in ids:
            raise SpecError(
                f"no sensor with id {camera.sensor!r} in {job.scene.name}",
                where=f"{job.path}: {where}",
                hint=f"sensors in the scene: {', '.join(ids) or 'none'}",
            )
    # The whole preparation, inspection cameras included: what it refuses (a missing mesh, a
    # film too large, an element Mitsuba does not read) is refused before anything renders.
    prepare_scene_xml(
        job.scene,
        max_depth=job.render.max_depth,
        camera=job.objective_camera,
        resolution=job.render.resolution,
        shared=job.parameters.shared,
        inspection=job.inspection_cameras,
        scene_args=job.scene_args,
    )
    return ids


def scene_fingerprint(path: Path, scene_args: Mapping[str, str] | None = None) -> str:
    """sha256 over every file the scene reads (the scene, its includes, meshes, textures,
    envmaps, spectra) and the scene arguments, so an edit to any of them counts."""
    expanded = expand_scene(path, scene_args or {})
    return files_fingerprint(expanded.files, scene_args or {}, path.parent)


def files_fingerprint(files: tuple[Path, ...], scene_args: Mapping[str, str], base: Path) -> str:
    """The fingerprint of a prepared scene (its ``files``), without expanding it again."""
    digest = hashlib.sha256()
    for name, value in sorted((str(k), str(v)) for k, v in scene_args.items()):
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


# The user's integrator -> the path-replay one that differentiates the same light transport:
# volumetric path tracers keep their media (prb ignores them), everything else becomes prb.
_REPLAY_OF = {"volpath": "prbvolpath", "volpathmis": "prbvolpath", "prbvolpath": "prbvolpath"}
# What sensaov replaces without changing the image the objective sees (max_depth is the job's).
_SAME_TRANSPORT = frozenset({"path", "prb", "prb_basic", "direct_projective", *_REPLAY_OF})
# Integrator settings that change the image and that prb and prbvolpath take as they are.
_KEPT_SETTINGS = ("hide_emitters", "rr_depth")


def _replace_integrator(root: ET.Element, max_depth: int) -> str | None:
    """Put the replay integrator in place of the scene's; return the scene's integrator type
    when it renders other light transport than the replacement (``direct``, ``aov``, …)."""
    found = root.findall("integrator")
    user = found[0] if found else None
    kind = user.get("type", "path") if user is not None else "path"
    for element in found:
        root.remove(element)
    integrator = ET.Element("integrator", {"type": _REPLAY_OF.get(kind, "prb")})
    ET.SubElement(integrator, "integer", {"name": "max_depth", "value": str(max_depth)})
    for setting in user.iter() if user is not None else ():
        if setting is not user and setting.get("name") in _KEPT_SETTINGS:
            ET.SubElement(integrator, setting.tag, dict(setting.attrib))
    root.insert(0, integrator)
    return None if kind in _SAME_TRANSPORT else kind


def _bitmaps_as_float(root: ET.Element) -> tuple[str, ...]:
    files = []
    for texture in root.iter("texture"):
        if texture.get("type") != "bitmap":
            continue
        filename = scene_names.child_value(texture, "filename")
        if filename is not None:
            files.append(filename)
        if scene_names.child_value(texture, "format") is None:
            ET.SubElement(texture, "string", {"name": "format", "value": "variant"})
    return tuple(files)
