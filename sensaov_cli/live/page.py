"""The page ``sensaov view`` serves: one self-contained HTML file, no external assets.

The page (``page.html`` beside this module: HTML, CSS and JavaScript in one file) talks to
the server only through the interface of docs/view.md. Its colour bar and sunburst use the very
colour table the PNG previews are drawn with, filled in here, so the legend and the picture
cannot disagree.
"""

from __future__ import annotations

import json
from functools import cache
from importlib import resources

from sensaov_cli.outputs.previews import RDBU

_TABLE_MARK = "/*RDBU*/[]"


@cache
def page_html() -> str:
    """The page's text, with the colour table filled in."""
    text = resources.files("sensaov_cli.live").joinpath("page.html").read_text("utf-8")
    if _TABLE_MARK not in text:
        raise RuntimeError("page.html lost its colour table mark")
    return text.replace(_TABLE_MARK, json.dumps(RDBU.tolist()))
