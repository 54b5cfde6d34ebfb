"""What people read on the page and the sunburst: the legend's encoding in words, wedge labels
in whole words that never show a parameter's type without its object."""

from __future__ import annotations

import itertools
import re

import pytest

from sensaov_cli.live.inspection import Legend
from sensaov_cli.live.legend_words import legend_words
from sensaov_cli.outputs.sunburst_drawing import wedge_caption
from sensaov_cli.views.channels import Encoding
from sensaov_cli.views.hierarchy import Panel, Wedge
from sensaov_cli.vocabulary import AGGREGATES, SIGNS, TONEMAPS, WEIGHTS


def _legend(encoding: str, mode: str = "shared") -> Legend:
    return Legend(encoding, mode, 1.0, 0.0, ((0.0, 0.0),), (), ())


@pytest.mark.parametrize(
    ("weight", "sign", "aggregate", "tonemap"),
    list(itertools.product(WEIGHTS, SIGNS, AGGREGATES, TONEMAPS)),
)
def test_every_encoding_is_said_in_words(
    weight: str, sign: str, aggregate: str, tonemap: str
) -> None:
    encoding = Encoding(weight, sign, aggregate, tonemap, "shared").describe()
    said = legend_words(_legend(encoding))
    assert "=" not in said and not re.search(r"\b(l2|rms|symlog|normalize)\b", said), said
    assert ("θ·∂M/∂θ" in said) == (weight == "value") and ("∂M/∂θ" in said)
    assert ("which way M moves" in said) == (sign == "magnitude")
    assert ("log scale" in said) == (tonemap != "none")
    assert {"l2": "sum of squares", "rms": "mean square", "sum": "summed"}[aggregate] in said


def test_an_image_and_a_texel_legend_say_what_they_are() -> None:
    image = legend_words(_legend(Encoding(sign="magnitude").describe(), "image"))
    assert image.startswith("the image's derivative per pixel") and "object" not in image
    texel = Encoding(tonemap="log").describe() + " (fixed by the job's texel channel)"
    said = legend_words(_legend(texel, "view"))
    assert said.endswith("(as the job's texel channel asks)") and "=" not in said
    assert legend_words(_legend("not an encoding")) == "not an encoding"  # shown as it came


def _wedge(*path: str) -> Wedge:
    return Wedge(len(path), path, 0.0, 0.2, 1.0, 1.0, "verified")


_PATHS = [
    ("back_wall", "reflectance", "back_wall.reflectance.value"),
    ("back_wall", "reflectance", "back_wall.bsdf.reflectance.value"),
    ("reflectance", "back_wall", "back_wall.reflectance.value"),
    ("light", "radiance", "light.emitter.radiance.value"),
    ("tall_box", "roughness", "blue_plastic.alpha"),
    ("glass_ball_of_a_very_long_name",),
    ("left_wall", "texture", "checker.reflectance.data"),
    ("supercalifragilistic",),
]


@pytest.mark.parametrize("path", _PATHS)
@pytest.mark.parametrize("fits", [4, 6, 8, 10, 12, 16, 24, 40])
def test_wedge_labels_are_whole_words_and_never_a_bare_repeat(
    path: tuple[str, ...], fits: int
) -> None:
    """Every line fits, every word is a whole word of the wedge's name, and a parameter's
    label is never just a name a ring inside already shows (its type without its object)."""
    wedge = _wedge(*path)
    caption = wedge_caption(wedge, fits)
    words = set(re.split(r"[._]", wedge.label))
    for line in caption.split("\n") if caption else []:
        assert len(line) <= fits, (caption, fits)
        assert set(filter(None, re.split(r"[._…]", line))) <= words, caption
    assert caption.replace("…", "").strip("._") not in path[:-1], caption
    assert caption.count("\n") <= 1


def test_a_parameter_wedge_keeps_its_object() -> None:
    wedge = _wedge("back_wall", "reflectance", "back_wall.reflectance.value")
    assert wedge_caption(wedge, 30) == "back_wall.reflectance"
    assert wedge_caption(wedge, 12) == "back_wall.\nreflectance"
    light = _wedge("light", "radiance", "light.emitter.radiance.value")
    assert wedge_caption(light, 30) == "light.emitter.radiance"
    assert wedge_caption(light, 14) == "light.emitter.\nradiance"
    assert wedge_caption(_wedge("floor", "reflectance", "floor.bsdf.reflectance.value"), 8) == ""


def test_the_drawn_sunburst_shows_no_word_cut_in_two() -> None:
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib import pyplot as plt
    from matplotlib.text import Text

    from sensaov_cli.outputs import sunburst_drawing as drawing

    wedges = [Wedge(0, (), 0.0, 1.0, 1.0, 1.0, "verified")]
    for i, path in enumerate(p for p in _PATHS if len(p) == 3):
        start = i / 5
        wedges += [Wedge(1, path[:1], start, start + 0.2, 1.0, 1.0, "verified"),
                   Wedge(2, path[:2], start, start + 0.2, 1.0, 1.0, "verified"),
                   Wedge(3, path, start, start + 0.2, 1.0, 1.0, "verified")]  # fmt: skip
    fig = drawing._figure([Panel("m", 1.0, tuple(wedges), ())], "object,type", "l2", 5.6)
    try:
        texts = [t.get_text() for t in fig.findobj(Text) if t.get_visible() and t.get_text()]
    finally:
        plt.close(fig)
    names = {name for w in wedges for name in w.path}
    tokens = {t for name in names for t in re.split(r"[._]", name)}
    shortened = [t for t in texts if ("…" in t or "\n" in t) and not t.startswith("M =")]
    assert shortened and all(set(re.split(r"[._\n…]", t)) - {""} <= tokens for t in shortened)
    assert "back_wall.\nreflectance" in texts  # the parameter wedge, with its object
