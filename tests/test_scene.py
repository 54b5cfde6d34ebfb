"""Scene loading and parameter selection on the shipped scenes (no rendering)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from types import ModuleType

import pytest

from sensaov_cli.errors import SceneError, SpecError
from sensaov_cli.job.load import load_job
from sensaov_cli.render.loading import LoadedScene, load_job_scene
from sensaov_cli.scene.prepare import prepare_xml

SPLIT_WHITE = ("back_wall", "ceiling", "floor", "light")


@pytest.fixture(scope="session")
def cbox(mi: ModuleType, job_writer: Callable[..., Path]) -> LoadedScene:
    return load_job_scene(load_job(job_writer("cbox_scene")))


def by_key(loaded: LoadedScene) -> dict[str, object]:
    return {info.key: info for info in loaded.selected}


def test_default_selection_is_materials_and_emitters(cbox: LoadedScene) -> None:
    selected = by_key(cbox)
    assert {info.type for info in cbox.selected} == {"reflectance", "roughness", "eta", "radiance"}
    assert not any("vertex_" in key or "to_world" in key for key in selected)
    assert "light.emitter.radiance.value" in selected
    reasons = {item.key: item.reason for item in cbox.excluded}
    assert reasons["tall_box.vertex_positions"].startswith("geometry")
    assert "NonDifferentiable" in reasons["checker.reflectance.to_uv"]


def test_type_is_the_slot_not_the_storage(cbox: LoadedScene) -> None:
    types = {info.key: info.type for info in cbox.selected}
    assert types["green.reflectance.value"] == "reflectance"
    assert types["checker.reflectance.data"] == "reflectance"
    assert types["blue_plastic.diffuse_reflectance.value"] == "reflectance"
    assert types["glass.alpha.value"] == types["blue_plastic.alpha"] == "roughness"
    assert types["glass.eta"] == "eta"


def test_8bit_texture_is_loaded_as_float_and_reported(cbox: LoadedScene) -> None:
    texture = by_key(cbox)["checker.reflectance.data"]
    source = cbox.textures[texture.key]
    assert texture.is_texture and source.converted
    assert texture.shape == (32, 32, 3)
    assert source.file is not None and source.file.endswith("wall.png")


def test_discontinuous_parameters_are_kept_and_flagged(cbox: LoadedScene) -> None:
    assert by_key(cbox)["glass.eta"].flags == ("discontinuous",)  # type: ignore[attr-defined]
    assert by_key(cbox)["green.reflectance.value"].flags == ()  # type: ignore[attr-defined]


def test_known_biased_parameters_are_marked_unverified(cbox: LoadedScene) -> None:
    alpha = by_key(cbox)["blue_plastic.alpha"]
    assert not alpha.verified and "known biased" in alpha.note  # type: ignore[attr-defined]
    assert by_key(cbox)["light.emitter.radiance.value"].verified  # type: ignore[attr-defined]


def test_shared_bsdf_is_split_into_one_key_per_object(cbox: LoadedScene) -> None:
    assert sorted(cbox.prepared.split["white"]) == list(SPLIT_WHITE)
    for shape in SPLIT_WHITE:
        assert by_key(cbox)[f"{shape}.bsdf.reflectance.value"].owners == (shape,)  # type: ignore[attr-defined]


def test_keep_mode_gives_one_key_owned_by_every_user(
    mi: ModuleType, job_writer: Callable[..., Path]
) -> None:
    loaded = load_job_scene(load_job(job_writer("keep", parameters={"shared": "keep"})))
    assert by_key(loaded)["white.reflectance.value"].owners == SPLIT_WHITE  # type: ignore[attr-defined]
    assert loaded.prepared.split == {}


def test_geometry_enters_only_when_named(mi: ModuleType, job_writer: Callable[..., Path]) -> None:
    job = job_writer("geometry", parameters={"include": ["*", "tall_box.vertex_positions"]})
    selected = by_key(load_job_scene(load_job(job)))
    assert "tall_box.vertex_positions" in selected
    assert "short_box.vertex_positions" not in selected


def test_exclude_globs_remove_and_say_so(mi: ModuleType, job_writer: Callable[..., Path]) -> None:
    loaded = load_job_scene(load_job(job_writer("exclude", parameters={"exclude": ["*.eta"]})))
    assert not any(info.type == "eta" for info in loaded.selected)
    reasons = {item.key: item.reason for item in loaded.excluded}
    assert reasons["glass.eta"] == "excluded by parameters.exclude '*.eta'"


def test_hidden_light_and_indirect_wall_are_selected(
    mi: ModuleType, job_writer: Callable[..., Path]
) -> None:
    loaded = load_job_scene(load_job(job_writer("interior", scene="interior")))
    owners = {owner for info in loaded.selected for owner in info.owners}
    assert {"ceiling_light", "front_wall"} <= owners
    assert len(loaded.objects) >= 8


def test_unknown_sensor_names_the_ones_there(
    mi: ModuleType, job_writer: Callable[..., Path]
) -> None:
    # The job's key is named, as run and validate name it (the scene is prepared once).
    with pytest.raises(SpecError, match="no sensor with id 'nope'") as info:
        load_job_scene(load_job(job_writer("sensor", objective_camera="nope")))
    assert "sensor" in str(info.value.hint) and str(info.value.where).endswith("objective_camera")


def test_inline_look_at_camera_and_resolution(
    mi: ModuleType, job_writer: Callable[..., Path]
) -> None:
    camera = {"look_at": {"origin": [0, 0, 3], "target": [0, 0, 0], "up": [0, 1, 0]}, "fov": 30}
    render = {"spp": 4, "resolution": [20, 10]}
    loaded = load_job_scene(load_job(job_writer("lookat", objective_camera=camera, render=render)))
    assert loaded.sensor.id() == "sensaov_objective"
    assert loaded.resolution == (20, 10)


def test_malformed_scene_xml_names_file_and_line(tmp_path: Path) -> None:
    scene = tmp_path / "broken.xml"
    scene.write_text('<scene version="3.0.0">\n  <shape type="sphere">\n</scene>\n')
    job = load_job(_job_for(tmp_path, scene))
    with pytest.raises(SceneError, match="malformed XML") as info:
        prepare_xml(
            scene, max_depth=4, camera=job.objective_camera, resolution=None, shared="split"
        )
    assert f"{scene}:3" in str(info.value)


def _job_for(folder: Path, scene: Path) -> Path:
    job = folder / "job.yaml"
    job.write_text(f"version: 1\nscene: {scene}\nobjectives: [{{name: m, type: mean_luminance}}]\n")
    return job


def test_inspection_cameras_get_sensors_of_their_own(
    mi: ModuleType, job_writer: Callable[..., Path]
) -> None:
    cameras = [
        {"name": "corner", "sensor": "corner", "resolution": [30, 20]},
        {"name": "objective", "objective": True},
    ]
    job = load_job(job_writer("inspect", scene="interior", inspection_cameras=cameras))
    loaded = load_job_scene(job, job.inspection_cameras)
    corner = loaded.inspection_sensors["corner"]
    assert tuple(corner.film().crop_size()) == (30, 20)  # resized copy; the scene's is untouched
    assert tuple(loaded.inspection_sensors["objective"].film().crop_size()) == (24, 24)
    assert loaded.prepared.materials["front_wall"] == "front_paint"
