"""A job that says nothing about batches gets error bars everywhere, and its Fig. 5 views.

The acceptance of the noise issue on the demo's construct: every row of ``rank --json`` (keys,
objects, types) has a numeric ``signed_se``, its ``dof`` and a boolean ``resolved``; M has its
error; forward channels and transport layers are still written at the default settings.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import pytest

from sensaov_cli.buffer.forward_sidecar import read_forward
from sensaov_cli.buffer.npz import read_buffer
from tests.conftest import sensaov


@pytest.fixture(scope="module")
def default_run(job_writer: Callable[..., Path]) -> Path:
    """The demo's channels and forward groups at 24x24, 16 spp, with no ``render.batches``."""
    job = job_writer(
        "default_errors",
        render={"spp": 16, "max_depth": 6, "seed": 0, "resolution": [24, 24]},
        objectives=[
            {"name": "mean_luma", "type": "mean_luminance"},
            {"name": "back_wall_luma", "type": "region_luminance", "region": [0.3, 0.2, 0.7, 0.6]},
        ],
        channels=[{"name": "objects", "kind": "object"}, {"name": "transport", "kind": "transport",
                                                          "top": 2}],
        forward=[{"name": "light", "object": "light", "direction": "value"}],
    )  # fmt: skip
    done = sensaov("run", "-q", str(job))
    assert done.returncode == 0, done.stderr
    return job


def test_the_default_buffer_has_batches_and_every_objective_its_error(default_run: Path) -> None:
    buffer = read_buffer(default_run.parent / "out" / "buffer.npz")
    assert buffer.statistics is not None and buffer.statistics.batches == 8
    assert buffer.provenance["batches_setting"] == "auto"
    doc = json.loads(
        sensaov("rank", str(default_run.parent / "out" / "buffer.npz"), "--json").stdout
    )
    for objective in doc["objectives"]:
        assert isinstance(objective["value_se"], float) and objective["value_se"] > 0


@pytest.mark.parametrize("by", ["key", "object", "type"])
def test_every_row_has_signed_se_dof_and_resolved(default_run: Path, by: str) -> None:
    buffer = default_run.parent / "out" / "buffer.npz"
    result = sensaov("rank", str(buffer), "--by", by, "--json")
    assert result.returncode == 0, result.stderr
    rows = [row for o in json.loads(result.stdout)["objectives"] for row in o["rows"]]
    assert rows
    for row in rows:
        assert isinstance(row["signed_se"], float), row
        assert row["dof"] == 7 or (row["estimator"] != "reverse" and row["dof"] >= 1), row
        assert isinstance(row["resolved"], bool), row
    # a number the batches cannot resolve is never one the table calls resolved
    for row in rows:
        if row["resolved"]:
            assert abs(row["signed"]) > 2.36 * row["signed_se"], row


def test_forward_channels_and_transport_layers_are_written_by_default(default_run: Path) -> None:
    out = default_run.parent / "out"
    forward = read_forward(out / "forward.npz")
    kinds = {(layer.kind, layer.name) for layer in forward.layers}
    assert ("forward", "light") in kinds, kinds
    assert any(kind == "transport" for kind, _ in kinds), kinds
    assert all(p.failure == "" and p.image is not None for p in forward.passes)
    assert forward.provenance["batches"], forward.provenance
