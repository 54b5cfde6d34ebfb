"""Figure 12: what texel channels cost a 512² view, and what pooling buys (seed-to-seed noise)."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from bench.fig_project import CAMERA, _camera, _make_buffer
from bench.jobs import EXTRA_OBJECTIVES, MEAN_LUMA, SCENES, Workspace
from bench.results import Figure, Goal, Row, fmt
from bench.settings import Settings
from bench.timing import Stats, interleave
from sensaov_cli.buffer.npz import read_buffer
from sensaov_cli.pipeline.project import DEFAULT_BEAUTY_SPP

TEXEL_CHANNEL = {"name": "texels", "kind": "texel"}
BUFFER_SPP = 8
# The noise rows: the demo job's own settings, and the sparse case §6 describes.
NOISE_CASES = ((64, 128), (4, 128))


def texel_cost(ws: Workspace, s: Settings, log: Callable[[str], None]) -> Figure:
    figure = Figure(
        12,
        "Texel channels: a view with them / the same view without; pooling's noise reduction",
        "≤ 1.15×",
        f"In-process `project_job` on one {s.view}² inspection camera of scenes/cbox (its "
        f"checker wall's bitmap), {s.vis_spp} visibility spp, beauty {DEFAULT_BEAUTY_SPP} spp, "
        "two objectives, the object/type/select channels of configs/cbox.yaml, with and "
        "without one `texel` channel (3 layers per texture and objective, the texture-domain "
        "files, the UV trace); interleaved, the `visibility_s` stage and "
        "`ProjectedView.seconds` plus the texture files' time. Noise rows: two `sensaov run`s "
        "of the demo job at seeds 0 and 1; the standard deviation of (field₀ − field₁)/√2 over "
        "the texels, pooled (default pool) over unpooled, and empty texels among those the "
        "objective camera sees.",
    )
    base = _job(ws, s, "texcost_base", with_texels=False)
    texel = _job(ws, s, "texcost_texel", with_texels=True)
    buffer_path = _make_buffer(base)
    t = interleave(
        {
            "base": _view(base, buffer_path, DEFAULT_BEAUTY_SPP),
            "texel": _view(texel, buffer_path, DEFAULT_BEAUTY_SPP),
        },
        s.view_rounds,
    )
    figure.rows.append(
        Row(
            f"cbox {s.view}², texel channel added",
            t["texel"].ratio_to(t["base"]),
            "x",
            Goal("<=", 1.15),
            f"with {fmt(t['texel'].median, 's')} vs without {fmt(t['base'].median, 's')}",
        )
    )
    figure.why_missed = (
        "The extra time (docs/texels.md, 'Cost') is the layered EXR's texel layers and their "
        "display layers (the largest part), the UVs out of the visibility kernel, the "
        "texture's footprint in the view (texel indices per run of a pixel's samples in one "
        "cell since issue 23, no longer per sample), the three panels per objective and the "
        "texture files. The view without texels got cheaper in issue 23 as well, so the ratio "
        "moved less than the extra seconds did."
    )
    log("figure 12: cost done")
    for spp, resolution in NOISE_CASES if not s.quick else ((4, 32),):
        figure.rows += _noise_rows(ws, spp, resolution)
        log(f"figure 12: noise at {spp} spp done")
    return figure


def _view(job: Path, buffer_path: Path, beauty_spp: int) -> Callable[[], float]:
    """Figure 4's view time (visibility and view stages) plus the camera-independent texel
    work (fields, texture files)."""
    from sensaov_cli.job.load import load_job
    from sensaov_cli.pipeline.project import project_job
    from sensaov_cli.progress import Progress

    spec = load_job(job)

    def measure() -> float:
        progress = Progress(quiet=True)
        (view,) = project_job(
            spec,
            buffer_path=buffer_path,
            cameras=(CAMERA,),
            beauty_spp=beauty_spp,
            progress=progress,
        )
        timings = progress.timings
        return float(view.seconds) + timings["visibility_s"] + timings.get("texels_s", 0.0)

    return measure


def _job(ws: Workspace, s: Settings, name: str, *, with_texels: bool) -> Path:
    path = ws.job(
        name,
        SCENES["cbox"],
        resolution=s.resolutions[0],
        spp=BUFFER_SPP,
        objectives=[MEAN_LUMA, EXTRA_OBJECTIVES[0]],
        inspection=(_camera("cbox", s),),
    )
    if with_texels:
        job: dict[str, Any] = yaml.safe_load(path.read_text())
        job["channels"].append(TEXEL_CHANNEL)
        path.write_text(yaml.safe_dump(job, sort_keys=False))
    return path


def _noise_rows(ws: Workspace, spp: int, resolution: int) -> list[Row]:
    from sensaov_cli.job.spec import ChannelSpec
    from sensaov_cli.views.texels import seed_noise, texel_fields

    fields = []
    for seed in (0, 1):
        job = ws.job(f"noise_{spp}_{seed}", SCENES["cbox"], resolution=resolution, spp=spp)
        data = yaml.safe_load(job.read_text())
        data["render"]["seed"] = seed
        job.write_text(yaml.safe_dump(data, sort_keys=False))
        buf = read_buffer(_make_buffer(job))
        fields.append(texel_fields(buf, ChannelSpec("t", "texel"), 0, {})[0])
    first, second = fields
    before = seed_noise(first.raw, second.raw)
    after = seed_noise(first.pooled, second.pooled)
    empty = [float(np.mean(np.all(f.raw == 0, axis=2))) for f in fields]
    pooled_empty = [float(np.mean(np.all(f.pooled == 0, axis=2))) for f in fields]
    detail = (
        f"σ unpooled {before:.3g}, pooled {after:.3g} ({first.pool.describe()}); empty texels "
        f"{100 * np.mean(empty):.1f} % unpooled, {100 * np.mean(pooled_empty):.1f} % pooled"
    )
    return [
        Row(
            f"cbox {resolution}² {spp} spp, seed-to-seed σ pooled / unpooled",
            Stats.of([after / before if before else 0.0]),
            "x",
            None,
            detail,
        )
    ]


__all__ = ["CAMERA", "texel_cost"]
