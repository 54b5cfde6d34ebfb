"""`sensaov report`: one HTML file, every image embedded and loadable, nothing from a network."""

from __future__ import annotations

import base64
import html
import json
import re
import shutil
import struct
import subprocess
from html.parser import HTMLParser
from pathlib import Path
from typing import Any

import pytest

from .conftest import sensaov
from .test_rankings import DEMO_CAMERAS

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
SCREENS, SCREEN_HEIGHT = 5, 900  # "about five screens before the appendix", at 1280 x 900
CHROMIUM = next(
    (shutil.which(n) for n in ("chromium", "chromium-browser") if shutil.which(n)), None
)


class Page(HTMLParser):
    """Every tag with its attributes, in order."""

    def __init__(self) -> None:
        super().__init__()
        self.tags: list[tuple[str, dict[str, str | None]]] = []

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        self.tags.append((tag, dict(attrs)))


@pytest.fixture(scope="module")
def reported(job_writer: Any) -> Path:
    objectives = [
        {"name": "mean_luma", "type": "mean_luminance"},
        {"name": "centre", "type": "region_luminance", "region": [0.3, 0.2, 0.7, 0.6]},
    ]
    job = job_writer(
        "report",
        inspection_cameras=DEMO_CAMERAS,
        objectives=objectives,
        channels=[{"name": "objects", "kind": "object"}],
    )
    assert sensaov("run", "-q", str(job)).returncode == 0
    assert sensaov("project", "-q", str(job), "--png").returncode == 0
    done = sensaov("report", str(job))
    assert done.returncode == 0, done.stderr
    path = job.parent / "out" / "report.html"
    assert done.stdout.strip() == str(path)
    return path


def png_size(data: bytes) -> tuple[int, int]:
    assert data.startswith(PNG_MAGIC)
    width, height = struct.unpack(">II", data[16:24])  # the IHDR chunk comes first
    return width, height


def test_every_image_is_an_embedded_png(reported: Path) -> None:
    page = Page()
    page.feed(reported.read_text(encoding="utf-8"))
    sources = [attrs["src"] or "" for tag, attrs in page.tags if tag == "img"]
    previews = sorted((reported.parent / "previews").rglob("*.png"))
    assert previews
    # per objective the primal, a sunburst and the objective camera's headline view; previews
    assert len(sources) == 2 * 3 + len(previews)
    for src in sources:
        assert src.startswith("data:image/png;base64,")
        width, height = png_size(base64.b64decode(src.split(",", 1)[1]))
        assert width > 0 and height > 0


def test_nothing_comes_from_a_network_or_a_script(reported: Path) -> None:
    page = Page()
    page.feed(reported.read_text(encoding="utf-8"))
    assert not [tag for tag, _ in page.tags if tag in {"script", "link", "iframe"}]
    linked = [v for _, attrs in page.tags for k, v in attrs.items() if k in {"src", "href"}]
    assert all((v or "").startswith("data:") for v in linked)


def test_tables_show_rankings_trust_and_provenance(reported: Path) -> None:
    text = reported.read_text(encoding="utf-8")
    for heading in ("Rankings in full", "Trust of the buffer", "Provenance", "objective centre"):
        assert heading in text
    assert re.search(r"<td>light</td>(<td[^>]*>[^<]*</td>)+<td>overhead</td></tr>", text)
    assert "<th>not seen by</th>" in text and "off-frame" not in text


