"""Resolved or not, everywhere: every number with its error, unresolved signs drawn neutral and
kept out of display scales and of the head of a ranking, one score for rankings and pictures.

One synthetic buffer of 8 batches, numpy only (no render): a floor, a 8x8 texture on the wall
whose 192 small same-sign texels rank 2nd by their sum and 7th by l2, a few single-component
objects, and a ball whose ``eta`` flips sign from batch to batch with a mean larger than every
other object's (the near-specular rough dielectric's heavy tail): its sign is not resolved.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from sensaov_cli.buffer.model import ObjectiveRecord, ParamRecord, SensitivityBuffer
from sensaov_cli.buffer.statistics import combine_batches
from sensaov_cli.job.spec import ChannelSpec
from sensaov_cli.live.inspection import object_parameters, object_summary
from sensaov_cli.outputs import sunburst_drawing
from sensaov_cli.outputs.contact_sheets import write_previews
from sensaov_cli.outputs.layered_exr import (
    ScaleGroup,
    SensitivityLayer,
    display_background,
    with_display,
)
from sensaov_cli.outputs.previews import NEUTRAL, neutral_linear
from sensaov_cli.outputs.tables import ranking_csv, ranking_text, summary_json, summary_text
from sensaov_cli.views.channels import channel_values, paint_pass, shared_channel_scale
from sensaov_cli.views.coverage import VisibilityPass, histogram, ranked
from sensaov_cli.views.hierarchy import panels, ranked_summary, rankings, sunburst_wedges

OBJECTIVE = "mean_luma"
BATCHES = 8
ETA = "ball.bsdf.eta"
WALL = "wall.bsdf.reflectance.data"
# The ball's eta per batch: a mean of +20, larger than the floor's +3, with an SE near 30.
ETA_BATCHES = (100.0, -60.0, 120.0, -50.0, 90.0, -70.0, 110.0, -80.0)
# object -> (key, shape, per-component gradient): every component of a group the same
STEADY = {
    "floor": ("floor.bsdf.reflectance.value", (3,), 1.0),
    "wall": (WALL, (8, 8, 3), 0.01),
    "lamp": ("lamp.emitter.radiance.value", (1,), 0.9),
    "shelf": ("shelf.bsdf.reflectance.value", (1,), 0.5),
    "chair": ("chair.bsdf.reflectance.value", (1,), 0.4),
    "table": ("table.bsdf.reflectance.value", (1,), 0.3),
}
OBJECTS = ("ball", "chair", "floor", "lamp", "shelf", "table", "wall")


def _params() -> tuple[ParamRecord, ...]:
    steady = tuple(
        ParamRecord(key, "reflectance", (name,), shape, len(shape) == 3, "diffuse", (),
                    "verified", "")
        for name, (key, shape, _) in STEADY.items()
    )  # fmt: skip
    eta = ParamRecord(ETA, "eta", ("ball",), (1,), False, "roughdielectric", (), "verified", "")
    return (eta, *steady)


def make_buffer(batches: int = BATCHES) -> SensitivityBuffer:
    """The buffer above; ``batches`` 1 keeps the mean only (no statistics)."""
    params = _params()
    values = {p.key: np.ones(p.shape, np.float32) for p in params}  # θ = 1: value = raw
    # A symmetric ± pattern: the steady groups' batches disagree by little and evenly, so no
    # batch carries their spread (no heavy tail), and their means are exact.
    wobble = [(-1.0) ** b * 1e-3 for b in range(BATCHES)]
    per_batch = []
    for b in range(BATCHES):
        grads = {ETA: np.full((1,), ETA_BATCHES[b], np.float32)}
        for _, (key, shape, grad) in STEADY.items():
            grads[key] = np.full(shape, grad * (1.0 + wobble[b]), np.float32)
        per_batch.append({OBJECTIVE: grads})
    keys = [p.key for p in params]
    outputs = [{OBJECTIVE: 0.25 + 1e-3 * (-1.0) ** b} for b in range(BATCHES)]
    spp = [4] * BATCHES
    grads, means, statistics = combine_batches(
        keys, values, per_batch, outputs, spp, range(BATCHES), "batches"
    )
    return SensitivityBuffer(
        provenance={"spp": 32},
        objects=OBJECTS,
        params=params,
        objectives=(ObjectiveRecord(OBJECTIVE, {"type": "mean_luminance"}, means[OBJECTIVE], 0),),
        values=values,
        grads=grads,
        statistics=statistics if batches > 1 else None,  # one batch: the same means, no error
    )


@pytest.fixture(scope="module")
def buf() -> SensitivityBuffer:
    return make_buffer()


def one_pixel_each() -> VisibilityPass:
    """A 7x1 view: pixel i sees object i alone, with every sample."""
    samples = np.repeat(np.arange(len(OBJECTS), dtype=np.int32), 2).reshape(len(OBJECTS), 2)
    coverage = histogram(samples)
    index, amount = ranked(coverage, (1, len(OBJECTS)), 2)
    return VisibilityPass(len(OBJECTS), 1, 2, OBJECTS, None, coverage, index, amount)


def test_every_summary_row_has_its_error_dof_and_resolution(buf: SensitivityBuffer) -> None:
    (objective,) = json.loads(summary_json(ranked_summary(buf, top=50)))["objectives"]
    assert objective["value_se"] > 0 and objective["resolution"]["dof"] == BATCHES - 1
    for section in ("parameters", "objects", "types"):
        for row in objective[section]:
            assert isinstance(row["signed_se"], float) and row["signed_se"] >= 0, row
            assert row["dof"] == BATCHES - 1 and isinstance(row["resolved"], bool), row
    parameters = {row["key"]: row for row in objective["parameters"]}
    assert parameters[ETA]["resolved"] is False
    assert parameters["floor.bsdf.reflectance.value"]["resolved"] is True
    # the ball's +20 is the largest |sum|, yet it ranks after every resolved parameter
    assert [row["key"] for row in objective["parameters"]][-1] == ETA
    assert [row["name"] for row in objective["objects"]][-1] == "ball"


@pytest.mark.parametrize("by", ["key", "object", "type"])
def test_every_ranking_row_has_its_error_in_json_csv_and_text(
    buf: SensitivityBuffer, by: str
) -> None:
    found = rankings(buf, by=by, top=50)  # type: ignore[arg-type]
    flags = [row.resolved for row in found[0].rows]
    assert all(isinstance(f, bool) for f in flags) and flags == sorted(flags, reverse=True)
    assert all(row.dof == BATCHES - 1 and row.signed_se is not None for row in found[0].rows)
    header, *lines = ranking_csv(found).splitlines()
    assert {"signed_se", "dof", "resolved", "noisy", "other_rank"} <= set(header.split(","))
    last = lines[-1].split(",")
    assert last[header.split(",").index("resolved")] == "False"
    text = ranking_text(found, method="sum", weight="value")
    assert "+?" in text and "unresolved" in text


def test_one_batch_says_there_is_no_error() -> None:
    single = make_buffer(batches=1)
    (objective,) = json.loads(summary_json(ranked_summary(single)))["objectives"]
    assert objective["value_se"] is None and objective["resolution"] is None
    for row in objective["parameters"] + objective["objects"] + objective["types"]:
        assert (row["signed_se"], row["dof"], row["resolved"]) == (None, None, None), row
    assert "no error: this buffer has one batch" in summary_text(single)
    (values,) = [v for v in channel_values(single, (ChannelSpec("objects", "object"),))]
    assert values.unresolved == {} and not values.measured


def test_an_unresolved_value_never_sets_the_display_scale(buf: SensitivityBuffer) -> None:
    channel = ChannelSpec("objects", "object")
    scale = shared_channel_scale(buf, channel, OBJECTIVE, {"cam": one_pixel_each()})
    assert scale.value == pytest.approx(3.0)  # the floor's, not the ball's +20
    (values,) = channel_values(buf, (channel,))
    assert list(values.unresolved) == ["ball"] and values.measured


def test_an_unresolved_object_is_drawn_neutral(buf: SensitivityBuffer, tmp_path: Path) -> None:
    view = one_pixel_each()
    (values,) = channel_values(buf, (ChannelSpec("objects", "object"),))
    painted = paint_pass(values, view)
    ball = OBJECTS.index("ball")
    assert painted.neutral is not None and painted.scale_data is not None
    assert painted.neutral[0].tolist() == [i == ball for i in range(len(OBJECTS))]
    assert painted.data[0, ball] == pytest.approx(20.0, rel=1e-5)  # the raw data keep it
    assert painted.scale_data[0, ball] == 0.0
    layer = SensitivityLayer(OBJECTIVE, "objects", painted.data, {"unresolved": "{}"},
                             group=ScaleGroup("g"), neutral=painted.neutral,
                             scale_data=painted.scale_data)  # fmt: skip
    scale = shared_channel_scale(buf, values.spec, OBJECTIVE, {"cam": view})
    _, display = with_display(layer, scale, display_background(view.coverage_hit))
    grey = neutral_linear().astype(np.float16)
    np.testing.assert_array_equal(display.data[0, ball], grey)
    floor = display.data[0, OBJECTS.index("floor")].astype(np.float32)
    assert floor[0] > floor[2]  # the floor's +3 is red, as before
    (entry, *_) = write_previews(tmp_path, "cam", [(layer, scale)], None, view, {})
    from PIL import Image

    with Image.open(tmp_path / entry.file) as image:
        rgb = np.asarray(image.convert("RGB"))
    assert (rgb == np.array(NEUTRAL, np.uint8)).all(axis=2).any()


def test_the_sunburst_draws_an_unresolved_wedge_grey(buf: SensitivityBuffer) -> None:
    wedges = {w.path: w for w in sunburst_wedges(buf, OBJECTIVE)}
    assert wedges[("ball",)].unresolved and not wedges[("floor",)].unresolved
    figure = sunburst_drawing._figure(panels(buf), "object,type", "sum", 5.6)
    faces = [tuple(np.round(p.get_facecolor()[:3], 4)) for p in figure.axes[0].patches]
    assert tuple(np.round(sunburst_drawing.NEUTRAL_RGB, 4)) in faces


def test_where_the_two_scores_disagree_the_row_says_so(buf: SensitivityBuffer) -> None:
    (objects,) = rankings(buf, by="object", top=50)
    wall = next(row for row in objects.rows if row.name == "wall")
    assert (wall.rank, wall.other_rank, wall.orders_disagree) == (2, 7, True)
    assert wall.other_score == pytest.approx(0.01 * np.sqrt(192), rel=1e-4)
    floor = next(row for row in objects.rows if row.name == "floor")
    assert not floor.orders_disagree
    text = ranking_text((objects,), method="sum", weight="value")
    (row,) = [line.split() for line in text.splitlines() if line.split()[-1:] == ["wall"]]
    assert row[0] == "2" and "7≠" in row  # its rank here, and by l2 marked on the row
    assert "≠ = the two orders disagree markedly" in text
    (by_l2,) = rankings(buf, by="object", top=50, method="l2")  # the user's override
    wall_by_l2 = next(row for row in by_l2.rows if row.name == "wall")
    assert (wall_by_l2.rank, wall_by_l2.other_rank) == (6, 3)  # 3rd by sum: the ball counts


def test_the_live_pick_carries_errors_and_resolution(buf: SensitivityBuffer) -> None:
    (row,) = object_parameters(buf, OBJECTIVE, "ball")
    assert (row.resolved, row.dof, row.method) == (False, BATCHES - 1, "sum")
    assert row.signed_se is not None and row.signed_se > 1.0
    (values,) = channel_values(buf, (ChannelSpec("objects", "object"),))
    summary = object_summary(buf, OBJECTIVE, "wall", values)
    assert summary.rank is not None
    assert (summary.rank.object_rank, summary.rank.object_other_rank) == (2, 7)
    assert summary.rank.object_resolved is True and summary.rank.object_orders_disagree
    ball = object_summary(buf, OBJECTIVE, "ball", values).rank
    assert ball is not None and ball.object_resolved is False
    assert ball.object_rank == len(OBJECTS)  # unresolved: after every resolved object
