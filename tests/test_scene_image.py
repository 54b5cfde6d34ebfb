"""The image differentiated is the scene's: its integrator, depth and media.

Pure-XML plans first (which replay integrator, which depth, what is listed), then renders that
compare sensaov's primal with Mitsuba's own render of the unedited file.
"""

from __future__ import annotations

import json
import xml.etree.ElementTree as ET
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

from sensaov_cli.buffer.npz import read_buffer
from sensaov_cli.errors import EXIT_BAD_INPUT, EXIT_OK, SceneError
from sensaov_cli.job.load import load_job
from sensaov_cli.job.spec import CameraSpec
from sensaov_cli.render.adjoint import render_primal
from sensaov_cli.render.loading import load_job_scene
from sensaov_cli.render.objectives import REC709_LUMA
from sensaov_cli.scene.prepare import PreparedScene, prepare_xml
from sensaov_cli.scene.source import Change
from tests.conftest import sensaov, use_scene, write_job

HERE = Path(__file__).parent / "scenes"
BODY = '<sensor type="perspective"><film type="hdrfilm"/></sensor><shape type="sphere" id="ball"/>'


def prepared(tmp_path: Path, body: str, version: str = "3.0.0", **options: object) -> PreparedScene:
    scene = tmp_path / "scene.xml"
    scene.write_text(f'<scene version="{version}">{body}{BODY}</scene>')
    settings: dict = {"max_depth": None, "camera": CameraSpec("objective"), "resolution": None}
    settings.update(options)
    return prepare_xml(scene, shared="split", **settings)


def image_changes(scene: PreparedScene) -> list[Change]:
    """The changes after which M is measured on another image than the scene renders."""
    return [change for change in scene.changes if change.alters_image]


def replay(scene: PreparedScene) -> dict[str, str]:
    element = ET.fromstring(scene.text).find("integrator")
    assert element is not None
    return {
        "type": element.get("type", ""),
        **{c.get("name", ""): c.get("value", "") for c in element},
    }


def test_a_moment_wrapped_volpath_keeps_its_media_and_depth(tmp_path: Path) -> None:
    scene = prepared(
        tmp_path,
        '<integrator type="moment"><integrator type="volpath">'
        '<integer name="max_depth" value="9"/></integrator></integrator>',
    )
    assert replay(scene) == {"type": "prbvolpath", "max_depth": "9"}
    assert scene.integration.scene_kind == "volpath" and scene.replaced_integrator is None
    assert any("'moment' unwrapped" in c.what for c in scene.changes)
    assert not image_changes(scene)


def test_direct_is_one_bounce_of_the_path_replay(tmp_path: Path) -> None:
    scene = prepared(
        tmp_path,
        '<integrator type="direct"><boolean name="hide_emitters" value="true"/></integrator>',
    )
    assert replay(scene) == {"type": "prb", "max_depth": "2", "hide_emitters": "true"}
    assert scene.replaced_integrator is None and not image_changes(scene)


def test_the_depth_is_the_scenes_unless_the_job_sets_one(tmp_path: Path) -> None:
    own = prepared(tmp_path, "")  # no integrator: Mitsuba renders with path, unbounded
    assert replay(own)["max_depth"] == "-1" and own.integration.scene_image is None
    assert not image_changes(own)
    job = prepared(
        tmp_path,
        '<integrator type="path"><integer name="max_depth" value="12"/></integrator>',
        max_depth=6,
    )
    assert replay(job)["max_depth"] == "6"
    (change,) = image_changes(job)
    assert "the job's render.max_depth" in change.what and "depth 12" in change.why
    assert job.integration.scene_image == {"type": "prb", "max_depth": 12}
    same = prepared(
        tmp_path,
        '<integrator type="path"><integer name="max_depth" value="6"/></integrator>',
        max_depth=6,
    )
    assert not image_changes(same)


def test_an_old_estimator_becomes_the_path_tracer_with_the_scenes_depth(tmp_path: Path) -> None:
    body = '<integrator type="guided_path"><integer name="maxDepth" value="7"/></integrator>'
    scene = prepared(tmp_path, body, version="0.5.0")
    assert replay(scene) == {"type": "prb", "max_depth": "7"}
    (change,) = [c for c in scene.changes if "guided_path" in c.what]
    assert "Mitsuba 3 has no 'guided_path'" in change.why and not change.alters_image
    assert change.where.endswith("scene.xml:1")
    media = '<medium type="homogeneous" id="fog"/>'
    media += '<shape type="sphere"><ref name="interior" id="fog"/></shape>'
    assert replay(prepared(tmp_path, body + media, version="0.5.0"))["type"] == "prbvolpath"


