"""The ranked summary: every trust label is marked, zeros are never ranked, numbers as promised."""

from __future__ import annotations

import json
import re
from typing import Any

import numpy as np
import pytest

from sensaov_cli.buffer.model import ObjectiveRecord, ParamRecord, SensitivityBuffer
from sensaov_cli.outputs.tables import (
    LABEL_MEANINGS,
    NO_GRADIENT_MARK,
    SUSPECT_MARK,
    UNVERIFIED_MARK,
    params_dict,
    params_text,
    summary_json,
    summary_text,
)
from sensaov_cli.views.hierarchy import ranked_summary

BIASED = "known biased: roughplastic alpha gradient ~5x too small"
ALPHA, WALL = "floor.bsdf.alpha.value", "wall.bsdf.reflectance.value"
LAMP = "lamp.emitter.radiance.value"
GOLD = "gold.bsdf.eta.value"
NO_FLOW = "smooth (delta) BSDF lobe: prb differentiates BSDFs through eval()"


def make_buffer(
    alpha_trust: str = "biased", extra: tuple[ParamRecord, ...] = ()
) -> SensitivityBuffer:
    note = "" if alpha_trust == "verified" else BIASED
    params = (
        ParamRecord(WALL, "reflectance", ("wall",), (3,), False, "diffuse", (), "verified", ""),
        ParamRecord(ALPHA, "roughness", ("floor",), (1,), False, "roughplastic", (),
                    alpha_trust, note),
        ParamRecord(LAMP, "radiance", ("lamp",), (3,), False, "area", (), "verified", ""),
        *extra,
    )  # fmt: skip
    values = {p.key: np.ones(p.shape, np.float32) for p in params}
    grads = {
        WALL: np.array([1e-3, 2e-3, 2e-3], np.float32),  # l2 3e-3
        ALPHA: np.array([-0.5], np.float32),
        LAMP: np.array([0.0, 0.0, 4e-2], np.float32),
        **{p.key: np.zeros(p.shape, np.float32) for p in extra},
    }
    objects = ("wall", "floor", "lamp", "ceiling", *(o for p in extra for o in p.owners))
    return SensitivityBuffer(
        provenance={"scene_path": "scenes/cbox.xml", "variant": "llvm_ad_rgb", "spp": 16},
        objects=tuple(dict.fromkeys(objects)),
        params=params,
        objectives=(ObjectiveRecord("brightness", {"kind": "mean_luminance"}, 0.125, 3),),
        values=values,
        grads={"brightness": grads},
    )


def summary_dict(buf: SensitivityBuffer, **options: Any) -> dict[str, Any]:
    """The JSON document ``rank --json`` prints for ``buf``."""
    document: dict[str, Any] = json.loads(summary_json(ranked_summary(buf, **options)))
    return document


def with_gold_ball() -> SensitivityBuffer:
    """The buffer plus a gold ball whose only parameter gets no gradient."""
    gold = ParamRecord(GOLD, "eta", ("gold_ball",), (3,), False, "conductor", (),
                       "no_gradient", NO_FLOW)  # fmt: skip
    return make_buffer(extra=(gold,))


@pytest.fixture
def buf() -> SensitivityBuffer:
    return make_buffer()


def row_of(text: str, key: str) -> str:
    """The table row (it starts with its rank) that names ``key``."""
    (row,) = [line for line in text.splitlines() if key in line and re.match(r"\s+\d+\s", line)]
    return row


