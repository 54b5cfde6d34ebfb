"""Encoding: signs, tone maps and scales, checked against numbers worked out by hand."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sensaov_cli.buffer.queries import KeyStats, combine
from sensaov_cli.errors import EncodingError, NonFiniteError
from sensaov_cli.job.spec import ChannelSpec
from sensaov_cli.views.channels import (
    Encoding,
    Scale,
    choose_scale,
    encode_image,
    signed_object_values,
    tonemap_values,
)
from sensaov_cli.vocabulary import Aggregate

# Per object, its contributions c = θ·∂M/∂θ: wall pulls M down, lamp up, cup cancels out.
CONTRIBUTIONS = {"wall": [-3.0, 1.0], "lamp": [2.0], "floor": [0.25, 0.0], "cup": [1.0, -1.0]}
OBJECTS = {"wall": -3.0, "lamp": 2.0, "floor": 0.5}
LOG10_1001 = math.log10(1001.0)


def scores(method: Aggregate) -> dict[str, float]:
    """The query's score of each object of CONTRIBUTIONS under ``method``."""
    return {
        name: combine([KeyStats(sum(x * x for x in c), sum(c), len(c))], method)
        for name, c in CONTRIBUTIONS.items()
    }


@pytest.mark.parametrize("aggregate", ["l2", "rms"])
def test_signed_norm_takes_the_sign_of_the_sum(aggregate: Aggregate) -> None:
    norms = scores(aggregate)
    got = signed_object_values(norms, scores("sum"), "signed")
    assert got == {
        "wall": -norms["wall"],
        "lamp": norms["lamp"],
        "floor": norms["floor"],
        "cup": norms["cup"],
    }
    assert got["wall"] < 0 and got["cup"] > 0  # the cup's sum is 0: it keeps its magnitude


@pytest.mark.parametrize("aggregate", ["l2", "rms"])
def test_magnitude_of_a_norm_is_the_norm(aggregate: Aggregate) -> None:
    norms = scores(aggregate)
    assert signed_object_values(norms, scores("sum"), "magnitude") == norms


def test_signed_sum_is_the_sum_itself() -> None:
    sums = scores("sum")
    assert signed_object_values(sums, sums, "signed") == {
        "wall": -2.0,
        "lamp": 2.0,
        "floor": 0.25,
        "cup": 0.0,
    }


def test_magnitude_of_a_sum_is_its_absolute_value() -> None:
    sums = scores("sum")
    assert signed_object_values(sums, sums, "magnitude") == {
        "wall": 2.0,
        "lamp": 2.0,
        "floor": 0.25,
        "cup": 0.0,
    }


def test_cancelling_group_keeps_its_magnitude() -> None:
    assert signed_object_values({"cup": 1.0}, {"cup": -0.0}, "signed") == {"cup": 1.0}


def test_sign_inputs_must_name_the_same_objects() -> None:
    with pytest.raises(ValueError, match="different objects"):
        signed_object_values({"a": 1.0}, {"b": 1.0}, "signed")


def test_unknown_sign_lists_the_valid_ones() -> None:
    with pytest.raises(EncodingError) as caught:
        signed_object_values(OBJECTS, OBJECTS, "absolute")
    assert "signed, magnitude" in str(caught.value)


@pytest.mark.parametrize(
    "mode, expected",
    [
        ("none", [0.0, 4.5, -49.5, 0.05]),
        ("log", [0.0, 1.0, 2.0, math.log10(1.1)]),
        ("symlog", [0.0, 1.0, -2.0, math.log10(1.1)]),
    ],
)
def test_tonemap_by_hand(mode: str, expected: list[float]) -> None:
    # threshold 0.5: |x|/t = 0, 9, 99, 0.1
    got = tonemap_values(np.array([0.0, 4.5, -49.5, 0.05]), mode, 0.5)
    assert got.dtype == np.float32
    np.testing.assert_allclose(got, expected, rtol=1e-6)


