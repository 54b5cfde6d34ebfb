"""A job that asks for every view (object, texel, forward with transport), as a person meets its
outputs: the report's first screen shows where sensitivity lands beside the sunburst, the
paper's Fig. 4 and 5 views are not folded away, and the EXR headers record provenance once per
file with paths relative to the output folder."""

from __future__ import annotations

import html
import json
import re
import shutil
import subprocess
from pathlib import Path
from typing import Any

import pytest

from sensaov_cli.outputs.exr import read_exr
from sensaov_cli.outputs.layered_exr import layer_key

from .conftest import ROOT, sensaov

SCREEN_WIDTH, SCREEN_HEIGHT = 1280, 900
CHROMIUM = next(
    (shutil.which(n) for n in ("chromium", "chromium-browser") if shutil.which(n)), None
)
PER_LAYER = 48  # attributes a layer may carry (docs/exr-layout.md): a texel panel has 42
PER_FILE = 24  # the file's own: OpenEXR's required ones, format, stamps, provenance, Cryptomatte


@pytest.fixture(scope="module")
def rich(job_writer: Any) -> Path:
    """cbox with a texel channel and a forward group with transport; run, project --png and
    report, as the README says."""
    job = job_writer(
        "rich",
        render={"spp": 8, "max_depth": 4, "seed": 0, "resolution": [24, 24]},
        channels=[
            {"name": "objects", "kind": "object"},
            {"name": "texels", "kind": "texel", "select": "checker.*"},
        ],
        forward=[{"name": "green_wall", "select": "green.*", "transport": True}],
        repair={"budget": 0},
    )
    for command in (("run", "-q"), ("project", "-q", "--png"), ("report",)):
        done = sensaov(*command[:1], str(job), *command[1:])
        assert done.returncode == 0, done.stderr
    return job.parent / "out"


def _sections(page: str) -> dict[str, str]:
    """The page's top-level sections by id (summary, camera-<name>, appendix)."""
    found = re.findall(r'<section id="([^"]+)"[^>]*>(.*?)</section>', page, re.DOTALL)
    return dict(found)


def test_the_summary_shows_each_objectives_view_beside_its_sunburst(rich: Path) -> None:
    summary = _sections((rich / "report.html").read_text(encoding="utf-8"))["summary"]
    (row,) = re.findall(r'<div class="row"><div class="col">(.*?)</div>(<figure[^>]*>)',
                        summary, re.DOTALL)  # fmt: skip
    column, beside = row
    assert column.startswith('<div class="pair"><figure class="view">')  # the picture first
    assert '<figure class="primal">' in column  # and the primal beside it, for reference
    assert "mean_luma.objects (trusted gradients) at the objective camera" in column
    assert column.index('class="view"') < column.index("Top objects")
    assert beside.startswith('<figure class="sunburst">')


def test_fig4_and_fig5_views_are_shown_not_folded(rich: Path) -> None:
    camera = _sections((rich / "report.html").read_text(encoding="utf-8"))["camera-objective"]
    shown, _, folded = camera.partition("<details>")
    assert "Texel, forward and transport views" in shown
    for caption in (
        "mean_luma: texel panels of checker.reflectance.data",  # Fig. 4's sheet
        "forward.green_wall",  # Fig. 5: where the image changes
        "mean_luma.transport_green_wall",  # and where that change lands in M
    ):
        assert f"<figcaption>{caption}</figcaption>" in shown
        assert f"<figcaption>{caption}</figcaption>" not in folded
    assert "every other pass of this camera" in folded  # single texel panels, sheets: folded
    assert "mean_luma.texels_checker_reflectance_joint" in folded


def test_a_job_without_an_object_channel_says_why_there_is_no_view(job_writer: Any) -> None:
    job = job_writer("no_object_channel", channels=[{"name": "types", "kind": "type"}])
    for command in (("run", "-q"), ("report",)):
        assert sensaov(*command[:1], str(job), *command[1:]).returncode == 0
    summary = _sections((job.parent / "out" / "report.html").read_text(encoding="utf-8"))
    assert 'class="view"' not in summary["summary"]
    assert "no object channel in this job" in summary["summary"]