# The text of make_buffer() before trust labels existed (with the signed sum and its rank
# beside each object's and type's score since texel channels, and each parameter's estimator
# since repairs; the sign with its resolution and the rank by the other score, and the line
# saying a one-batch buffer has no error, since resolution), scored by l2 and read with
# untrusted parameters mixed in: only the legend changed since, to say the label the table says.
BEFORE_LABELS = """\
sensitivity buffer: 3 parameters, 4 objects, 1 objective · scene scenes/cbox.xml · variant llvm_ad_rgb · spp 16
scores: l2 of theta * dM/dtheta over each group's components
signed: their plain sum; > 0 means increasing the parameter raises M
no error: this buffer has one batch, so no number has a standard error and no sign is known to be resolved (render.batches >= 2, or a merge of shards, gives them)

objective 'brightness'   M = 0.125
  parameters (top 3 of 3)
    #        score     signed  sign  #sum  type         estimator  key                          owners
    1  !  5.00e-01  -5.00e-01  -        1  roughness    reverse    floor.bsdf.alpha.value       floor
    2     4.00e-02  +4.00e-02  +        2  radiance     reverse    lamp.emitter.radiance.value  lamp
    3     3.00e-03  +5.00e-03  +        3  reflectance  reverse    wall.bsdf.reflectance.value  wall
  objects (top 4 of 4)
    #        score     signed  sign  #sum  object
    1  !  5.00e-01  -5.00e-01  -        1  floor
    2     4.00e-02  +4.00e-02  +        2  lamp
    3     3.00e-03  +5.00e-03  +        3  wall
    4     0.00e+00  +0.00e+00  0        4  ceiling
  types
    #        score     signed  sign  #sum  type
    1  !  5.00e-01  -5.00e-01  -        1  roughness
    2     4.00e-02  +4.00e-02  +        2  radiance
    3     3.00e-03  +5.00e-03  +        3  reflectance
  ! = {meaning}
      floor.bsdf.alpha.value: {trust}: known biased: roughplastic alpha gradient ~5x too small
    objects and types so marked include such a parameter
"""  # noqa: E501

# The default since: objects and types add up trusted parameters only, the rest apart.
APART = """\
  objects (trusted parameters only) (top 3 of 3)
    #        score  sign  #l2  object
    1    +4.00e-02  +       1  lamp
    2    +5.00e-03  +       2  wall
    3    +0.00e+00  0       3  ceiling
  types (trusted parameters only)
    #        score  sign  #l2  type
    1    +4.00e-02  +       1  radiance
    2    +5.00e-03  +       2  reflectance
  left out of the objects and types above (not trusted), by object:
      floor  -5.00e-01  -5.00e-01  floor.bsdf.alpha.value (biased)
  ! = biased: disagrees with finite differences, do not trust the number
      floor.bsdf.alpha.value: biased: known biased: roughplastic alpha gradient ~5x too small
"""


@pytest.mark.parametrize("trust", ["biased", "unverified"])
def test_text_without_new_labels_is_unchanged_but_for_the_label(trust: str) -> None:
    meaning = LABEL_MEANINGS[trust]
    expected = BEFORE_LABELS.format(meaning=meaning, trust=trust)
    assert summary_text(make_buffer(trust), untrusted="include", method="l2") == expected


def test_objects_and_types_leave_untrusted_parameters_apart() -> None:
    text = summary_text(make_buffer("biased"))
    assert text.endswith(APART)
    assert "unverified" not in text  # a biased parameter is called biased, nowhere unverified


def test_unverified_parameter_is_marked_in_text(buf: SensitivityBuffer) -> None:
    text = summary_text(buf)
    assert UNVERIFIED_MARK in row_of(text, ALPHA).split()
    assert UNVERIFIED_MARK not in row_of(text, WALL).split()
    assert f"{ALPHA}: biased: {BIASED}" in text  # the legend gives the label and the reason
    assert "unverified" not in text  # biased is said biased


def test_labels_are_in_the_dict(buf: SensitivityBuffer) -> None:
    (objective,) = summary_dict(buf, untrusted="include")["objectives"]
    labels = {p["key"]: (p["verified"], p["trust"], p["note"]) for p in objective["parameters"]}
    assert labels[ALPHA] == (False, "biased", BIASED)
    assert labels[WALL] == (True, "verified", "")
    assert {o["name"]: o["trust"] for o in objective["objects"]}["floor"] == "biased"
    assert {t["type"]: t["verified"] for t in objective["types"]}["roughness"] is False
    (apart,) = summary_dict(buf)["objectives"]
    assert "floor" not in {o["name"] for o in apart["objects"]}  # its only parameter: biased
    (floor,) = apart["left_out"]["objects"]
    # scored by the default, the signed sum
    assert (floor["name"], floor["keys"], floor["score"]) == ("floor", [[ALPHA, "biased"]], -0.5)


