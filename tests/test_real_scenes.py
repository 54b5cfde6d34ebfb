"""Scenes as people write them (scenes/corpus): objects, types, cameras and arguments.

The corpus uses the constructs of Mitsuba's public scene data (includes, defaults, instancing,
nested textures, every emitter kind); these tests check what a user of such a scene sees:
objects named as the scene names them, instances as objects, types by the slot a parameter
fills, camera ids and scene arguments checked before anything renders, and ``run`` plus
``project --png`` going through on every scene with a plain job.
"""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET
from collections.abc import Callable
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
import pytest
import yaml

from sensaov_cli.buffer.npz import read_buffer
from sensaov_cli.errors import EXIT_BAD_INPUT, EXIT_OK
from sensaov_cli.job.load import load_job
from sensaov_cli.job.spec import CameraSpec, ChannelSpec
from sensaov_cli.outputs.exr import read_exr
from sensaov_cli.render.loading import LoadedScene, load_job_scene
from sensaov_cli.render.visibility import trace
from sensaov_cli.scene.prepare import prepare_xml
from sensaov_cli.views.channels import ChannelValues, paint_pass, robust_scale
from sensaov_cli.views.coverage import VisibilityPass, histogram, ranked
from tests.conftest import sensaov, write_job

CORPUS = Path(__file__).resolve().parents[1] / "scenes" / "corpus"
ARGS = {"glass_table": {"ior": 1.5}}
SCENES = ["shaderball", "cbox_spectral", "instanced_shelf", "texture_lab", "glass_table"]
SCENES += ["emitter_zoo"]


def corpus_job(folder: Path, scene: str, **overrides: object) -> Path:
    """A plain job on a corpus scene (32x24, 4 spp), with the arguments the scene needs."""
    settings: dict[str, Any] = {
        "render": {"spp": 4, "max_depth": 4, "seed": 0, "resolution": [32, 24]},
        "scene_args": ARGS.get(scene, {}),
    }
    settings.update(overrides)
    path = write_job(folder, **settings)
    job = yaml.safe_load(path.read_text())
    job["scene"] = str(CORPUS / scene / "scene.xml")
    path.write_text(yaml.safe_dump(job, sort_keys=False))
    return path


@pytest.fixture(scope="session")
def corpus_scene(
    mi: ModuleType, tmp_path_factory: pytest.TempPathFactory
) -> Callable[[str], LoadedScene]:
    loaded: dict[str, LoadedScene] = {}

    def load(scene: str) -> LoadedScene:
        if scene not in loaded:
            job = corpus_job(tmp_path_factory.mktemp(scene), scene)
            loaded[scene] = load_job_scene(load_job(job))
        return loaded[scene]

    return load


def owners(loaded: LoadedScene, key: str) -> tuple[str, ...]:
    return next(p.owners for p in loaded.selected if p.key == key)


def types(loaded: LoadedScene) -> dict[str, str]:
    return {p.key: p.type for p in loaded.selected}


def test_instances_are_objects_owning_their_shapegroup(corpus_scene: Any) -> None:
    """With shared: split (the default) each instance owns its own copy of the group."""
    shelf = corpus_scene("instanced_shelf")
    instances = ("pot_a", "pot_b", "pot_group_2")  # the third has no id in the scene
    assert set(instances) <= set(shelf.objects)
    glazes = [p for p in shelf.selected if p.key.endswith("bsdf.base_color.value")]
    assert sorted(p.owners for p in glazes) == [(name,) for name in sorted(instances)]


def test_instances_are_seen_by_the_visibility_pass(mi: ModuleType, corpus_scene: Any) -> None:
    shelf = corpus_scene("instanced_shelf")
    vis = trace(mi, shelf.scene, shelf.sensor, shelf.objects, 2)
    seen = set(vis.visible_objects)
    assert {"pot_a", "pot_b", "pot_group_2", "shelf_board"} <= seen


def test_unnamed_objects_are_named_from_the_scene(corpus_scene: Any) -> None:
    zoo = corpus_scene("emitter_zoo")
    assert "strip_light" in zoo.objects  # an area light's id names its unnamed shape
    assert "point_light" in zoo.objects  # a lone emitter is named by its type
    assert not [name for name in zoo.objects if name.startswith(("shape_", "emitter_"))]


def test_types_follow_the_slot_through_nested_textures(corpus_scene: Any) -> None:
    lab = types(corpus_scene("texture_lab"))
    assert lab["checker_metal.alpha.color0.value"] == "roughness"
    assert lab["nested_mat.reflectance.color0.data"] == "reflectance"
    assert {t for k, t in lab.items() if ".color" in k and "floor" in k} == {"reflectance"}
    assert lab["spot_key.texture.value"] == "radiance"


def test_envmap_parameters_are_radiance(corpus_scene: Any) -> None:
    ball = corpus_scene("shaderball")
    envmap = {k: t for k, t in types(ball).items() if k.startswith("sky.")}
    assert envmap and set(envmap.values()) == {"radiance"}, envmap


def test_keys_are_stable_and_carry_no_address(corpus_scene: Any) -> None:
    shelf = corpus_scene("instanced_shelf")
    keys = [p.key for p in shelf.selected]
    assert "floor_mat.reflectance.data" in keys  # a top-level texture used through <ref>
    assert not [k for k in keys if k.startswith("object_")]


def test_validate_checks_sensor_ids_without_mitsuba(tmp_path: Path) -> None:
    job = corpus_job(tmp_path, "texture_lab", objective_camera="no_such_camera")
    result = sensaov("validate", str(job))
    assert result.returncode == EXIT_BAD_INPUT
    assert "no sensor with id 'no_such_camera'" in result.stderr
    assert "sensors in the scene: camera" in result.stderr