def test_a_camera_inside_a_medium_is_refused_naming_it(tmp_path: Path) -> None:
    scene = tmp_path / "scene.xml"
    scene.write_text(
        '<scene version="3.0.0"><integrator type="volpath"/><medium type="homogeneous" id="fog"/>'
        '<sensor type="perspective"><ref name="medium" id="fog"/><film type="hdrfilm"/></sensor>'
        "</scene>"
    )
    with pytest.raises(SceneError, match="camera inside medium 'fog'"):
        prepare_xml(
            scene, max_depth=None, camera=CameraSpec("objective"), resolution=None, shared="split"
        )


def luminance(image: np.ndarray) -> float:
    return float((np.asarray(image)[..., :3] @ np.array(REC709_LUMA)).mean())


def mitsuba_mean(mi: ModuleType, scene: Path, spp: int, seeds: range) -> tuple[float, float]:
    """Mean luminance of Mitsuba's own render of the unedited file: mean and standard error."""
    loaded = mi.load_file(str(scene))
    values = [luminance(mi.render(loaded, spp=spp, seed=seed)) for seed in seeds]
    return float(np.mean(values)), float(np.std(values, ddof=1) / np.sqrt(len(values)))


def sensaov_mean(job: Path, spp: int, seeds: range) -> tuple[float, float]:
    loaded = load_job_scene(load_job(job))
    values = [luminance(render_primal(loaded, spp, seed)) for seed in seeds]
    return float(np.mean(values)), float(np.std(values, ddof=1) / np.sqrt(len(values)))


def scene_job(tmp_path: Path, scene: str, **render: object) -> Path:
    job = write_job(tmp_path, render={"spp": 16, "seed": 0, **render})
    use_scene(job, HERE / scene)
    return job


@pytest.mark.parametrize("scene", ["deep_box.xml", "media_moment.xml"])
def test_the_primal_is_mitsubas_own_image_in_expectation(
    mi: ModuleType, tmp_path: Path, scene: str
) -> None:
    """Without max_depth in the job: the deep box renders depth 3 (not 6), the media scene its
    medium through prbvolpath (prb alone would drop it: about half the light)."""
    theirs, their_error = mitsuba_mean(mi, HERE / scene, 64, range(8))
    ours, our_error = sensaov_mean(scene_job(tmp_path, scene), 64, range(100, 108))
    gap = abs(ours - theirs)
    assert gap < 4 * np.hypot(their_error, our_error) + 1e-4 and gap < 0.05 * theirs, (ours, theirs)


def test_a_depth_the_job_changes_is_warned_with_its_effect(tmp_path: Path) -> None:
    job = scene_job(tmp_path, "deep_box.xml", max_depth=6)
    result = sensaov("run", str(job))
    assert result.returncode == EXIT_OK, result.stderr
    assert "the job's render.max_depth 6 replaces the scene's 3" in result.stderr
    provenance = read_buffer(tmp_path / "out" / "buffer.npz").provenance
    (effect,) = provenance["image_effects"]
    assert effect["value"] > 1.2 * effect["scene_value"]  # depth 6 adds much light in the box
    assert provenance["max_depth"] == 6 and provenance["scene_max_depth"] == 3
    changes = [c for c in provenance["scene_changes"] if c["alters_image"]]
    assert len(changes) == 1 and "integrator 'path' -> 'prb'" in changes[0]["what"]


def test_media_parameters_of_a_scene_that_renders_no_media_are_left_out(tmp_path: Path) -> None:
    scene = tmp_path / "scene.xml"
    scene.write_text((HERE / "media_moment.xml").read_text().replace('"moment"', '"path"', 1))
    job = write_job(tmp_path, render={"spp": 4, "seed": 0})
    use_scene(job, scene)
    result = sensaov("params", str(job), "--json")
    assert result.returncode == EXIT_OK, result.stderr
    inventory = json.loads(result.stdout)
    reasons = {e["key"]: e["reason"] for e in inventory["excluded"]}
    assert "renders no media" in reasons["fog.albedo.value.value"]
    assert not [p for p in inventory["selected"] if p["key"].startswith("fog.")]


def test_a_camera_in_a_medium_exits_2_naming_the_medium(tmp_path: Path) -> None:
    scene = tmp_path / "scene.xml"
    text = (HERE / "media_moment.xml").read_text()
    scene.write_text(
        text.replace('<float name="fov"', '<ref name="medium" id="fog"/><float name="fov"')
    )
    job = write_job(tmp_path)
    use_scene(job, scene)
    result = sensaov("validate", str(job))
    assert result.returncode == EXIT_BAD_INPUT
    assert "camera inside medium 'fog'" in result.stderr and "Traceback" not in result.stderr
