"""The sunburst: wedge angles proportional to the ranked values, and the files it writes."""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from pathlib import Path

import pytest
from click.testing import CliRunner

from sensaov_cli import interrupts
from sensaov_cli.buffer.queries import aggregate, ranking
from sensaov_cli.cli import main
from sensaov_cli.errors import EXIT_BAD_INPUT
from sensaov_cli.views.hierarchy import SCENE_WIDE, Wedge, panels, sunburst_wedges
from tests.bad_buffers import write_buffer

from .test_rankings import OBJECTIVES, make_buffer

BUF = make_buffer()
FLOWING = [p.key for p in BUF.params if p.trust != "no_gradient"]


@pytest.fixture
def runner(monkeypatch: pytest.MonkeyPatch) -> CliRunner:
    monkeypatch.setattr(interrupts, "install", lambda **_: None)
    return CliRunner()


def children(wedges: tuple[Wedge, ...], parent: Wedge) -> list[Wedge]:
    return [
        w for w in wedges if w.ring == parent.ring + 1 and w.path[: len(parent.path)] == parent.path
    ]


@pytest.mark.parametrize("objective", OBJECTIVES)
@pytest.mark.parametrize(("order", "first"), [("object,type", "object"), ("type,object", "type")])
@pytest.mark.parametrize("method", ["l2", "rms", "sum"])
def test_first_ring_angles_are_the_ranking(
    objective: str, order: str, first: str, method: str
) -> None:
    wedges = sunburst_wedges(BUF, objective, order=order, method=method, untrusted="include")
    ring = [w for w in wedges if w.ring == 1]
    ranked = [
        (n, s)
        for n, s in ranking(BUF, objective, by=first, method=method, keys=FLOWING)
        if s != 0.0
    ]
    if first == "object":  # what no object owns has a wedge of its own, ranked with the rest
        global_keys = [k for k in FLOWING if not BUF.param(k).owners]
        ranked.append((SCENE_WIDE, aggregate(BUF, objective, global_keys, method=method)))
        ranked.sort(key=lambda item: -abs(item[1]))
    assert [w.label for w in ring] == [n for n, _ in ranked]
    total = sum(abs(s) for _, s in ranked)
    for wedge, (_, score) in zip(ring, ranked, strict=True):
        assert wedge.span == pytest.approx(abs(score) / total, rel=1e-12)
        assert wedge.score == pytest.approx(score, rel=1e-12)
    assert ring[0].start == 0.0 and ring[-1].stop == pytest.approx(1.0)


@pytest.mark.parametrize(("order", "first"), [("object,type", "object"), ("type,object", "type")])
def test_untrusted_parameters_get_a_hatched_wedge_of_their_own(order: str, first: str) -> None:
    """The biased floor alpha leaves floor's (roughness's) wedge for one of its own."""
    wedges = sunburst_wedges(BUF, "brightness", order=order)
    ring = {w.label: w for w in wedges if w.ring == 1}
    trusted = [k for k in FLOWING if BUF.param(k).trust == "verified"]
    name = "floor" if first == "object" else "roughness"
    apart = ring[f"{name} (untrusted)"]
    assert apart.trust == "biased"
    alpha = ["floor.bsdf.alpha.value"]  # scored by the default score, the signed sum
    assert apart.score == pytest.approx(aggregate(BUF, "brightness", alpha, method="sum"))
    if first == "object":  # floor keeps its shared, verified reflectance
        kept = [k for k in trusted if "floor" in BUF.param(k).owners]
        assert ring["floor"].trust == "verified"
        assert ring["floor"].score == pytest.approx(
            aggregate(BUF, "brightness", kept, method="sum")
        )
    else:  # roughness had nothing else
        assert "roughness" not in ring
    assert all(w.trust == "verified" for label, w in ring.items() if "untrusted" not in label)


@pytest.mark.parametrize("order", ["object,type", "type,object"])
def test_children_split_their_parent_in_proportion(order: str) -> None:
    wedges = sunburst_wedges(BUF, "centre", order=order)
    assert {w.ring for w in wedges} == {0, 1, 2, 3}
    for parent in wedges:
        kids = children(wedges, parent)
        if parent.ring == 3:
            assert kids == []
            continue
        assert kids, parent
        assert kids[0].start == pytest.approx(parent.start)
        assert kids[-1].stop == pytest.approx(parent.stop)
        total = math.fsum(abs(k.score) for k in kids)
        for kid in kids:
            assert kid.span == pytest.approx(parent.span * abs(kid.score) / total, rel=1e-9)


def test_leaves_are_the_flowing_keys_under_each_owner() -> None:
    wedges = sunburst_wedges(BUF, "brightness")
    leaves = [w for w in wedges if w.ring == 3]
    assert "glass.eta" not in {w.label for w in leaves}
    # the shared white BSDF sits under both of its owners
    assert {w.path[0] for w in leaves if w.label == "white.reflectance.value"} == {
        "floor",
        "ceiling",
    }
    # a parameter no object owns is drawn under the scene-wide wedge
    assert [w.path for w in leaves if w.label == "exposure.scale"] == [
        (SCENE_WIDE, "scale", "exposure.scale")
    ]
    assert {w.trust for w in leaves if w.label == "floor.bsdf.alpha.value"} == {"biased"}


def test_panels_list_what_is_not_drawn() -> None:
    (panel,) = panels(BUF, ["centre"])
    assert panel.objective == "centre" and panel.no_gradient == ("glass.eta",)


@pytest.mark.parametrize("suffix", ["svg", "png"])
def test_cli_writes_the_file(runner: CliRunner, tmp_path: Path, suffix: str) -> None:
    buffer = tmp_path / "buffer.npz"
    write_buffer(buffer, BUF)
    out = tmp_path / f"sunburst.{suffix}"
    result = runner.invoke(main, ["sunburst", str(buffer), "-o", str(out)])
    assert result.exit_code == 0, result.output
    data = out.read_bytes()
    if suffix == "png":
        assert data.startswith(b"\x89PNG\r\n\x1a\n")
        assert b"sensaov" in data  # the provenance in the Description chunk
    else:
        text = ET.fromstring(data).itertext()
        assert "sensaov" in "".join(text)
        assert "wall" in data.decode()  # the widest wedge (floor's sum is too thin to label)
    assert list(tmp_path.glob(".*partial")) == []


def test_cli_refuses_an_unknown_format(runner: CliRunner, tmp_path: Path) -> None:
    buffer = tmp_path / "buffer.npz"
    write_buffer(buffer, BUF)
    result = runner.invoke(main, ["sunburst", str(buffer), "-o", str(tmp_path / "s.jpg")])
    assert result.exit_code == EXIT_BAD_INPUT
    assert not (tmp_path / "s.jpg").exists()


def test_every_text_is_at_least_eleven_pixels_at_one_to_one() -> None:
    """The report shows the PNG at 1:1: a font of FONT_PT at DPI is its size in pixels."""
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib import pyplot as plt
    from matplotlib.text import Text

    from sensaov_cli.outputs import sunburst_drawing as drawing

    fig = drawing._figure(panels(BUF, ["brightness"]), "object,type", "l2", 5.6)
    try:
        texts = [t for t in fig.findobj(Text) if t.get_text().strip() and t.get_visible()]
        sizes = [t.get_fontsize() * drawing.DPI / 72 for t in texts]
    finally:
        plt.close(fig)
    assert len(texts) > 10 and min(sizes) >= drawing.MIN_TEXT_PX