def test_run_refuses_an_unknown_inspection_camera_before_rendering(tmp_path: Path) -> None:
    cameras = [{"name": "side", "sensor": "missing"}]
    job = corpus_job(tmp_path, "texture_lab", inspection_cameras=cameras)
    result = sensaov("run", str(job))
    assert result.returncode == EXIT_BAD_INPUT
    assert "inspection_cameras[0].sensor" in result.stderr
    assert "rendering" not in result.stderr and not (tmp_path / "out").exists()


def test_a_scene_argument_without_default_must_be_given(tmp_path: Path) -> None:
    job = corpus_job(tmp_path, "glass_table", scene_args={})
    result = sensaov("validate", str(job))
    assert result.returncode == EXIT_BAD_INPUT
    assert "$ior" in result.stderr and "scene_args" in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1


@pytest.mark.slow
@pytest.mark.parametrize("scene", SCENES)
def test_run_and_project_go_through_on_every_corpus_scene(tmp_path: Path, scene: str) -> None:
    cameras = [{"name": "objective", "objective": True}]
    job = corpus_job(tmp_path, scene, inspection_cameras=cameras)
    for command in (("run", str(job)), ("project", str(job), "--png")):
        result = sensaov(*command)
        assert result.returncode == EXIT_OK, result.stderr
    buffer = read_buffer(tmp_path / "out" / "buffer.npz")
    recorded = buffer.provenance["scene_args"]  # every $name used, the scene's defaults too
    assert {k: str(v) for k, v in ARGS.get(scene, {}).items()}.items() <= recorded.items()
    channels, header = read_exr(tmp_path / "out" / "objective.exr")
    assert any(name.startswith("CryptoObject") for name in channels)
    assert list((tmp_path / "out" / "previews").glob("*.png"))
    invisible = {name for key, value in header.items() if key.endswith("/invisible")
                 for name in json.loads(value)}  # fmt: skip
    if scene in ("emitter_zoo", "instanced_shelf"):  # lights no camera sees are listed
        assert invisible


def test_display_scales_never_read_what_no_camera_sees() -> None:
    objects = ("ball", "sky")
    coverage = histogram(np.zeros((4, 2), np.int32))  # every sample hits the ball
    index, amount = ranked(coverage, (2, 2), 2)
    vis = VisibilityPass(2, 2, 2, objects, None, coverage, index, amount)
    channel = ChannelSpec("objects", "object", normalize="shared")
    values = ChannelValues(
        objective="m",
        pass_name="objects",
        spec=channel,
        selection="all",
        keys=("ball.x", "sky.data"),
        magnitudes=np.array([0.1, 10.0]),
        signed_sums=np.array([0.1, 10.0]),
        unverified=(),
    )
    painted = paint_pass(values, vis)
    # Encoded on the camera-independent scale (the sky's 10); its display scale reads only the
    # pixels this camera paints: the ball's 0.1, encoded as 0.01.
    assert painted.scale.scale == pytest.approx(10.0)
    assert painted.invisible == ("sky",)
    scale = robust_scale({"cam": [painted.data]})
    assert scale.value == pytest.approx(0.01) and scale.clipped == 0.0


def integrator_of(tmp_path: Path, integrator: str) -> tuple[ET.Element, str | None]:
    scene = tmp_path / "scene.xml"
    scene.write_text(
        f'<scene version="3.0.0">{integrator}'
        '<sensor type="perspective"><film type="hdrfilm"/></sensor>'
        '<shape type="sphere" id="ball"/></scene>'
    )
    prepared = prepare_xml(
        scene, max_depth=4, camera=CameraSpec("objective"), resolution=None, shared="split"
    )
    return ET.fromstring(prepared.text).find("integrator"), prepared.replaced_integrator


def test_integrator_settings_that_change_the_image_are_kept(tmp_path: Path) -> None:
    settings = '<boolean name="hide_emitters" value="true"/><integer name="rr_depth" value="3"/>'
    integrator, replaced = integrator_of(
        tmp_path, f'<integrator type="path">{settings}</integrator>'
    )
    assert integrator is not None and integrator.get("type") == "prb" and replaced is None
    kept = {child.get("name"): child.get("value") for child in integrator}
    assert kept == {"max_depth": "4", "hide_emitters": "true", "rr_depth": "3"}


def test_a_volumetric_scene_keeps_its_media(tmp_path: Path) -> None:
    integrator, replaced = integrator_of(tmp_path, '<integrator type="volpath"/>')
    assert integrator is not None and integrator.get("type") == "prbvolpath" and replaced is None


def test_an_integrator_rendering_other_transport_is_reported(tmp_path: Path) -> None:
    integrator, replaced = integrator_of(tmp_path, '<integrator type="depth"/>')
    assert integrator is not None and integrator.get("type") == "prb"
    assert replaced == "depth"


def test_spectral_colour_coefficients_are_not_trusted(tmp_path: Path) -> None:
    job = write_job(tmp_path, variant="llvm_ad_spectral")
    result = sensaov("params", str(job), "--json")
    assert result.returncode == EXIT_OK, result.stderr
    selected = {p["key"]: p for p in json.loads(result.stdout)["selected"]}
    colour = selected["green.reflectance.value"]
    assert colour["trust"] == "unverified" and "spectral-upsampling" in colour["note"]
    assert selected["glass.eta"]["trust"] != "unverified"  # a plain float is what it says