def test_suspect_parameter_has_its_own_mark_and_legend() -> None:
    buf = make_buffer("suspect")
    text = summary_text(buf)
    assert SUSPECT_MARK in row_of(text, ALPHA).split()
    included = summary_text(buf, top=0, untrusted="include")
    assert SUSPECT_MARK in row_of(included, "roughness").split()  # its type
    assert "? = suspect: failed a run-time self-check" in text
    assert UNVERIFIED_MARK + " =" not in text  # nothing unverified here


def test_zero_gradient_is_listed_apart_not_ranked() -> None:
    text = summary_text(with_gold_ball())
    assert not [line for line in text.splitlines() if re.match(rf"\s+\d+\s.*{GOLD}", line)]
    assert f"  {NO_GRADIENT_MARK} = no gradient flows, not ranked:" in text
    assert f"      {GOLD} (gold_ball): {NO_FLOW}" in text
    assert (
        "parameters (top 3 of 3)" in text
        and "objects (trusted parameters only) (top 3 of 3)" in text
    )
    assert not re.search(r"^\s+\d+\s.*\b(gold_ball|eta)$", text, re.MULTILINE)


def test_zero_gradient_in_json_and_out_of_every_score() -> None:
    summary = summary_dict(with_gold_ball(), top=10)
    assert (summary["format"], summary["format_version"]) == ("sensaov-summary", 4)
    assert summary["counts"]["parameters"] == 4 and summary["counts"]["ranked_parameters"] == 3
    (objective,) = summary["objectives"]
    assert [p["key"] for p in objective["no_gradient"]] == [GOLD]
    assert objective["no_gradient"][0]["note"] == NO_FLOW
    assert GOLD not in [p["key"] for p in objective["parameters"]]
    assert "gold_ball" not in [o["name"] for o in objective["objects"]]
    assert "eta" not in [t["type"] for t in objective["types"]]
    assert "ceiling" in [o["name"] for o in objective["objects"]]  # owns nothing: still scored


def test_an_object_keeps_its_flowing_parameters() -> None:
    """A zero-gradient parameter leaves its object only when it was the object's last one."""
    extra = ParamRecord("floor.bsdf.reflectance.value", "reflectance", ("floor",), (3,), False,
                        "diffuse", (), "no_gradient", NO_FLOW)  # fmt: skip
    buf = make_buffer(extra=(extra,))
    (objective,) = summary_dict(buf, untrusted="include", method="l2")["objectives"]
    floor = {o["name"]: o for o in objective["objects"]}["floor"]
    assert floor["score"] == 0.5 and floor["trust"] == "biased"
    types = {t["type"]: t for t in objective["types"]}
    assert types["reflectance"]["score"] == pytest.approx(3e-3)  # the wall's only


def test_dict_is_json_and_ranked(buf: SensitivityBuffer) -> None:
    summary = summary_dict(buf, top=2, untrusted="include")
    (objective,) = summary["objectives"]
    assert (objective["name"], objective["value"]) == ("brightness", 0.125)
    assert objective["definition"] == {"kind": "mean_luminance"}
    keys = [p["key"] for p in objective["parameters"]]
    assert keys == [ALPHA, LAMP]
    assert objective["parameters"][0]["signed"] == -0.5
    assert [t["type"] for t in objective["types"]] == ["roughness", "radiance", "reflectance"]
    assert len(objective["objects"]) == 2 and objective["no_gradient"] == []


def test_scores_have_three_significant_digits(buf: SensitivityBuffer) -> None:
    text = summary_text(buf, method="l2")  # l2 score, signed sum, sign, rank by the sum
    assert re.search(r"\b3\.00e-03\s+\+5\.00e-03\s+\+\s+\d+\s+reflectance", text)
    assert re.search(r"\b5\.00e-01\s+-5\.00e-01\s+-\s+\d+\s+roughness", text)


def test_signed_method_shows_the_sign(buf: SensitivityBuffer) -> None:
    text = summary_text(buf, method="sum")
    assert re.search(
        r"-5\.00e-01\s+-\s+\d+\s+roughness\s+reverse\s+floor\.bsdf\.alpha\.value", text
    )
    assert re.search(r"\+4\.00e-02\s+\+\s+\d+\s+radiance", text)


