"""The scene corpus (scenes/corpus) through sensaov's rewrite, checked against Mitsuba itself.

Every corpus scene, with the arguments it needs, is loaded twice: by Mitsuba from the user's
files (``mi.load_file(path, optimize=False, **args)``) and by Mitsuba from the text
``prepare_xml`` writes. Both are rendered by one ``prb`` integrator object at the same
seed and spp, so the scenes' own integrators (``$integrator``) take no part and the sample
paths are the same. The images are compared with a tolerance, not bit for bit, for two
measured reasons: 8-bit bitmaps are loaded as float by the rewrite (sRGB decoded at load
instead of at lookup; differences up to ~4e-6), and the film's Gaussian and tent filters
splat samples with atomic adds whose order varies between threads (the same scene rendered
twice differs by ~1e-7).
"""

from __future__ import annotations

from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
import pytest
import yaml

from sensaov_cli.errors import SceneError
from sensaov_cli.job.load import load_job
from sensaov_cli.job.spec import CameraSpec
from sensaov_cli.render.loading import LoadedScene, load_job_scene
from sensaov_cli.scene.prepare import PreparedScene, prepare_xml

CORPUS = Path(__file__).resolve().parents[1] / "scenes" / "corpus"
# (scene folder, the scene arguments it is loaded with)
JOBS = [
    ("shaderball", {}),
    ("shaderball", {"material": "gold"}),
    ("cbox_spectral", {}),
    ("instanced_shelf", {}),
    ("texture_lab", {}),
    ("glass_table", {"ior": "1.5"}),
    ("emitter_zoo", {}),
]
MAX_DEPTH, SPP, SEED = 5, 4, 7


def prepared_corpus(name: str, args: dict[str, str], **options: Any) -> PreparedScene:
    settings: dict[str, Any] = {"camera": CameraSpec(name="objective"), "resolution": None}
    settings.update(options)
    return prepare_xml(
        CORPUS / name / "scene.xml",
        max_depth=MAX_DEPTH,
        shared="split",
        scene_args=args,
        **settings,
    )


@pytest.fixture(scope="session")
def integrator(mi: ModuleType) -> Any:
    return mi.load_dict({"type": "prb", "max_depth": MAX_DEPTH})


@pytest.mark.parametrize(
    ("name", "args"),
    JOBS,
    ids=[" ".join([n, *(f"{k}={v}" for k, v in a.items())]) for n, a in JOBS],
)
def test_rewritten_scene_renders_like_mitsubas_own_load(
    mi: ModuleType, integrator: Any, name: str, args: dict[str, str]
) -> None:
    original = mi.load_file(str(CORPUS / name / "scene.xml"), optimize=False, **args)
    prepared = prepared_corpus(name, args)
    # Loaded without any file resolver set-up: every name the scene reads is absolute.
    rewritten = mi.load_string(prepared.text, optimize=False)
    sensor = next(s for s in rewritten.sensors() if s.id() == prepared.sensor_id)
    expected = np.array(integrator.render(original, original.sensors()[0], seed=SEED, spp=SPP))
    image = np.array(integrator.render(rewritten, sensor, seed=SEED, spp=SPP))
    assert expected.mean() > 1e-3
    np.testing.assert_allclose(image, expected, rtol=1e-4, atol=1e-5)
    assert not [key for key in mi.traverse(rewritten).keys() if key.startswith("object_")]


def write_job(folder: Path, scene: Path, **overrides: Any) -> Path:
    job: dict[str, Any] = {
        "version": 1,
        "scene": str(scene),
        "variant": "llvm_ad_rgb",
        "render": {"spp": 4, "max_depth": MAX_DEPTH, "seed": 0},
        "objectives": [{"name": "mean_luma", "type": "mean_luminance"}],
        "output": str(folder / "out"),
    }
    job.update(overrides)
    path = folder / "job.yaml"
    path.write_text(yaml.safe_dump(job, sort_keys=False))
    return path


@pytest.fixture(scope="session")
def shelf(mi: ModuleType, tmp_path_factory: pytest.TempPathFactory) -> LoadedScene:
    """instanced_shelf with an inspection camera copying the objective sensor (its film has
    ``id="film"``) and a look_at one copying its film."""
    cameras = [
        {"name": "objective", "objective": True, "resolution": [16, 12]},
        {"name": "top", "look_at": {"origin": [0, 4, 1], "target": [0, 0, 0], "up": [0, 1, 0]}},
    ]
    scene = CORPUS / "instanced_shelf" / "scene.xml"
    path = write_job(tmp_path_factory.mktemp("shelf"), scene, inspection_cameras=cameras)
    spec = load_job(path)
    return load_job_scene(spec, spec.inspection_cameras)


def test_sensors_with_film_sampler_and_filter_ids_can_be_copied(shelf: LoadedScene) -> None:
    assert set(shelf.inspection_sensors) == {"objective", "top"}
    assert tuple(shelf.inspection_sensors["objective"].film().crop_size()) == (16, 12)
    assert shelf.resolution == (64, 48)  # the scene's own $resx/$resy: the job sets none


