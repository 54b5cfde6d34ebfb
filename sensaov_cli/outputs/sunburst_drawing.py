"""The sunburst as an SVG or PNG (paper Fig. 1), drawn with matplotlib from views' wedges.

:mod:`sensaov_cli.views.hierarchy` computes every angle; this module only draws.
Colour is the wedge's signed sum Σc on the previews' RdBu relative to the largest |Σc| in its
ring, so a pale wedge is a small one or one whose parameters pull both ways. Unverified wedges
are hatched; unresolved ones (a sign within noise, or heavy-tailed) are grey and dotted, and never
set their ring's scale. matplotlib is imported lazily, with the Agg backend: no display is needed.
"""

from __future__ import annotations

import io
import json
import math
import os
import re
import warnings
from collections.abc import Sequence
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from sensaov_cli.errors import OutputError
from sensaov_cli.outputs.atomic import atomic_write_bytes, scratch_folder
from sensaov_cli.outputs.previews import NEUTRAL, RDBU, diverging_rgb
from sensaov_cli.views.hierarchy import Panel, Wedge

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

FORMATS = ("svg", "png")
PANEL_INCHES = 7.0
DPI = 120  # PNG only
# Outer radius of the objective's disc and of each ring; keys, the longest labels, get the widest.
RADII = (0.17, 0.43, 0.68, 1.0)
FONT_PT = 8.0  # 13.3 px at DPI: every text of the drawing is at least MIN_TEXT_PX at 1:1
MIN_TEXT_PX = 11.0
MIN_LABEL_ARC_IN = 0.17  # a wedge narrower than this at mid-radius gets no label
_VIEW = 1.12  # axes limits: the disc plus a margin
_HATCH = "////"
_NOISE_HATCH = "...."  # unresolved: within its 95 % t interval, or heavy-tailed batches
NEUTRAL_RGB = tuple(c / 255.0 for c in NEUTRAL)  # an unresolved wedge: neither red nor blue
_RING_NAMES = {
    "object,type": "objects → types → parameters",
    "type,object": "types → objects → parameters",
}


def write_sunburst(
    path: Path, panels: Sequence[Panel], *, order: str, encoding: str, provenance: dict[str, Any]
) -> None:
    """Draw ``panels`` side by side into ``path`` (``.svg`` or ``.png``), atomically."""
    fmt = path.suffix.lower().lstrip(".")
    if fmt not in FORMATS:
        raise OutputError(
            f"cannot write a sunburst as {path.suffix or 'no suffix'!r}",
            where=str(path),
            hint="name the file .svg or .png",
        )
    data = sunburst_bytes(panels, fmt=fmt, order=order, encoding=encoding, provenance=provenance)
    atomic_write_bytes(path, data)


def sunburst_bytes(
    panels: Sequence[Panel],
    *,
    fmt: str,
    order: str,
    encoding: str,
    provenance: dict[str, Any],
    panel_inches: float = PANEL_INCHES,
) -> bytes:
    """The drawing as the bytes of an SVG or PNG file (a report embeds them at 1:1)."""
    # matplotlib's font cache: sensaov writes nowhere but its outputs (and $HOME may be
    # read-only), so a folder of its own unless the user set one (docs/rankings.md, "Sunburst").
    os.environ.setdefault("MPLCONFIGDIR", str(scratch_folder("matplotlib")))
    import matplotlib

    matplotlib.use("Agg")  # no display on a farm; must precede pyplot
    from matplotlib import pyplot as plt

    with warnings.catch_warnings():
        # A name in a script DejaVu Sans lacks is drawn with boxes: a warning per glyph is noise.
        warnings.filterwarnings(
            "ignore", message="Glyph .* missing from font", category=UserWarning
        )
        fig = _figure(panels, order, encoding, panel_inches)
        out = io.BytesIO()
        try:
            metadata = {"Description": json.dumps(provenance, sort_keys=True)}
            fig.savefig(out, format=fmt, dpi=DPI, metadata=metadata)
        finally:
            plt.close(fig)
    return out.getvalue()