def test_text_names_the_objective_and_provenance(buf: SensitivityBuffer) -> None:
    text = summary_text(buf, top=1)
    assert "objective 'brightness'" in text and "M = 0.125" in text
    assert "scene scenes/cbox.xml" in text and "parameters (top 1 of 3)" in text


def test_no_mark_and_no_legend_when_all_verified() -> None:
    text = summary_text(make_buffer("verified"))
    assert "unverified" not in text
    assert UNVERIFIED_MARK not in text.replace("!=", "")


def test_groups_stay_marked_when_the_parameter_is_not_shown(buf: SensitivityBuffer) -> None:
    text = summary_text(buf, top=0, untrusted="include")
    assert UNVERIFIED_MARK in row_of(text, "roughness").split()
    assert "! = biased: disagrees with finite differences" in text
    assert "objects and types so marked include such a parameter" in text


def test_a_suspect_group_outranks_an_unverified_one() -> None:
    suspect = ParamRecord("floor.bsdf.k.value", "k", ("floor",), (1,), False, "x", (),
                          "suspect", "failed a self-check")  # fmt: skip
    (objective,) = summary_dict(make_buffer(extra=(suspect,)), untrusted="include")["objectives"]
    assert {o["name"]: o["trust"] for o in objective["objects"]}["floor"] == "suspect"


class Inventory:
    """What ``sensaov params`` reads of a loaded scene, without loading one."""

    variant = "llvm_ad_rgb"
    objects = ("floor", "gold_ball", "wall")
    excluded = ()
    split: dict[str, tuple[str, ...]] = {}
    textures: dict[str, object] = {}
    changes: tuple[tuple[str, str, str], ...] = ()

    def __init__(self, records: tuple[ParamRecord, ...], repairs: dict | None = None) -> None:
        self.selected = records
        self.repairs = repairs or {}


def test_params_shows_every_label() -> None:
    inventory = Inventory(with_gold_ball().params)
    text = params_text(inventory)
    assert "BIASED" in row_of_params(text, ALPHA) and "NO GRADIENT" in row_of_params(text, GOLD)
    assert "UNVERIFIED" not in row_of_params(text, WALL) and f"  - NO GRADIENT: {NO_FLOW}" in text
    assert f"  - BIASED: {BIASED}" in text  # the heading no longer calls biased unverified
    entries = {e["key"]: e for e in params_dict(inventory)["selected"]}
    assert (entries[GOLD]["trust"], entries[GOLD]["verified"]) == ("no_gradient", False)
    assert entries[ALPHA]["estimator"] == "reverse" and entries[ALPHA]["repair"] is None


def test_params_says_what_run_will_repair() -> None:
    inventory = Inventory(with_gold_ball().params, {ALPHA: "biased: known biased"})
    text = params_text(inventory)
    assert "REPAIRED" in row_of_params(text, ALPHA) and "REPAIRED" not in row_of_params(text, WALL)
    assert "run computes them again by central differences" in text
    entries = {e["key"]: e for e in params_dict(inventory)["selected"]}
    assert entries[ALPHA]["repair"] == "biased: known biased"


def row_of_params(text: str, key: str) -> str:
    (row,) = [line for line in text.splitlines() if line.startswith(key)]
    return row


def test_a_pass_is_not_marked_for_a_parameter_no_gradient_flows_through() -> None:
    """The gold ball's eta adds exactly 0 to every picture: only the biased alpha marks it."""
    from sensaov_cli.job.spec import ChannelSpec
    from sensaov_cli.views.channels import channel_values

    channel = (ChannelSpec("objects", "object"),)
    (objects,) = channel_values(with_gold_ball(), channel, untrusted="include")
    assert GOLD in objects.keys
    assert objects.unverified == (ALPHA,)
    trusted, apart = channel_values(with_gold_ball(), channel)  # the default: apart
    assert (trusted.pass_name, trusted.part, trusted.unverified) == ("objects", "trusted", ())
    assert GOLD in trusted.keys and ALPHA not in trusted.keys
    assert trusted.left_out == {"floor": (ALPHA,)}
    assert (apart.pass_name, apart.keys, apart.unverified) == (
        "objects_untrusted",
        (ALPHA,),
        (ALPHA,),
    )
