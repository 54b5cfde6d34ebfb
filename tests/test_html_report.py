"""`sensaov report`: one HTML file, every image embedded and loadable, nothing from a network."""

from __future__ import annotations

import base64
import json
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
    assert len(sources) == 1 + 2 + len(previews)  # primal, a sunburst per objective, previews
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
    for heading in ("Rankings", "Trust of the buffer", "Provenance", "objective centre"):
        assert heading in text
    assert "<td>light</td><td>overhead</td>" in text  # the off-frame label per camera


@pytest.mark.skipif(CHROMIUM is None, reason="no chromium: apt-get install chromium (README)")
def test_chromium_loads_every_image(reported: Path, tmp_path: Path) -> None:
    probe = tmp_path / "probe.html"
    script = (
        "<script>addEventListener('load',()=>{document.body.setAttribute('data-widths',"
        "JSON.stringify([...document.images].map(i=>i.naturalWidth)))})</script>"
    )
    probe.write_text(reported.read_text(encoding="utf-8").replace("</body>", script + "</body>"))
    run = [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--virtual-time-budget=5000"]
    dom = subprocess.run(
        [*run, "--dump-dom", probe.as_uri()],
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
    ).stdout
    widths = json.loads(dom.split('data-widths="', 1)[1].split('"', 1)[0].replace("&quot;", '"'))
    assert widths and all(w > 0 for w in widths)
    shot = tmp_path / "report.png"
    subprocess.run(
        [*run, f"--screenshot={shot}", "--window-size=1280,2000", probe.as_uri()],
        capture_output=True,
        timeout=120,
        check=True,
    )
    assert png_size(shot.read_bytes())[0] > 0


def test_a_report_before_run_says_what_to_do(tmp_path: Path) -> None:
    from .conftest import write_job

    job = write_job(tmp_path)
    result = sensaov("report", str(job))
    assert result.returncode == 2
    (line,) = result.stderr.strip().splitlines()
    assert "no buffer to report on" in line and f"sensaov run {job}" in line
    assert not (tmp_path / "out").exists()  # nothing half-written