def _figure(panels: Sequence[Panel], order: str, encoding: str, inches: float) -> Figure:
    from matplotlib import pyplot as plt

    fig, axes = plt.subplots(
        1, len(panels), figsize=(inches * len(panels), inches + 1.1), squeeze=False
    )
    for ax, panel in zip(axes[0], panels, strict=True):
        _draw_panel(ax, panel, inches)
    _legend(fig, order, encoding)
    fig.subplots_adjust(left=0.01, right=0.99, top=0.96, bottom=0.12, wspace=0.02)
    return fig


def _draw_panel(ax: Axes, panel: Panel, inches: float) -> None:
    from matplotlib.patches import Circle

    ax.set_xlim(-_VIEW, _VIEW)
    ax.set_ylim(-_VIEW, _VIEW)
    ax.set_aspect("equal")
    ax.axis("off")
    ax.add_patch(Circle((0, 0), RADII[0], facecolor="#f0f0f0", edgecolor="white"))
    ax.set_title(f"objective {panel.objective!r}", fontsize=11, weight="bold")
    ax.text(0, 0, f"M =\n{panel.value:.4g}", ha="center", va="center", fontsize=FONT_PT)
    rings = [w for w in panel.wedges if w.ring > 0]
    for ring in sorted({w.ring for w in rings}):
        members = [w for w in rings if w.ring == ring]
        # An unresolved wedge is drawn neutral and never sets its ring's colour scale.
        resolved = [abs(w.signed) for w in members if not w.unresolved]
        scale = max(resolved, default=0.0)
        colours = diverging_rgb(np.array([w.signed for w in members]), scale) / 255.0
        for wedge, colour in zip(members, colours, strict=True):
            _draw_wedge(ax, wedge, NEUTRAL_RGB if wedge.unresolved else tuple(colour), inches)
    notes = []
    if panel.no_gradient:
        shown = ", ".join(panel.no_gradient[:4]) + (" …" if len(panel.no_gradient) > 4 else "")
        notes.append(f"not drawn (no gradient): {shown}")
    if panel.zero_valued:
        zero = ", ".join(f"{z.key} (raw ∂M/∂θ {z.raw_signed:+.2e})" for z in panel.zero_valued[:3])
        notes.append(f"θ = 0, so no wedge: {zero}" + (" …" if len(panel.zero_valued) > 3 else ""))
    for line, text in enumerate(notes):
        ax.text(0, -_VIEW + 0.02 + 0.07 * line, text, ha="center", fontsize=FONT_PT,
                color="#555555")  # fmt: skip


def _degrees(fraction: float) -> float:
    """A fraction of a turn clockwise from the top, as matplotlib's counter-clockwise degrees."""
    return 90.0 - 360.0 * fraction


def _draw_wedge(ax: Axes, wedge: Wedge, colour: tuple[float, ...], inches: float) -> None:
    from matplotlib.patches import Wedge as WedgePatch

    inner, outer = RADII[wedge.ring - 1], RADII[wedge.ring]
    ring = partial(
        WedgePatch, (0, 0), outer, _degrees(wedge.stop), _degrees(wedge.start), width=outer - inner
    )
    ax.add_patch(ring(facecolor=colour, edgecolor="white", linewidth=0.8))
    hatches = _HATCH * (wedge.trust != "verified") + _NOISE_HATCH * wedge.unresolved
    if hatches:  # a second, unfilled patch: matplotlib hatches in the edge colour
        ax.add_patch(ring(fill=False, hatch=hatches, edgecolor="#444444", linewidth=0))
    _label(ax, wedge, (inner, outer), colour, bool(hatches), inches)


