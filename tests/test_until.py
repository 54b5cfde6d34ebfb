"""render.batches: auto and render.until: batches by default, sampling until the top resolves."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest

from sensaov_cli.buffer.npz import read_buffer
from sensaov_cli.job.spec import AUTO_BATCHES, RenderSpec
from sensaov_cli.pipeline.resolution import Open, resolution
from sensaov_cli.render.adjoint import batch_plan

from .conftest import sensaov

OBJECTIVES = [{"name": "mean_luma", "type": "mean_luminance"}]
RENDER = {"spp": 4, "max_depth": 3, "seed": 0, "resolution": [16, 16]}


@pytest.mark.parametrize(
    ("spp", "batches", "count"),
    [(64, "auto", AUTO_BATCHES), (4, "auto", 4), (1, "auto", 1), (64, 1, 1), (64, 3, 3)],
)
def test_auto_batches_are_eight_at_most_spp_and_an_integer_is_kept(
    spp: int, batches: int | str, count: int
) -> None:
    assert RenderSpec(spp=spp, batches=batches).batch_count == count  # type: ignore[arg-type]


def test_later_rounds_use_new_seeds_and_the_same_split() -> None:
    """A round of render.until is the first round's split at seeds no earlier batch used; the
    first round is the plan a merge of shards reproduces (batch 0 at the job's seed)."""
    first = batch_plan(10, 7, 4)
    second = batch_plan(10, 7, 4, first=4)
    assert first[0] == (3, 7) and [n for n, _ in first] == [n for n, _ in second] == [3, 3, 2, 2]
    seeds = [s for _, s in first + second]
    assert len(set(seeds)) == 8
    assert [s for _, s in batch_plan(20, 7, 8)] == seeds  # batch b's seed depends on b only


def test_the_shard_estimate_follows_the_square_root_law() -> None:
    """Mean 1, SE 1 from 4 shards: t(0.975, 3) = 3.18, so about 4 · 3.18² ≈ 41 shards in all."""
    item = Open("m", "wall", "sign", 1.0, 1.0)
    assert item.more_batches(4) == 37
    assert Open("m", "wall", "sign", 10.0, 1.0).more_batches(4) == 1
    assert Open("m", "wall", "noisy", 1.0, 1.0, "tail").more_batches(4) is None
    assert Open("m", "wall", "sign", 0.0, 1.0).more_batches(4) is None


def _run(job_writer: Callable[..., Path], name: str, top: int, max_spp: int) -> tuple[Path, str]:
    render = {**RENDER, "deterministic": True, "until": {"resolved": top, "max_spp": max_spp}}
    job = job_writer(name, objectives=OBJECTIVES, render=render)
    done = sensaov("run", str(job))
    assert done.returncode == 0, done.stderr
    return job, done.stderr


@pytest.fixture(scope="module")
def resolved_run(job_writer: Callable[..., Path]) -> tuple[Path, str]:
    """The light and the back wall of the small box resolve within two rounds of 4 spp."""
    return _run(job_writer, "until_resolved", 2, 64)


@pytest.fixture(scope="module")
def open_run(job_writer: Callable[..., Path]) -> tuple[Path, str]:
    """Every object of the box, 8 spp: objects of near-zero sum cannot resolve in that."""
    return _run(job_writer, "until_open", 9, 8)


def _check_recorded(job: Path, top: int) -> dict:
    buffer = read_buffer(job.parent / "out" / "buffer.npz")
    until = buffer.provenance["until"]
    assert buffer.provenance["batches_setting"] == "auto"
    assert until["resolved"] == top
    assert until["spp_spent"] == buffer.provenance["spp"]
    assert sum(b["spp"] for b in buffer.provenance["batches"]) == until["spp_spent"]
    assert buffer.statistics is not None and buffer.statistics.batches == until["batches"]
    # what it recorded agrees with the buffer it wrote, read by the same ranking as rank's
    found = resolution(buffer, top)
    assert [list(pair) for pair in found.resolved] == until["resolved_objects"]
    assert [o.name for o in found.open] == [o["name"] for o in until["open"]]
    return until


def test_until_stops_when_the_top_is_resolved(resolved_run: tuple[Path, str]) -> None:
    job, stderr = resolved_run
    until = _check_recorded(job, 2)
    assert until["outcome"] == "resolved" and until["open"] == []
    assert until["spp_spent"] < 64 and until["spp_spent"] % 4 == 0  # whole rounds of spp 4
    assert len(until["resolved_objects"]) == 2
    assert "render.until: the top 2 objects of every objective are resolved" in stderr
    assert f"at {until['spp_spent']} spp" in stderr


def test_until_names_what_the_budget_left_open(open_run: tuple[Path, str]) -> None:
    job, stderr = open_run
    until = _check_recorded(job, 9)
    assert until["outcome"] == "open" and until["spp_spent"] == 8
    assert until["rounds"] == 2 and until["batches"] == 8
    assert until["open"]
    assert "render.until: max_spp 8 reached at 8 spp (8 batches); still open: " in stderr
    for item in until["open"]:
        assert item["name"] in stderr


def test_until_is_ignored_by_a_shard(resolved_run: tuple[Path, str]) -> None:
    job, _ = resolved_run
    done = sensaov("run", str(job), "--shard", "1/2", "-q")
    assert done.returncode == 0, done.stderr
    shard = read_buffer(job.parent / "out" / "buffer.shard-1-of-2.npz")
    assert "until" not in shard.provenance and shard.provenance["spp"] == 2


def test_merge_says_what_is_open_and_estimates_the_shards(open_run: tuple[Path, str]) -> None:
    job, _ = open_run
    out = job.parent / "out"
    for i in (1, 2):
        done = sensaov("run", str(job), "--shard", f"{i}/2", "-q")
        assert done.returncode == 0, done.stderr
    shards = [str(out / f"buffer.shard-{i}-of-2.npz") for i in (1, 2)]
    done = sensaov("merge", *shards, "-o", str(out / "merged.npz"))
    assert done.returncode == 0, done.stderr
    found = resolution(read_buffer(out / "merged.npz"), 9)  # the job's until.resolved
    assert found.open and found.batches == 2
    assert "still open among the top 9 objects (2 shards)" in done.stdout
    assert "1/sqrt(n) law" in done.stdout
    for item in found.open:
        more = item.more_batches(2)
        estimate = "cannot say" if more is None else f"about {more} more"
        assert f"{item.describe()}: {estimate}" in done.stdout