@pytest.mark.parametrize("threshold", [0.0, -1.0, math.inf])
def test_log_tonemaps_need_a_positive_threshold(threshold: float) -> None:
    with pytest.raises(ValueError, match="threshold"):
        tonemap_values(np.ones(2), "log", threshold)


@pytest.mark.parametrize(
    "tonemap, threshold, scale", [("none", 0.0, 3.0), ("log", 3e-3, LOG10_1001)]
)
def test_shared_scale_is_the_peak_object_value(
    tonemap: str, threshold: float, scale: float
) -> None:
    got = choose_scale(Encoding(tonemap=tonemap, normalize="shared"), OBJECTS)
    assert got.threshold == pytest.approx(threshold, rel=1e-12)
    assert got.scale == pytest.approx(scale, rel=1e-6)


def test_shared_scale_does_not_depend_on_the_image() -> None:
    encoding = Encoding(tonemap="symlog", normalize="shared")
    alone = choose_scale(encoding, OBJECTS)
    for painted in (np.zeros((4, 4)), np.full((2, 3), 0.1), np.array([[-3.0, 2.0]])):
        assert choose_scale(encoding, OBJECTS, painted) == alone


def test_shared_scale_bounds_every_painted_pixel() -> None:
    # A pixel is a coverage-weighted mean of object values (background counts as 0).
    rng = np.random.default_rng(7)
    weights = rng.dirichlet(np.ones(len(OBJECTS) + 1), size=(16, 16))
    painted = weights @ np.array([*OBJECTS.values(), 0.0])
    painted[0, 0] = -3.0  # one pixel fully covered by the peak object
    for tonemap in ("none", "log", "symlog"):
        encoding = Encoding(tonemap=tonemap, normalize="shared")
        scale = choose_scale(encoding, OBJECTS)
        encoded = encode_image(painted, encoding, scale.threshold, scale.scale)
        assert np.max(np.abs(encoded)) == pytest.approx(1.0, rel=1e-6)
        assert np.all(np.abs(encoded) <= 1.0 + 1e-6)


@pytest.mark.parametrize(
    "tonemap, threshold, scale", [("none", 0.0, 0.5), ("log", 5e-4, LOG10_1001)]
)
def test_channel_scale_is_the_peak_of_this_image(
    tonemap: str, threshold: float, scale: float
) -> None:
    painted = np.array([[0.25, -0.5], [0.0, 0.1]])  # peak 0.5, below the objects' peak of 3
    encoding = Encoding(tonemap=tonemap, normalize="channel")
    got = choose_scale(encoding, OBJECTS, painted)
    assert got.threshold == pytest.approx(threshold, rel=1e-12)
    assert got.scale == pytest.approx(scale, rel=1e-6)
    encoded = encode_image(painted, encoding, got.threshold, got.scale)
    assert np.max(np.abs(encoded)) == pytest.approx(1.0, rel=1e-6)


def test_channel_scale_needs_the_image() -> None:
    with pytest.raises(ValueError, match="painted image"):
        choose_scale(Encoding(normalize="channel"), OBJECTS)


def test_unnormalised_scale_is_one_with_a_threshold_from_the_objects() -> None:
    assert choose_scale(Encoding(tonemap="log"), OBJECTS) == Scale(3e-3, 1.0)
    assert choose_scale(Encoding(), OBJECTS) == Scale(0.0, 1.0)


def test_default_encoding_leaves_data_linear_and_unscaled() -> None:
    painted = np.array([[1e-7, -2.5], [0.0, 3.0]], dtype=np.float32)
    scale = choose_scale(Encoding(), OBJECTS)
    encoded = encode_image(painted, Encoding(), scale.threshold, scale.scale)
    assert encoded.dtype == np.float32
    np.testing.assert_array_equal(encoded, painted)