def test_keys_are_named_after_the_scene_and_stable(mi: ModuleType, shelf: LoadedScene) -> None:
    keys = set(shelf.params.keys())
    assert not [key for key in keys if key.startswith("object_")]
    # the top-level bitmap "floor_grid", used by floor_mat through <ref>
    assert {"floor_mat.reflectance.data", "wall_rectangle.to_world", "pot_group_2.to_world"} <= keys
    # Mitsuba's own keys for unnamed objects change on every load; these do not.
    loads = [prepared_corpus("instanced_shelf", {}).text for _ in range(2)]
    first, second = (set(mi.traverse(mi.load_string(t, optimize=False)).keys()) for t in loads)
    assert first == second and not [key for key in first if key.startswith("object_")]


def test_mitsubas_load_error_points_at_the_users_file(mi: ModuleType, tmp_path: Path) -> None:
    sensor = '<sensor type="perspective"><film type="hdrfilm"/></sensor>'
    scene = tmp_path / "scene.xml"
    scene.write_text(f'<scene version="3.0.0">\n{sensor}\n<include filename="ball.xml"/>\n</scene>')
    ball = tmp_path / "ball.xml"
    ball.write_text(
        '<scene version="3.0.0">\n<shape type="sphere">\n<float name="radius" value="x"/>'
    )
    ball.write_text(ball.read_text() + "</shape>\n</scene>\n")
    with pytest.raises(SceneError, match='could not parse floating point value "x"') as info:
        load_job_scene(load_job(write_job(tmp_path, scene)))
    assert info.value.where == f"{ball}:3"


def test_a_refd_film_and_a_crop_window_load_at_every_cameras_size(
    mi: ModuleType, tmp_path: Path
) -> None:
    # Review items 5 and 8: a <ref>'d film failed in project; a crop overrode the sizes asked.
    crop = "".join(
        f'<integer name="{n}" value="{v}"/>'
        for n, v in (("width", 32), ("height", 32), ("crop_offset_x", 8), ("crop_width", 16))
    )
    sensors = "".join(
        f'<sensor type="perspective" id="{i}"><ref id="film"/></sensor>' for i in ("a", "b")
    )
    scene = tmp_path / "scene.xml"
    scene.write_text(
        f'<scene version="3.0.0"><film type="hdrfilm" id="film">{crop}</film>{sensors}'
        '<shape type="sphere"/></scene>'
    )
    look = {"origin": [0, 0, 5], "target": [0, 0, 0], "up": [0, 1, 0]}
    cameras = [
        {"name": "objective", "objective": True},
        {"name": "other", "sensor": "b", "resolution": [6, 2]},
        {"name": "look", "look_at": look, "resolution": [3, 3]},
    ]
    job = write_job(tmp_path, scene, inspection_cameras=cameras, render={"resolution": [20, 10]})
    spec = load_job(job)
    loaded = load_job_scene(spec, spec.inspection_cameras)
    sizes = {n: tuple(s.film().crop_size()) for n, s in loaded.inspection_sensors.items()}
    assert sizes == {"objective": (20, 10), "other": (6, 2), "look": (3, 3)}
    assert loaded.resolution == (20, 10)


def shelf_gradients(mi: ModuleType, shared: str) -> dict[str, float]:
    """d(mean image)/d(base colour) of every pot_glaze copy, instanced_shelf at 16x12."""
    import drjit as dr

    prepared = prepare_xml(
        CORPUS / "instanced_shelf" / "scene.xml",
        max_depth=3,
        shared=shared,
        camera=CameraSpec(name="objective"),
        resolution=(16, 12),
    )
    scene = mi.load_string(prepared.text, optimize=False)
    params = mi.traverse(scene)
    keys = [key for key in params.keys() if key.endswith("base_color.value")]
    for key in keys:
        dr.enable_grad(params[key])
    params.update()
    integrator = mi.load_dict({"type": "prb", "max_depth": 3})
    image = mi.render(scene, params, integrator=integrator, seed=SEED, spp=SPP)
    dr.backward(dr.mean(image, axis=None))
    return {key: float(dr.sum(dr.grad(params[key]), axis=None)[0]) for key in keys}


def test_split_gives_each_instance_its_own_shapegroup_gradient(mi: ModuleType) -> None:
    # Review item 4: every instance got the whole shapegroup's gradient, split included.
    kept = shelf_gradients(mi, "keep")
    split = shelf_gradients(mi, "split")
    assert list(kept) == ["pot_glaze.base_color.value"]
    instances = ("pot_a", "pot_b", "pot_group_2")
    # the group copy for instance i is pot_group_i, its member blob is blob_i
    assert sorted(split) == [f"pot_group_{i}.blob_{i}.bsdf.base_color.value" for i in instances]
    assert len(set(split.values())) == 3  # each instance sees its own share
    assert sum(split.values()) == pytest.approx(kept["pot_glaze.base_color.value"], rel=1e-4)


def test_each_instance_owns_its_own_shapegroup_copy(shelf: LoadedScene) -> None:
    owners = {p.key: p.owners for p in shelf.selected if p.key.endswith("base_color.value")}
    assert owners == {
        f"pot_group_{i}.blob_{i}.bsdf.base_color.value": (i,)
        for i in ("pot_a", "pot_b", "pot_group_2")
    }