def _label(
    ax: Axes,
    wedge: Wedge,
    radii: tuple[float, float],
    colour: tuple[float, ...],
    boxed: bool,
    inches: float,
) -> None:
    inches_per_unit = inches / (2 * _VIEW)
    radius = sum(radii) / 2
    if wedge.span * 2 * math.pi * radius * inches_per_unit < MIN_LABEL_ARC_IN:
        return
    fits = int((radii[1] - radii[0]) * 0.9 * inches_per_unit * 72 / (0.5 * FONT_PT))
    text = wedge_caption(wedge, fits)
    if not text:
        return
    middle = math.radians(_degrees((wedge.start + wedge.stop) / 2))
    rotation = math.degrees(middle)
    if math.cos(middle) < 0:  # keep text upright on the left half
        rotation += 180.0
    dark = float(np.dot(colour[:3], (0.2126, 0.7152, 0.0722))) < 0.45
    # On a hatched wedge the text sits on a patch of the wedge's colour, or the hatch hides it.
    box = {"facecolor": colour, "edgecolor": "none", "pad": 0.6} if boxed else None
    ax.text(
        radius * math.cos(middle),
        radius * math.sin(middle),
        text,
        rotation=rotation,
        rotation_mode="anchor",
        ha="center",
        va="center",
        fontsize=FONT_PT,
        color="white" if dark else "black",
        bbox=box,
    )


def wedge_caption(wedge: Wedge, fits: int) -> str:
    """The wedge's name in lines of at most ``fits`` characters, in whole words (a key's parts
    between dots and underscores), or "" where even a shortened one does not fit. A parameter
    is named by its key (``.value``/``.data`` left out), object and all: read on its own, its
    wedge never shows a type without the object it belongs to."""
    inner = wedge.path[:-1]
    label = wedge.label
    for tail in (".value", ".data"):
        label = label.removesuffix(tail)
    if len(label) <= fits:
        return label
    words: list[str] = _WORD.findall(label)  # each word with the separator that follows it
    lines = [("".join(words[:i]), "".join(words[i:])) for i in range(1, len(words))]
    fitting = [(first, second) for first, second in lines if max(len(first), len(second)) <= fits]
    if fitting:  # two lines, as even as they come
        first, second = min(fitting, key=lambda pair: abs(len(pair[0]) - len(pair[1])))
        return f"{first}\n{second}"
    keep_end = wedge.ring >= len(RADII) - 1  # a parameter's last words name it; a group's first
    for count in range(len(words) - 1, 0, -1):
        part = "".join(words[-count:]) if keep_end else "".join(words[:count]).rstrip("._")
        shown = f"…{part}" if keep_end else f"{part}…"
        if len(shown) <= fits and part.strip("._") not in inner:
            return shown
    return ""


_WORD = re.compile(r"[^._]+[._]?|[._]")


def _legend(fig: Figure, order: str, encoding: str) -> None:
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import LinearSegmentedColormap, Normalize
    from matplotlib.patches import Patch

    cmap = LinearSegmentedColormap.from_list("sensaov_rdbu", RDBU / 255.0)
    bar_ax = fig.add_axes((0.06, 0.085, 0.36, 0.02))
    bar = fig.colorbar(ScalarMappable(Normalize(-1, 1), cmap), cax=bar_ax, orientation="horizontal")
    bar.set_ticks([-1, 0, 1], labels=["lowers M", "0", "raises M"])
    bar.ax.tick_params(labelsize=FONT_PT)
    bar.ax.set_title("colour: Σc / largest resolved |Σc| in its ring", fontsize=FONT_PT)
    marks = {_HATCH: "not trusted: apart from its group",
             _NOISE_HATCH: "unresolved (grey): sign within noise or heavy-tailed"}  # fmt: skip
    fig.legend(
        handles=[
            Patch(facecolor="white", edgecolor="#444444", hatch=h, label=marks[h]) for h in marks
        ],
        loc="lower left",
        bbox_to_anchor=(0.5, 0.045),
        fontsize=FONT_PT,
        frameon=False,
    )
    fig.text(
        0.5,
        0.012,
        f"rings from the centre: objective → {_RING_NAMES.get(order, order)}; "
        f"angle ∝ {encoding} among the wedges of one parent",
        ha="center",
        fontsize=FONT_PT,
        wrap=True,
    )
