"""Texel channels end to end on a flat-lit quad: placement through UVs, wrap, to_uv, sums.

The quad fills an orthographic 32x32 frame with an 8x8 texture, so one texel covers 4x4
pixels and texel edges fall on pixel edges. A region objective over a block of pixels has
gradients only in the texels those pixels read; painting the field back through the same
lookup must put it on that block again, wherever ``to_uv`` and the wrap mode sent it.
"""

from __future__ import annotations

import json
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest

from sensaov_cli.buffer.npz import read_buffer
from sensaov_cli.buffer.queries import key_stats
from sensaov_cli.job.spec import ChannelSpec, PoolSpec
from sensaov_cli.outputs.exr import read_exr
from sensaov_cli.views.texels import TextureSampling, texel_fields

from .conftest import use_scene, write_job

QUAD = Path(__file__).parent / "scenes" / "texel_quad.xml"
BLOCK = [0.25, 0.25, 0.75, 0.625]  # texels 2..5 across, 2..4 down: pixels 8..24 x 8..20
EDGE = [0.0, 0.25, 0.5, 0.75]  # touches the frame's left edge
TEXEL = 4  # pixels per texel
CASES = {
    "nearest_repeat": ("nearest", "repeat", 0),
    "nearest_clamp_rotated": ("nearest", "clamp", 90),
    "bilinear_repeat": ("bilinear", "repeat", 0),
    "bilinear_clamp_rotated": ("bilinear", "clamp", 90),
}


def _run(folder: Path, mi: ModuleType, filter_type: str, wrap: str, angle: int) -> Path:
    from sensaov_cli.job.load import load_job
    from sensaov_cli.pipeline.project import project_job
    from sensaov_cli.pipeline.run import run_job
    from sensaov_cli.progress import Progress

    folder.mkdir(parents=True)
    texture = folder / "quad_texture.exr"
    rng = np.random.default_rng(5)
    mi.Bitmap(rng.uniform(0.3, 0.7, (8, 8, 3)).astype(np.float32)).write(str(texture))
    job = write_job(
        folder,
        scene_args={
            "filter": filter_type,
            "wrap": wrap,
            "angle": str(angle),
            "texture": str(texture),
        },
        render={"spp": 16, "max_depth": 2, "seed": 0, "resolution": [32, 32]},
        objectives=[
            {"name": "block", "type": "region_luminance", "region": BLOCK},
            {"name": "edge", "type": "region_luminance", "region": EDGE},
        ],
        channels=[{"name": "tex", "kind": "texel", "pool": {"kind": "none"}}],
    )
    use_scene(job, QUAD)
    spec = load_job(job)
    progress = Progress(quiet=True)
    run_job(spec, allow_python=False, progress=progress)
    project_job(spec, buffer_path=spec.output / "buffer.npz", progress=progress)
    return spec.output


@pytest.fixture(scope="module")
def outputs(tmp_path_factory: pytest.TempPathFactory, mi: ModuleType) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("texel_quad")
    return {name: _run(root / name, mi, *case) for name, case in CASES.items()}


def _painted(out: Path, objective: str) -> np.ndarray:
    channels, _ = read_exr(out / "objective.exr")
    name = f"{objective}.tex_quad_bsdf_reflectance_texel"
    return sum(np.abs(channels[f"{name}.{c}"]) for c in "RGB")


def _pixels(region: list[float], grow: int) -> np.ndarray:
    mask = np.zeros((32, 32), bool)
    x0, y0, x1, y1 = (int(round(v * 32)) for v in region)
    mask[max(0, y0 - grow) : y1 + grow, max(0, x0 - grow) : x1 + grow] = True
    return mask


@pytest.mark.parametrize("case", list(CASES))
def test_the_field_lands_on_the_region_again(outputs: dict[str, Path], case: str) -> None:
    nonzero = _painted(outputs[case], "block") > 0
    if case.startswith("nearest"):
        assert (nonzero == _pixels(BLOCK, 0)).all()  # exactly the block
    else:
        # Bilinear reaches one texel's width in each of the two lookups (the gradient's and the
        # painting's): at most 1.5 texels past a texel-aligned block, inside it everywhere.
        assert nonzero[_pixels(BLOCK, 0)].all()
        assert not nonzero[~_pixels(BLOCK, 3 * TEXEL // 2)].any()


def test_repeat_wraps_the_filter_to_the_far_edge_and_clamp_does_not(
    outputs: dict[str, Path],
) -> None:
    repeat = _painted(outputs["bilinear_repeat"], "edge") > 0
    clamp = _painted(outputs["bilinear_clamp_rotated"], "edge") > 0
    far = ~_pixels(EDGE, 3 * TEXEL // 2)  # away from the region, across the frame
    # The left edge's bilinear lookups read the last texel column through the wrap; that
    # column is painted where it shows: the frame's right edge, 1.5 texels wide at most.
    assert repeat[8:24, 32 - TEXEL :].all()
    assert not repeat[:, 16 + 3 * TEXEL // 2 : 32 - 3 * TEXEL // 2].any()
    assert not clamp[far].any()


@pytest.mark.parametrize("case", ["bilinear_repeat", "nearest_clamp_rotated"])
@pytest.mark.parametrize("pool", ["none", "gaussian", "box", "mip"])
def test_field_sums_equal_the_buffers_signed_sum(
    outputs: dict[str, Path], case: str, pool: str
) -> None:
    buf = read_buffer(outputs[case] / "buffer.npz")
    channel = ChannelSpec("tex", "texel", pool=PoolSpec(pool, 2.0))
    sampling = TextureSampling(wrap="clamp" if "clamp" in case else "repeat")
    for field in texel_fields(buf, channel, 0, {"quad.bsdf.reflectance.data": sampling}):
        total = key_stats(buf, field.objective, [field.record.key])[field.record.key].total
        assert field.raw.sum() == pytest.approx(total, rel=1e-6)
        assert field.pooled.sum() == pytest.approx(total, rel=1e-6)


def test_layers_record_sums_scales_pool_and_lookup(outputs: dict[str, Path]) -> None:
    _, header = read_exr(outputs["nearest_clamp_rotated"] / "objective.exr")
    names = {k.split("/")[1] for k in header if k.startswith("sensaov/") and k.count("/") == 2}
    meta = {
        header[f"sensaov/{n}/panel"]: {k.split("/")[2]: header[k] for k in header if f"/{n}/" in k}
        for n in names
        if f"sensaov/{n}/panel" in header and header[f"sensaov/{n}/objective"] == "block"
    }
    assert set(meta) == {"object", "texel", "joint"}
    texel = meta["texel"]
    assert "wrap=clamp" in texel["lookup"] and "filter=nearest" in texel["lookup"]
    assert "[6.12323e-17, -1, 1]" in texel["lookup"] or "[-1, " in texel["lookup"]
    assert float(texel["signed_sum"]) == pytest.approx(float(texel["pooled_sum"]), rel=1e-9)
    assert float(texel["panel_scale"]) > 0 and "kind=none" in texel["pool"]
    assert json.loads(texel["unverified"]) == []
    assert set(json.loads(texel["estimators"]).values()) == {"reverse"}
    domain = outputs["nearest_clamp_rotated"] / "textures"
    assert sorted(p.suffix for p in domain.iterdir()) == [".exr", ".exr", ".png", ".png"]