@pytest.mark.parametrize("normalize", ["none", "channel", "shared"])
@pytest.mark.parametrize("tonemap", ["none", "log", "symlog"])
def test_all_zero_is_safe(tonemap: str, normalize: str) -> None:
    encoding = Encoding(tonemap=tonemap, normalize=normalize)
    painted = np.zeros((3, 3))
    for objects in ({"a": 0.0, "b": -0.0}, {}):
        scale = choose_scale(encoding, objects, painted)
        assert scale.scale == 1.0 and math.isfinite(scale.threshold)
        encoded = encode_image(painted, encoding, scale.threshold, scale.scale)
        np.testing.assert_array_equal(encoded, np.zeros((3, 3), dtype=np.float32))


@pytest.mark.parametrize("tonemap", ["none", "log", "symlog"])
def test_a_denormal_peak_still_gets_a_usable_scale(tonemap: str) -> None:
    scale = choose_scale(Encoding(tonemap=tonemap, normalize="shared"), {"a": 5e-324})
    assert scale.scale > 0 and (tonemap == "none" or scale.threshold > 0)


def test_scale_zero_divides_by_nothing() -> None:
    encoded = encode_image(np.zeros((2, 2)), Encoding(), 0.0, 0.0)
    assert encoded.dtype == np.float32 and np.all(encoded == 0.0)


@pytest.mark.parametrize("bad", [math.nan, math.inf])
def test_non_finite_values_are_refused(bad: float) -> None:
    painted = np.array([[0.0, bad]])
    for call in (
        lambda: tonemap_values(painted, "none", 1.0),
        lambda: encode_image(painted, Encoding(), 0.0, 1.0),
        lambda: choose_scale(Encoding(normalize="channel"), OBJECTS, painted),
        lambda: choose_scale(Encoding(), {"a": bad}),
        lambda: signed_object_values({"a": bad}, {"a": 1.0}, "signed"),
        lambda: signed_object_values({"a": 1.0}, {"a": bad}, "magnitude"),
    ):
        with pytest.raises(NonFiniteError):
            call()
    assert issubclass(NonFiniteError, ValueError)


def test_values_beyond_float32_are_refused() -> None:
    with pytest.raises(NonFiniteError, match="float32"):
        tonemap_values(np.array([1e39]), "none", 1.0)


@pytest.mark.parametrize("scale", [-1.0, math.nan, math.inf])
def test_encode_refuses_a_bad_scale(scale: float) -> None:
    with pytest.raises(ValueError, match="scale"):
        encode_image(np.zeros(2), Encoding(), 0.0, scale)


def test_describe_is_stable() -> None:
    assert Encoding().describe() == (  # the default score is the signed sum
        "weight=value;sign=signed;aggregate=sum;tonemap=none;normalize=none"
    )
    custom = Encoding("raw", "magnitude", "rms", "symlog", "shared")
    assert (
        custom.describe()
        == "weight=raw;sign=magnitude;aggregate=rms;tonemap=symlog;normalize=shared"
    )
    assert Scale(0.001, 2.5).describe() == "threshold=0.001;scale=2.5"


def test_parse_reads_back_describe() -> None:
    custom = Encoding("raw", "magnitude", "sum", "log", "channel")
    assert Encoding.parse(custom.describe()) == custom


@pytest.mark.parametrize(
    "text",
    [
        "",
        "weight=value",
        "sign=signed;weight=value;aggregate=l2;tonemap=none;normalize=none",
        "weight=value;sign=signed;aggregate=l2;tonemap=none;normalize",
    ],
)
def test_parse_refuses_what_describe_did_not_write(text: str) -> None:
    with pytest.raises(EncodingError, match="cannot read encoding"):
        Encoding.parse(text)


def test_unknown_option_names_the_choices() -> None:
    with pytest.raises(EncodingError) as caught:
        Encoding(tonemap="gamma")
    assert caught.value.hint == "use one of: none, log, symlog"


def test_from_channel_copies_the_channel_encoding() -> None:
    channel = ChannelSpec(
        "rough", "type", ("roughness",), None, "raw", "magnitude", "sum", "log", "shared"
    )
    assert Encoding.from_channel(channel) == Encoding("raw", "magnitude", "sum", "log", "shared")
