"""Selection and aggregation, checked against numbers worked out by hand."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sensaov_cli.buffer.model import ObjectiveRecord, ParamRecord, SensitivityBuffer
from sensaov_cli.buffer.queries import aggregate, per_object, ranking, select
from sensaov_cli.errors import QueryError, UnknownNameError

A = "a.bsdf.reflectance.value"  # owned by a; value [1, 2], dM/dθ [3, -4] -> θ·dM/dθ [3, -8]
SHARED = "shared.reflectance.value"  # owned by a and b; value [0.5], dM/dθ [2] -> [1]
B = "b.bsdf.alpha.value"  # owned by b; value [2], dM/dθ [-1] -> [-2]


def record(key: str, ptype: str, owners: tuple[str, ...], size: int) -> ParamRecord:
    return ParamRecord(key, ptype, owners, (size,), False, "diffuse", (), "verified", "")


@pytest.fixture
def buf() -> SensitivityBuffer:
    params = (
        record(A, "reflectance", ("a",), 2),
        record(SHARED, "reflectance", ("a", "b"), 1),
        record(B, "roughness", ("b",), 1),
    )
    values = {A: np.array([1.0, 2.0]), SHARED: np.array([0.5]), B: np.array([2.0])}
    grads = {A: np.array([3.0, -4.0]), SHARED: np.array([2.0]), B: np.array([-1.0])}
    return SensitivityBuffer(
        provenance={},
        objects=("c", "b", "a"),  # c owns nothing
        params=params,
        objectives=(ObjectiveRecord("m", {}, 1.0, 0), ObjectiveRecord("n", {}, 2.0, 1)),
        values=values,
        grads={"m": grads, "n": {k: -10 * g for k, g in grads.items()}},
    )


# all components: θ·dM/dθ = [3, -8, 1, -2], dM/dθ = [3, -4, 2, -1]
@pytest.mark.parametrize(
    "method, weight, expected",
    [
        ("l2", "value", math.sqrt(78)),
        ("rms", "value", math.sqrt(78 / 4)),
        ("sum", "value", -6.0),
        ("l2", "raw", math.sqrt(30)),
        ("rms", "raw", math.sqrt(30 / 4)),
        ("sum", "raw", 0.0),
    ],
)
def test_aggregate_by_hand(buf: SensitivityBuffer, method, weight, expected: float) -> None:
    got = aggregate(buf, "m", [A, SHARED, B], method=method, weight=weight)
    assert got == pytest.approx(expected, rel=1e-12, abs=1e-12)


def test_aggregate_reads_the_named_objective(buf: SensitivityBuffer) -> None:
    assert aggregate(buf, "n", [A, SHARED, B], method="sum") == pytest.approx(60.0)


def test_aggregate_of_nothing_is_zero(buf: SensitivityBuffer) -> None:
    for method in ("l2", "rms", "sum"):
        assert aggregate(buf, "m", [], method=method) == 0.0


def test_aggregate_counts_a_repeated_key_once(buf: SensitivityBuffer) -> None:
    assert aggregate(buf, "m", [B, B], method="sum") == -2.0


def test_vertical_and_horizontal_cuts(buf: SensitivityBuffer) -> None:
    assert select(buf) == (A, SHARED, B)
    assert select(buf, objects="b") == (SHARED, B)
    assert select(buf, objects=["a", "c"]) == (A, SHARED)
    assert select(buf, objects="c") == ()
    assert select(buf, types=["reflectance"]) == (A, SHARED)
    assert select(buf, glob="*.bsdf.*") == (A, B)
    assert select(buf, glob=["a.*", "b.*"]) == (A, B)


def test_cuts_intersect(buf: SensitivityBuffer) -> None:
    assert select(buf, objects="b", types="reflectance") == (SHARED,)
    assert select(buf, objects="a", glob="*.bsdf.*") == (A,)
    assert select(buf, objects="b", types="reflectance", glob="*.bsdf.*") == ()


def test_empty_collection_selects_nothing(buf: SensitivityBuffer) -> None:
    assert select(buf, objects=[]) == ()


def test_per_object_counts_a_shared_parameter_for_each_owner(buf: SensitivityBuffer) -> None:
    assert per_object(buf, "m") == pytest.approx({"a": math.sqrt(74), "b": math.sqrt(5), "c": 0})
    assert per_object(buf, "m", method="sum") == pytest.approx({"a": -4, "b": -1, "c": 0})
    assert list(per_object(buf, "m")) == ["a", "b", "c"]


def test_per_object_within_a_selection(buf: SensitivityBuffer) -> None:
    keys = select(buf, types="roughness")
    assert per_object(buf, "m", keys=keys, method="sum") == {"a": 0.0, "b": -2.0, "c": 0.0}


def test_ranking_by_type(buf: SensitivityBuffer) -> None:
    scores = dict(ranking(buf, "m", by="type", weight="raw", method="rms"))
    assert scores == pytest.approx({"reflectance": math.sqrt(29 / 3), "roughness": 1.0})


def test_ranking_by_magnitude(buf: SensitivityBuffer) -> None:
    ranked = ranking(buf, "m")
    assert [name for name, _ in ranked] == [A, B, SHARED]
    assert [score for _, score in ranked] == pytest.approx([math.sqrt(73), 2.0, 1.0])
    assert [name for name, _ in ranking(buf, "m", by="object")] == ["a", "b", "c"]
    ((name, score),) = ranking(buf, "m", by="type", top=1)
    assert name == "reflectance" and score == pytest.approx(math.sqrt(74))


def test_ranking_uses_magnitude_and_keeps_ties_in_buffer_order(buf: SensitivityBuffer) -> None:
    # raw sums: A = -1, SHARED = 2, B = -1
    assert ranking(buf, "m", method="sum", weight="raw") == [(SHARED, 2.0), (A, -1.0), (B, -1.0)]


def test_unknown_names_suggest_the_closest(buf: SensitivityBuffer) -> None:
    with pytest.raises(UnknownNameError, match="did you mean 'm'"):
        aggregate(buf, "mm", [A])
    with pytest.raises(UnknownNameError, match="did you mean 'roughness'"):
        select(buf, types="roughnes")
    with pytest.raises(UnknownNameError, match="known: a, b, c"):
        select(buf, objects="wall")
    with pytest.raises(UnknownNameError, match="parameter"):
        aggregate(buf, "m", ["a.bsdf.reflectance"])


@pytest.mark.parametrize(
    "kwargs", [{"method": "max"}, {"weight": "log"}, {"by": "plugin"}, {"top": -1}]
)
def test_bad_options_are_query_errors(buf: SensitivityBuffer, kwargs: dict) -> None:
    with pytest.raises(QueryError):
        ranking(buf, "m", **kwargs)


def test_copies_sharing_arrays_and_zero_gradients_are_counted_by_hand() -> None:
    """Format 4 hands texture copies one shared array and untouched ones a shared zero array:
    key_stats sums each shared pair once, yet every key keeps its own count."""
    texture, grad, zeros = np.array([1.0, 2.0, 4.0]), np.array([1.0, -1.0, 0.5]), np.zeros(3)
    keys = ("a.tex.data", "b.tex.data", "c.tex.data")
    params = tuple(ParamRecord(k, "reflectance", (k[0],), (3,), True, "bitmap", (), "verified", "")
                   for k in keys)  # fmt: skip
    buf = SensitivityBuffer(
        provenance={}, objects=("a", "b", "c"), params=params,
        objectives=(ObjectiveRecord("m", {}, 1.0, 0),),
        values=dict.fromkeys(keys, texture),
        grads={"m": dict(zip(keys, (grad, grad, zeros), strict=True))},
    )  # fmt: skip
    # θ·dM/dθ = [1, -2, 2]: Σ = 1, Σ² = 9 for a and b; 0 for c
    assert per_object(buf, "m", method="sum") == pytest.approx({"a": 1.0, "b": 1.0, "c": 0.0})
    assert aggregate(buf, "m", keys, method="rms") == pytest.approx(math.sqrt(18 / 9))
