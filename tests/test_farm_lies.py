"""Farm inputs that lie (docs/farm.md, "What merge refuses"): claimed samples against the batch
plan, a primal put in another's place (merge and --resume), other Mitsuba, Dr.Jit or variant."""

from __future__ import annotations

import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from sensaov_cli.buffer.npz import read_buffer
from sensaov_cli.buffer.shards import batch_plan, pixels_digest
from sensaov_cli.outputs.exr import read_exr, write_exr

from .conftest import sensaov
from .test_farm import _copy_with_header, _provenance

RENDER = {"spp": 8, "max_depth": 3, "seed": 0, "resolution": [16, 16], "deterministic": True}


def _render_shards(job: Path) -> Path:
    for i in (1, 2):
        done = sensaov("run", str(job), "--shard", f"{i}/2", "-q")
        assert done.returncode == 0, done.stderr
    return job.parent / "out"


@pytest.fixture(scope="module")
def ours(job_writer: Callable[..., Path]) -> Path:
    """A job rendered as 2 shards; returns its output folder."""
    return _render_shards(job_writer("lies_ours", render=RENDER))


@pytest.fixture(scope="module")
def theirs(job_writer: Callable[..., Path]) -> Path:
    """Another job (another seed) of the same scene and size, as 2 shards and as one run."""
    job = job_writer("lies_theirs", render={**RENDER, "seed": 5})
    out = _render_shards(job)
    done = sensaov("run", str(job), "-q")
    assert done.returncode == 0, done.stderr
    return out


def _workspace(ours: Path, tmp_path: Path) -> Path:
    """A copy of our shards (and primals) to spoil without touching the fixture."""
    copy = tmp_path / "out"
    copy.mkdir()
    for name in ("buffer", "primal"):
        for i in (1, 2):
            ext = "npz" if name == "buffer" else "exr"
            shutil.copy(ours / f"{name}.shard-{i}-of-2.{ext}", copy)
    return copy


def _merge(folder: Path) -> tuple[int, list[str], str, Path]:
    out = folder / "merged.npz"
    shards = [str(folder / f"buffer.shard-{i}-of-2.npz") for i in (1, 2)]
    done = sensaov("merge", *shards, "-o", str(out))
    errors = [line for line in done.stderr.splitlines() if line.startswith("sensaov: error")]
    return done.returncode, errors, done.stderr, out


def _refused(folder: Path, says: str) -> None:
    code, errors, stderr, out = _merge(folder)
    assert code == 2, stderr
    assert len(errors) == 1 and says in errors[0], stderr
    assert "Traceback" not in stderr
    assert not out.exists() and not (folder / "merged.primal.exr").exists()
    assert not list(folder.glob("*.partial*"))


def _respoil(folder: Path, index: int, edit: Callable[[dict], None]) -> None:
    path = folder / f"buffer.shard-{index}-of-2.npz"
    spoilt = _copy_with_header(path, folder / "spoilt.npz", edit)
    spoilt.replace(path)


def test_the_plan_fixes_each_shards_samples_and_seed(ours: Path) -> None:
    plan = batch_plan(8, 0, 2)
    for i in (1, 2):
        provenance = read_buffer(ours / f"buffer.shard-{i}-of-2.npz").provenance
        assert (provenance["spp"], provenance["primal_seed"]) == plan[i - 1]


def test_an_honest_merge_records_its_primal(ours: Path, tmp_path: Path) -> None:
    folder = _workspace(ours, tmp_path)
    code, errors, stderr, out = _merge(folder)
    assert code == 0 and not errors, stderr
    recorded = read_buffer(out).provenance["primal"]
    channels, _ = read_exr(folder / "merged.primal.exr")
    assert recorded == {"file": "merged.primal.exr", "sha256": pixels_digest(channels)}


@pytest.mark.parametrize(
    ("lie", "says"),
    [
        # the trial's case: 7 and 1 spp where the plan renders 4 and 4 (the sum still holds)
        ({1: {"spp": 7}, 2: {"spp": 1}}, "shard 1/2 claims 7 spp"),
        ({1: {"spp": 5}, 2: {"spp": 3}}, "renders it with 4 spp"),
        ({2: {"spp": 8}}, "shard 2/2 claims 8 spp"),
        ({2: {"primal_seed": 0}}, "at seed 0"),  # batch 0's seed: not batch 1's samples
        ({1: {"job_spp": 16}, 2: {"job_spp": 16}}, "is not its job's render.spp 8"),
    ],
)
def test_merge_refuses_claimed_samples_the_plan_does_not_render(
    ours: Path, tmp_path: Path, lie: dict[int, dict[str, object]], says: str
) -> None:
    folder = _workspace(ours, tmp_path)
    for index, fields in lie.items():
        for field, value in fields.items():
            _respoil(folder, index, _provenance(field, value))
    _refused(folder, says)


