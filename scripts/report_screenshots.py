"""Screenshots of a sensaov report in headless Chromium, and the page's length.

    .venv/bin/python scripts/report_screenshots.py out/cbox/report.html shots/

Writes ``DIR/report-screen-1.png`` … (1280 × 900 each, the page down to the appendix and one
screen of it) and ``DIR/page-length.txt``: where the appendix starts and the whole height, in CSS
pixels and in screens of 900 px. Needs ``chromium`` on PATH (Debian: apt-get install chromium);
not part of the test suite (tests/test_html_report.py checks the same where Chromium is).
"""

from __future__ import annotations

import argparse
import html
import json
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
from matplotlib import image

WIDTH, SCREEN = 1280, 900
_MEASURE = (
    "<script>addEventListener('load',()=>{document.body.setAttribute('data-m',JSON.stringify("
    "{appendix:document.getElementById('appendix').offsetTop,"
    "height:document.documentElement.scrollHeight,images:document.images.length}))})</script>"
)


def chromium() -> str:
    found = shutil.which("chromium") or shutil.which("chromium-browser")
    if found is None:
        raise SystemExit("no chromium on PATH (apt-get install chromium)")
    return found


def measure(page: Path, browser: str) -> dict[str, int]:
    with tempfile.TemporaryDirectory() as tmp:
        probe = Path(tmp) / "probe.html"
        probe.write_text(page.read_text(encoding="utf-8").replace("</body>", _MEASURE + "</body>"))
        dom = subprocess.run(
            [browser, "--headless", "--no-sandbox", "--disable-gpu", "--virtual-time-budget=5000",
             f"--window-size={WIDTH},{SCREEN}", "--dump-dom", probe.as_uri()],
            capture_output=True, text=True, timeout=120, check=True,
        ).stdout  # fmt: skip
    return dict(json.loads(html.unescape(dom.split('data-m="', 1)[1].split('"', 1)[0])))


def screenshots(page: Path, browser: str, height: int, folder: Path) -> list[Path]:
    full = folder / "report-full.png"
    subprocess.run(
        [browser, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
         "--virtual-time-budget=5000", f"--window-size={WIDTH},{height}",
         f"--screenshot={full}", page.as_uri()],
        capture_output=True, timeout=120, check=True,
    )  # fmt: skip
    pixels = image.imread(full)
    shots = []
    for index, top in enumerate(range(0, height, SCREEN), 1):
        shot = folder / f"report-screen-{index}.png"
        tile = np.ones((SCREEN, WIDTH, pixels.shape[2]), pixels.dtype)
        part = pixels[top : top + SCREEN]
        tile[: part.shape[0]] = part
        image.imsave(shot, tile)
        shots.append(shot)
    full.unlink()
    return shots


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("report", type=Path)
    parser.add_argument("folder", type=Path)
    args = parser.parse_args()
    browser = chromium()
    args.folder.mkdir(parents=True, exist_ok=True)
    found = measure(args.report.resolve(), browser)
    shots = screenshots(args.report.resolve(), browser, found["appendix"] + SCREEN, args.folder)
    text = (
        f"{args.report}: {found['images']} images; appendix at {found['appendix']} px "
        f"({found['appendix'] / SCREEN:.1f} screens of {WIDTH}x{SCREEN}); whole page "
        f"{found['height']} px ({found['height'] / SCREEN:.1f} screens)\n"
    )
    (args.folder / "page-length.txt").write_text(text)
    print(text, end="")
    print("\n".join(str(shot) for shot in shots))
    return 0


if __name__ == "__main__":
    sys.exit(main())