def test_the_page_reads_summary_cameras_appendix(reported: Path) -> None:
    """Summary first (question, objectives, top objects, left out), a section per camera with
    its headline previews, then the appendix; every section names the buffer it shows."""
    text = reported.read_text(encoding="utf-8")
    order = [
        text.index(mark)
        for mark in (
            'id="summary"',
            "Which parts of scene.xml matter",
            "Top objects",
            'id="camera-objective"',
            'id="camera-overhead"',
            'id="appendix"',
        )
    ]
    assert order == sorted(order)
    summary = text[: text.index('id="camera-objective"')]
    # Of the previews, the summary shows each objective's headline view at the objective camera
    # (beside its sunburst); every other belongs to its camera's section.
    captions = re.findall(r'<figure class="(?:layer|view|sheet)">.*?<figcaption>(.*?)<', summary)
    assert captions == [
        f"{o}.objects (trusted gradients) at the objective camera: where sensitivity lands"
        for o in ("mean_luma", "centre")
    ]
    camera = text[text.index('id="camera-objective"') : text.index('id="camera-overhead"')]
    assert "mean_luma.objects (trusted gradients)" in camera  # a headline preview
    assert "<details>" in camera  # every other pass, folded away
    assert text.count("made from buffer id") >= 4  # summary, each camera, appendix


def test_the_sunburst_is_shown_at_its_own_size(reported: Path) -> None:
    """At 1:1 its text keeps the size it was drawn at (>= 11 px, tests/test_sunburst.py)."""
    page = Page()
    page.feed(reported.read_text(encoding="utf-8"))
    images = [attrs for tag, attrs in page.tags if tag == "img"]
    sunbursts = [a for a in images if (a.get("alt") or "").startswith("sunburst of")]
    assert len(sunbursts) == 2
    for attrs in images:
        data = base64.b64decode((attrs["src"] or "").split(",", 1)[1])
        assert (int(attrs["width"] or 0), int(attrs["height"] or 0)) == png_size(data)


def _chromium(page: Path, tmp_path: Path, height: int) -> tuple[dict[str, Any], Path]:
    """The page's measurements (every image's sizes, the appendix's offset) and a screenshot
    of its first ``height`` pixels at 1280 px wide."""
    assert CHROMIUM is not None
    probe = tmp_path / "probe.html"
    script = (
        "<script>addEventListener('load',()=>{document.body.setAttribute('data-m',"
        "JSON.stringify({images:[...document.images].map(i=>[i.naturalWidth,i.width]),"
        "appendix:document.getElementById('appendix').offsetTop,"
        "height:document.documentElement.scrollHeight}))})</script>"
    )
    probe.write_text(page.read_text(encoding="utf-8").replace("</body>", script + "</body>"))
    run = [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
           "--virtual-time-budget=5000"]  # fmt: skip
    dom = subprocess.run(
        [*run, "--window-size=1280,900", "--dump-dom", probe.as_uri()],
        capture_output=True, text=True, timeout=120, check=True,
    ).stdout  # fmt: skip
    found = json.loads(html.unescape(dom.split('data-m="', 1)[1].split('"', 1)[0]))
    shot = tmp_path / "report.png"
    subprocess.run(
        [*run, f"--screenshot={shot}", f"--window-size=1280,{height}", page.as_uri()],
        capture_output=True, timeout=120, check=True,
    )  # fmt: skip
    return found, shot


@pytest.mark.skipif(CHROMIUM is None, reason="no chromium: apt-get install chromium (README)")
def test_chromium_shows_every_image_at_its_size(reported: Path, tmp_path: Path) -> None:
    found, shot = _chromium(reported, tmp_path, 1000)
    assert found["images"] and all(natural > 0 for natural, _ in found["images"])
    assert all(shown == natural for natural, shown in found["images"])  # nothing scaled down
    assert found["appendix"] <= SCREENS * SCREEN_HEIGHT  # the demo's figure: docs/rankings.md
    assert png_size(shot.read_bytes()) == (1280, 1000)


def test_a_report_before_run_says_what_to_do(tmp_path: Path) -> None:
    from .conftest import write_job

    job = write_job(tmp_path)
    result = sensaov("report", str(job))
    assert result.returncode == 2
    (line,) = result.stderr.strip().splitlines()
    assert "no buffer to report on" in line and f"sensaov run {job}" in line
    assert not (tmp_path / "out").exists()  # nothing half-written