@pytest.mark.parametrize(
    ("field", "value"),
    [("mitsuba_version", "3.0.0"), ("drjit_version", "0.4.0"), ("variant", "scalar_rgb")],
)
def test_merge_refuses_shards_rendered_by_other_builds_or_variants(
    ours: Path, tmp_path: Path, field: str, value: str
) -> None:
    folder = _workspace(ours, tmp_path)
    _respoil(folder, 2, _provenance(field, value))
    _refused(folder, f"rendered with {field} '{value}'")


def test_merge_refuses_a_shard_missing_what_renders_it(ours: Path, tmp_path: Path) -> None:
    folder = _workspace(ours, tmp_path)
    _respoil(folder, 1, lambda header: header["provenance"].pop("variant"))
    _refused(folder, "provenance variant is missing")


@pytest.mark.parametrize("foreign", ["other_job", "other_shard", "one_pixel", "no_record"])
def test_merge_refuses_a_primal_the_shard_did_not_write(
    ours: Path, theirs: Path, tmp_path: Path, foreign: str
) -> None:
    folder = _workspace(ours, tmp_path)
    primal = folder / "primal.shard-1-of-2.exr"
    says = "not the primal buffer.shard-1-of-2.npz was written with"
    if foreign == "other_job":  # the trial's case: another job's shard 1, same name and size
        shutil.copy(theirs / "primal.shard-1-of-2.exr", primal)
    elif foreign == "other_shard":
        shutil.copy(folder / "primal.shard-2-of-2.exr", primal)
    elif foreign == "one_pixel":
        channels, _ = read_exr(primal)
        channels = {name: data.copy() for name, data in channels.items()}
        next(iter(channels.values()))[3, 5] += np.float32(0.25)
        write_exr(primal, channels, {})
    else:  # a shard from before buffers recorded their primal
        _respoil(folder, 1, lambda header: header["provenance"].pop("primal"))
        says = "provenance primal is missing"
    _refused(folder, says)
    if foreign != "no_record":
        assert str(primal) in _merge(folder)[1][0]  # the line names the file


def _resume(job: Path, *shard: str) -> tuple[int, str, str]:
    done = sensaov("run", str(job), *shard, "--resume")
    return done.returncode, done.stdout, done.stderr


def test_resume_refuses_a_foreign_primal_in_a_shards_place(
    job_writer: Callable[..., Path], theirs: Path
) -> None:
    job = job_writer("lies_resume_shard", render=RENDER)
    out = _render_shards(job)
    primal = out / "primal.shard-1-of-2.exr"
    shutil.copy(theirs / "primal.shard-1-of-2.exr", primal)
    before = primal.read_bytes(), (out / "buffer.shard-1-of-2.npz").stat().st_mtime_ns
    code, stdout, stderr = _resume(job, "--shard", "1/2")
    assert code == 2, stderr
    errors = [line for line in stderr.splitlines() if line.startswith("sensaov: error")]
    assert len(errors) == 1 and errors[0].startswith(f"sensaov: error: {primal}: not the primal")
    assert "skipped" not in stderr and "wrote" not in stdout and "Traceback" not in stderr
    assert (primal.read_bytes(), (out / "buffer.shard-1-of-2.npz").stat().st_mtime_ns) == before
    # shard 2 is intact: resumed without a render, and says only that
    code, stdout, stderr = _resume(job, "--shard", "2/2")
    assert code == 0 and "skipped (--resume)" in stderr, stderr
    assert "wrote" not in stdout and "kept" in stdout


def test_plain_resume_refuses_a_foreign_primal_and_says_only_what_happened(
    job_writer: Callable[..., Path], theirs: Path
) -> None:
    job = job_writer("lies_resume_plain", render=RENDER)
    code, stdout, stderr = _resume(job)
    assert code == 0 and "wrote" in stdout and "skipped" not in stderr, stderr  # nothing to resume
    code, stdout, stderr = _resume(job)
    assert code == 0 and "skipped (--resume)" in stderr, stderr
    assert "wrote" not in stdout and "kept" in stdout
    primal = job.parent / "out" / "primal.exr"
    shutil.copy(theirs / "primal.exr", primal)
    code, stdout, stderr = _resume(job)
    assert code == 2 and f"{primal}: not the primal buffer.npz was written with" in stderr, stderr
    assert "wrote" not in stdout
