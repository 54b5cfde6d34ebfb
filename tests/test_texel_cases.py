"""Texel channels on the awkward cases: several textures on one object, a roughness bitmap,
a mesh without UVs, a texture no camera sees, a lookup the scene XML cannot pin down."""

from __future__ import annotations

from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

from sensaov_cli.outputs.exr import read_exr
from sensaov_cli.pipeline.project import sampling_of
from sensaov_cli.render.visibility import texture_probes

from .conftest import sensaov, use_scene, write_job

MIX = Path(__file__).parent / "scenes" / "texel_mix.xml"


@pytest.fixture(scope="module")
def mix(tmp_path_factory: pytest.TempPathFactory, mi: ModuleType) -> tuple[dict, dict]:
    folder = tmp_path_factory.mktemp("texel_mix")
    rng = np.random.default_rng(2)
    mi.Bitmap(rng.uniform(0.3, 0.8, (8, 8, 3)).astype(np.float32)).write(str(folder / "c.exr"))
    mi.Bitmap(rng.uniform(0.1, 0.4, (4, 4, 1)).astype(np.float32)).write(str(folder / "r.exr"))
    job = write_job(
        folder,
        scene_args={"colour": str(folder / "c.exr"), "rough": str(folder / "r.exr")},
        render={"spp": 16, "max_depth": 3, "seed": 0, "resolution": [24, 24]},
        channels=[{"name": "tex", "kind": "texel"}],
    )
    use_scene(job, MIX)
    assert sensaov("run", "-q", str(job)).returncode == 0
    done = sensaov("project", str(job))
    assert done.returncode == 0, done.stderr
    channels, header = read_exr(folder / "out" / "objective.exr")
    texel = {}
    for key, value in header.items():
        if key.endswith("/panel") and value == "texel":
            base = key.rsplit("/", 1)[0]
            texel[header[f"{base}/texture"]] = {
                k.rsplit("/", 1)[1]: v for k, v in header.items() if k.startswith(base + "/")
            }
    return channels, texel


def test_several_textures_on_one_object_each_get_a_layer(mix: tuple[dict, dict]) -> None:
    channels, texel = mix
    assert {"ball.bsdf.alpha.data", "ball.bsdf.specular_reflectance.data"} <= set(texel)
    assert "mean_luma.tex_ball_bsdf_alpha_texel.Y" in channels  # one channel: Y
    assert "mean_luma.tex_ball_bsdf_specular_reflectance_texel.R" in channels


def test_a_roughness_bitmap_says_it_is_not_a_colour(mix: tuple[dict, dict]) -> None:
    alpha = mix[1]["ball.bsdf.alpha.data"]
    assert alpha["texture_type"] == "roughness" and "not a colour" in alpha["notes"]


def test_a_mesh_without_uvs_is_noted(mix: tuple[dict, dict]) -> None:
    assert "no UV coordinates" in mix[1]["no_uv.bsdf.reflectance.data"]["notes"]


def test_a_texture_no_camera_sees_is_painted_zero_with_a_note(mix: tuple[dict, dict]) -> None:
    channels, texel = mix
    behind = texel["behind.bsdf.reflectance.data"]
    assert behind["texels_seen"] == "0" and "no sample of this camera" in behind["notes"]
    assert not channels["mean_luma.tex_behind_bsdf_reflectance_texel.R"].any()


@pytest.mark.parametrize("mode", [("nearest", "mirror"), ("bilinear", "clamp")])
def test_probing_finds_the_lookup_the_xml_got_wrong(mi: ModuleType, mode: tuple[str, str]) -> None:
    texels = np.random.default_rng(4).random((6, 5, 3)).astype(np.float32)
    texture = mi.load_dict(
        {
            "type": "bitmap",
            "bitmap": mi.Bitmap(texels),
            "filter_type": mode[0],
            "wrap_mode": mode[1],
        }
    )
    params = mi.traverse(texture)
    wrong = {"": ("bilinear", "repeat", "")}  # an inline bitmap: the XML knows nothing
    sampling = sampling_of(texture_probes(mi, params, ("data",), wrong)["data"])
    assert (sampling.filter, sampling.wrap) == mode