@pytest.mark.skipif(CHROMIUM is None, reason="no chromium: apt-get install chromium (README)")
def test_chromium_shows_the_view_and_the_sunburst_on_the_first_screen(
    rich: Path, tmp_path: Path
) -> None:
    assert CHROMIUM is not None
    probe = tmp_path / "probe.html"
    script = (
        "<script>addEventListener('load',()=>{document.body.setAttribute('data-m',JSON.stringify("
        "[...document.querySelectorAll('#summary figure')].map(f=>{const r=f.querySelector('img')"
        ".getBoundingClientRect();return [f.className,r.left,r.top,r.right,r.bottom]})))})"
        "</script>"
    )
    page = (rich / "report.html").read_text(encoding="utf-8")
    probe.write_text(page.replace("</body>", script + "</body>"))
    dom = subprocess.run(
        [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
         "--virtual-time-budget=5000", f"--window-size={SCREEN_WIDTH},{SCREEN_HEIGHT}",
         "--dump-dom", probe.as_uri()],
        capture_output=True, text=True, timeout=120, check=True,
    ).stdout  # fmt: skip
    boxes = json.loads(html.unescape(dom.split('data-m="', 1)[1].split('"', 1)[0]))
    view = next(box for box in boxes if box[0] == "view")
    sunburst = next(box for box in boxes if box[0] == "sunburst")
    assert 0 <= view[2] and view[4] <= SCREEN_HEIGHT  # the whole picture on the first screen
    assert sunburst[2] < SCREEN_HEIGHT / 2  # the sunburst starts on its upper half
    assert view[3] <= sunburst[1] and abs(view[2] - sunburst[2]) < 60  # side by side


def _strings(value: object) -> list[str]:
    if isinstance(value, dict):
        return [s for key, item in value.items() for s in (str(key), *_strings(item))]
    if isinstance(value, list):
        return [s for item in value for s in _strings(item)]
    return [str(value)]


def test_exr_headers_record_provenance_once_with_relative_paths(rich: Path) -> None:
    channels, header = read_exr(rich / "objective.exr")
    names = {
        value for key, value in header.items() if re.fullmatch(r"sensaov/[0-9a-f]{7}/name", key)
    }
    assert len(names) > 10  # objects, texel panels, forward, transport and their displays
    assert len(header) <= PER_FILE + PER_LAYER * len(names)
    for name in names:
        per_layer = [key for key in header if key.startswith(f"sensaov/{layer_key(name)}/")]
        assert len(per_layer) <= PER_LAYER
        assert not {"buffer", "camera", "spp", "forward_file"} & {k.split("/")[2] for k in
                                                                 per_layer}  # fmt: skip
    provenance = json.loads(header["sensaov/provenance"])
    assert (provenance["buffer"], provenance["forward_file"]) == ("buffer.npz", "forward.npz")
    assert provenance["camera"] == "objective" and provenance["vis_spp"] == 16
    assert [key for key, value in header.items() if "buffer.npz" in str(value)] == [
        "sensaov/provenance"
    ]
    scene = provenance["buffer_provenance"]["scene_path"]
    assert (rich / scene).resolve() == (ROOT / "scenes" / "cbox" / "scene.xml").resolve()
    # What compositors read stays: every Cryptomatte type with its four attributes.
    for crypto in ("CryptoObject", "CryptoMaterial"):
        key = f"cryptomatte/{layer_key(crypto)}"
        assert header[f"{key}/name"] == crypto
        assert {f"{key}/{k}" for k in ("hash", "conversion", "manifest")} <= header.keys()
        assert f"{crypto}00.R" in channels
    # No absolute path in any header sensaov wrote: the views, the primal, the texel files.
    files = (rich / "objective.exr", rich / "primal.exr", *rich.glob("textures/*.exr"))
    assert len(files) == 3
    for path in files:
        _, found = read_exr(path)
        text = [s for value in found.values() for s in _strings(_json_or(value))]
        absolute = [s for s in text if re.search(r"(^|[\s'\"=(])/[A-Za-z]", s)]
        assert not absolute, path
        assert any(s.endswith(("buffer.npz", "scenes/cbox/scene.xml")) for s in text), path


def _json_or(value: object) -> object:
    try:
        return json.loads(value) if isinstance(value, str) else value
    except ValueError:
        return value
