"""The ranked summary: unverified gradients are always marked, numbers read as promised."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from sensaov_cli.buffer.model import ObjectiveRecord, ParamRecord, SensitivityBuffer
from sensaov_cli.outputs.tables import UNVERIFIED_MARK, summary_text
from sensaov_cli.views.summary import summary_dict

BIASED = "known biased: roughplastic alpha gradient ~5x too small"


def make_buffer(alpha_verified: bool = False) -> SensitivityBuffer:
    note = "" if alpha_verified else BIASED
    params = (
        ParamRecord("wall.bsdf.reflectance.value", "reflectance", ("wall",), (3,), False,
                    "diffuse", (), True, ""),
        ParamRecord("floor.bsdf.alpha.value", "roughness", ("floor",), (1,), False,
                    "roughplastic", (), alpha_verified, note),
        ParamRecord("lamp.emitter.radiance.value", "radiance", ("lamp",), (3,), False,
                    "area", (), True, ""),
    )  # fmt: skip
    values = {p.key: np.ones(p.shape, np.float32) for p in params}
    grads = {
        "wall.bsdf.reflectance.value": np.array([1e-3, 2e-3, 2e-3], np.float32),  # l2 3e-3
        "floor.bsdf.alpha.value": np.array([-0.5], np.float32),
        "lamp.emitter.radiance.value": np.array([0.0, 0.0, 4e-2], np.float32),
    }
    return SensitivityBuffer(
        provenance={"scene_path": "scenes/cbox.xml", "variant": "llvm_ad_rgb", "spp": 16},
        objects=("wall", "floor", "lamp", "ceiling"),
        params=params,
        objectives=(ObjectiveRecord("brightness", {"kind": "mean_luminance"}, 0.125, 3),),
        values=values,
        grads={"brightness": grads},
    )


@pytest.fixture
def buf() -> SensitivityBuffer:
    return make_buffer()


def row_of(text: str, key: str) -> str:
    """The table row (it starts with its rank) that names ``key``."""
    (row,) = [line for line in text.splitlines() if key in line and re.match(r"\s+\d+\s", line)]
    return row


def test_unverified_parameter_is_marked_in_text(buf: SensitivityBuffer) -> None:
    text = summary_text(buf)
    assert UNVERIFIED_MARK in row_of(text, "floor.bsdf.alpha.value").split()
    assert UNVERIFIED_MARK not in row_of(text, "wall.bsdf.reflectance.value").split()
    assert f"floor.bsdf.alpha.value: {BIASED}" in text  # the legend gives the reason
    assert "unverified" in text


def test_unverified_parameter_is_false_in_dict(buf: SensitivityBuffer) -> None:
    (objective,) = summary_dict(buf)["objectives"]
    verified = {p["key"]: (p["verified"], p["note"]) for p in objective["parameters"]}
    assert verified["floor.bsdf.alpha.value"] == (False, BIASED)
    assert verified["wall.bsdf.reflectance.value"] == (True, "")
    assert {o["name"]: o["verified"] for o in objective["objects"]}["floor"] is False
    assert {t["type"]: t["verified"] for t in objective["types"]}["roughness"] is False


def test_dict_is_json_and_ranked(buf: SensitivityBuffer) -> None:
    summary = json.loads(json.dumps(summary_dict(buf, top=2)))
    assert (summary["format"], summary["format_version"]) == ("sensaov-summary", 1)
    (objective,) = summary["objectives"]
    assert (objective["name"], objective["value"]) == ("brightness", 0.125)
    assert objective["definition"] == {"kind": "mean_luminance"}
    keys = [p["key"] for p in objective["parameters"]]
    assert keys == ["floor.bsdf.alpha.value", "lamp.emitter.radiance.value"]
    assert objective["parameters"][0]["signed"] == -0.5
    assert [t["type"] for t in objective["types"]] == ["roughness", "radiance", "reflectance"]
    assert len(objective["objects"]) == 2


def test_scores_have_three_significant_digits(buf: SensitivityBuffer) -> None:
    text = summary_text(buf)
    assert re.search(r"\b3\.00e-03\s+\+5\.00e-03\s+reflectance", text)  # l2 score, signed sum
    assert re.search(r"\b5\.00e-01\s+-5\.00e-01\s+roughness", text)


def test_signed_method_shows_the_sign(buf: SensitivityBuffer) -> None:
    text = summary_text(buf, method="sum")
    assert re.search(r"-5\.00e-01\s+roughness\s+floor\.bsdf\.alpha\.value", text)
    assert re.search(r"\+4\.00e-02\s+radiance", text)


def test_text_names_the_objective_and_provenance(buf: SensitivityBuffer) -> None:
    text = summary_text(buf, top=1)
    assert "objective 'brightness'" in text and "M = 0.125" in text
    assert "scene scenes/cbox.xml" in text and "parameters (top 1 of 3)" in text


def test_no_mark_and_no_legend_when_all_verified() -> None:
    text = summary_text(make_buffer(alpha_verified=True))
    assert "unverified" not in text
    assert UNVERIFIED_MARK not in text.replace("!=", "")


def test_groups_stay_marked_when_the_parameter_is_not_shown(buf: SensitivityBuffer) -> None:
    text = summary_text(buf, top=0)
    assert UNVERIFIED_MARK in row_of(text, "roughness").split()
    assert "includes a parameter whose gradient is unverified" in text
