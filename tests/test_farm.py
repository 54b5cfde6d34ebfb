"""Farm scale (docs/farm.md): shards, an exact merge, standard errors, resume and progress."""

from __future__ import annotations

import json
import zipfile
from collections.abc import Callable
from pathlib import Path

import numpy as np
import OpenEXR
import pytest

from sensaov_cli.buffer.npz import read_buffer
from sensaov_cli.buffer.statistics import pooled_stderr

from .conftest import sensaov
from .test_buffer_storage import write_version_3

SHARDS = 4
OBJECTIVES = [
    {"name": "mean_luma", "type": "mean_luminance"},
    {"name": "centre", "type": "region_luminance", "region": [0.25, 0.25, 0.75, 0.75]},
]
RENDER = {"spp": 16, "max_depth": 4, "seed": 0, "resolution": [24, 24], "deterministic": True}


@pytest.fixture(scope="module")
def farm(job_writer: Callable[..., Path]) -> Path:
    """A job rendered as 4 shards; returns the job file (outputs in its out/)."""
    job = job_writer("farm", objectives=OBJECTIVES, render=RENDER)
    for i in range(1, SHARDS + 1):
        done = sensaov("run", str(job), "--shard", f"{i}/{SHARDS}", "-q")
        assert done.returncode == 0, done.stderr
    return job


def shard_paths(job: Path) -> list[Path]:
    return [job.parent / "out" / f"buffer.shard-{i}-of-{SHARDS}.npz" for i in range(1, 5)]


@pytest.fixture(scope="module")
def merged(farm: Path) -> Path:
    out = farm.parent / "out" / "buffer.npz"
    done = sensaov("merge", *map(str, shard_paths(farm)), "-o", str(out))
    assert done.returncode == 0, done.stderr
    return out


def test_shards_write_their_own_files_and_a_quarter_of_the_samples(farm: Path) -> None:
    out = farm.parent / "out"
    names = sorted(p.name for p in out.iterdir())
    for i in range(1, SHARDS + 1):
        assert f"buffer.shard-{i}-of-4.npz" in names and f"primal.shard-{i}-of-4.exr" in names
    shard = read_buffer(shard_paths(farm)[1])
    assert shard.provenance["spp"] == 4 and shard.provenance["job_spp"] == 16
    assert shard.provenance["task"] == {"shard": {"index": 2, "count": 4}, "objectives": None}


def test_merge_is_the_spp_weighted_mean_exactly(farm: Path, merged: Path) -> None:
    shards = [read_buffer(p) for p in shard_paths(farm)]
    result = read_buffer(merged)
    spp = np.array([s.provenance["spp"] for s in shards], dtype=np.float64)
    assert result.provenance["spp"] == spp.sum() == 16
    for objective in ("mean_luma", "centre"):
        for key in result.keys:
            stack = np.stack([s.grad(objective, key).astype(np.float64) for s in shards])
            expected = np.tensordot(spp / spp.sum(), stack, axes=1).astype(np.float32)
            np.testing.assert_allclose(result.grad(objective, key), expected, rtol=1e-6, atol=0)
            se = pooled_stderr(stack, spp).astype(np.float32)
            np.testing.assert_allclose(
                result.statistics.stderr[objective][key], se, rtol=1e-5, atol=0
            )
        values = [s.objective(objective).value for s in shards]
        assert result.objective(objective).value == pytest.approx(np.average(values, weights=spp))
    assert result.statistics.source == "shards" and result.statistics.spp == (4, 4, 4, 4)


def test_merge_equals_one_run_with_as_many_batches(
    farm: Path, merged: Path, job_writer: Callable[..., Path]
) -> None:
    """Shard i is batch i-1 of the same plan: with deterministic: true, the same bits."""
    job = job_writer("batches", objectives=OBJECTIVES, render={**RENDER, "batches": SHARDS})
    done = sensaov("run", str(job), "-q")
    assert done.returncode == 0, done.stderr
    single = read_buffer(job.parent / "out" / "buffer.npz")
    result = read_buffer(merged)
    assert single.statistics is not None and single.statistics.seeds == result.statistics.seeds
    for objective in ("mean_luma", "centre"):
        for key in result.keys:
            assert np.array_equal(single.grad(objective, key), result.grad(objective, key)), key
            assert np.array_equal(
                single.statistics.stderr[objective][key], result.statistics.stderr[objective][key]
            )


def test_shards_repair_their_share_and_the_merge_holds_every_seed(farm: Path, merged: Path):
    """Each shard renders its batch's share of the repair's seeds (one of 4 here); the merge
    has all four, the same as one run's, and its batch statistics cover the repairs."""
    shards = [read_buffer(p) for p in shard_paths(farm)]
    result = read_buffer(merged)
    key = "blue_plastic.alpha"
    assert [len(s.repairs[key].seeds) for s in shards] == [1, 1, 1, 1]
    assert result.param(key).estimator == "finite-difference" and result.param(key).verified
    assert result.repairs[key].seeds == tuple(s.repairs[key].seeds[0] for s in shards)
    assert result.statistics.stderr["mean_luma"][key] > 0


def test_merged_and_an_independent_run_agree_within_the_standard_errors(
    merged: Path, job_writer: Callable[..., Path]
) -> None:
    other = {**RENDER, "seed": 7, "batches": 4}
    job = job_writer("independent", objectives=OBJECTIVES, render=other)
    assert sensaov("run", str(job), "-q").returncode == 0
    a = read_buffer(merged)
    b = read_buffer(job.parent / "out" / "buffer.npz")
    z = []
    for objective in ("mean_luma", "centre"):
        for key in a.keys:
            se = np.hypot(a.statistics.stderr[objective][key], b.statistics.stderr[objective][key])
            diff = np.abs(a.grad(objective, key) - b.grad(objective, key))
            z += list((diff[se > 0] / se[se > 0]).ravel())
    z_arr = np.array(z)
    # Normal errors: 95 % within 2 sigma. Four batches make each SE estimate noisy (a t
    # distribution with 3 degrees of freedom per side), so ask for 80 % within 3.
    assert len(z_arr) > 20 and np.mean(z_arr < 3) > 0.8, np.percentile(z_arr, [50, 90])


def test_rank_shows_standard_errors_and_stability(merged: Path) -> None:
    done = sensaov("rank", str(merged), "--by", "object", "--json")
    assert done.returncode == 0, done.stderr
    document = json.loads(done.stdout)
    first = document["objectives"][0]
    assert first["batches"] == 4 and 0.0 <= first["stability"] <= 1.0
    row = first["rows"][0]
    assert row["score_se"] > 0 and row["signed_se"] > 0 and row["dof"] == 3
    # Resolution at the batch count: Student's t at 3 degrees of freedom, not 2 SE, and no
    # heavy tail (a noisy row is never resolved, whatever its interval says)
    resolution = first["resolution"]
    assert (resolution["batches"], resolution["dof"]) == (4, 3)
    assert resolution["factor"] == pytest.approx(3.1824463, abs=1e-6)
    rows = first["rows"] + first["left_out"]
    for entry in rows:
        beyond = abs(entry["signed"]) > 3.1824463 * entry["signed_se"]
        assert entry["resolved"] == (beyond and entry["noisy"] is None), entry
    # the unresolved rows rank after every resolved one
    flags = [entry["resolved"] for entry in first["rows"]]
    assert flags == sorted(flags, reverse=True), flags
    text = sensaov("rank", str(merged), "--by", "object").stdout
    assert "standard error from 4 batches" in text and "bootstrap" in text
    assert "within 3.18 standard errors (Student's t, 3 degrees of freedom" in text


# --- refusals: one line, exit 2 -----------------------------------------------------------


def _copy_with_header(source: Path, target: Path, edit: Callable[[dict], None]) -> Path:
    with zipfile.ZipFile(source) as zin, zipfile.ZipFile(target, "w") as zout:
        for item in zin.infolist():
            data = zin.read(item.filename)
            if item.filename == "header.npy":
                import io

                header = json.loads(str(np.load(io.BytesIO(data))[()]))
                edit(header)
                out = io.BytesIO()
                np.lib.format.write_array(out, np.array(json.dumps(header)), allow_pickle=False)
                data = out.getvalue()
            zout.writestr(item, data)
    return target


def _provenance(field: str, value: object) -> Callable[[dict], None]:
    return lambda header: header["provenance"].__setitem__(field, value)


def _other_parameters(header: dict) -> None:
    header["params"][0]["key"] = "renamed.key"


@pytest.mark.parametrize(
    ("case", "expected"),
    [
        ("missing", "missing shard(s) 3/4"),
        ("duplicate", "given twice"),
        ("scene", "another scene"),
        ("job", "another job"),
        ("parameters", "other parameters"),
        ("version", "format version 3"),
        ("count", "shard of 3"),
        ("not_a_shard", "not a shard"),
    ],
)
def test_merge_refuses_mismatched_shards(farm: Path, tmp_path: Path, case: str, expected: str):
    paths = shard_paths(farm)
    spoil = {
        "scene": _provenance("scene_fingerprint", "0" * 16),
        "job": _provenance("job_hash", "f" * 16),
        "parameters": _other_parameters,
        "count": _provenance("task", {"shard": {"index": 3, "count": 3}, "objectives": None}),
        "not_a_shard": _provenance("task", {"shard": None, "objectives": None}),
    }
    if case == "missing":
        given = [paths[0], paths[1], paths[3]]
    elif case == "duplicate":
        given = [*paths, paths[2]]
    elif case == "version":  # the same shard, as sensaov wrote it before format 4
        older = tmp_path / "x.npz"
        write_version_3(older, read_buffer(paths[2]))
        given = [*paths[:2], older, paths[3]]
    else:
        given = [*paths[:2], _copy_with_header(paths[2], tmp_path / "x.npz", spoil[case]), paths[3]]
    out = tmp_path / "merged.npz"
    done = sensaov("merge", *map(str, given), "-o", str(out))
    assert done.returncode == 2, done.stderr
    lines = [line for line in done.stderr.splitlines() if line.startswith("sensaov: error")]
    assert len(lines) == 1 and expected in lines[0], done.stderr
    assert "Traceback" not in done.stderr and not out.exists()


def test_merge_refuses_to_overwrite_a_shard(farm: Path) -> None:
    paths = shard_paths(farm)
    done = sensaov("merge", *map(str, paths), "-o", str(paths[0]))
    assert done.returncode == 2 and "which this command reads" in done.stderr


# --- objective splits, resume, progress ----------------------------------------------------


def test_objective_split_shards_merge_like_whole_ones(farm: Path, merged: Path) -> None:
    """One farm task per (shard, objective): the merge is the same as whole shards'."""
    out = farm.parent / "out"
    files = []
    for i in range(1, SHARDS + 1):
        for name in ("mean_luma", "centre"):
            done = sensaov("run", str(farm), "--shard", f"{i}/4", "--objective", name, "-q")
            assert done.returncode == 0, done.stderr
            files.append(out / f"buffer.shard-{i}-of-4.objective-{name}.npz")
    target = out / "split" / "buffer.npz"
    done = sensaov("merge", *map(str, files), "-o", str(target))
    assert done.returncode == 0, done.stderr
    a, b = read_buffer(target), read_buffer(merged)
    for key in a.keys:
        assert np.array_equal(a.grad("centre", key), b.grad("centre", key))


def test_resume_skips_a_complete_task_and_redoes_a_changed_one(farm: Path) -> None:
    path = shard_paths(farm)[0]
    before = path.stat().st_mtime_ns
    done = sensaov("run", str(farm), "--shard", "1/4", "--resume")
    assert done.returncode == 0 and "skipped (--resume)" in done.stderr
    assert path.stat().st_mtime_ns == before
    done = sensaov("run", str(farm), "--shard", "2/4", "--resume", "--objective", "centre", "-q")
    assert done.returncode == 0  # another task (one objective): its own file, rendered


def test_farm_progress_lines(job_writer: Callable[..., Path]) -> None:
    job = job_writer("progress", objectives=OBJECTIVES, render={**RENDER, "batches": 2})
    done = sensaov("run", str(job), "--progress", "farm")
    assert done.returncode == 0, done.stderr
    percents = [
        int(line[10:-1]) for line in done.stderr.splitlines() if line.startswith("Progress:")
    ]
    assert percents == sorted(percents) and percents[-1] == 100 and len(percents) >= 5
    plain = sensaov("run", str(job), "--progress", "plain")
    assert "Progress:" not in plain.stderr


def test_shard_outside_its_range_is_refused(farm: Path) -> None:
    for bad in ("0/4", "5/4", "x/4", "3"):
        done = sensaov("run", str(farm), "--shard", bad)
        assert done.returncode == 2 and "Traceback" not in done.stderr
    done = sensaov("run", str(farm), "--shard", "1/32")  # 32 shards of 16 spp
    assert done.returncode == 2 and "cannot split render.spp" in done.stderr


def test_standard_errors_are_calibrated(job_writer: Callable[..., Path]) -> None:
    """Over independent seeds, the spread of the estimates matches the reported errors.

    Ten runs of 4 batches each. The spread over 10 seeds is itself uncertain by about
    1/sqrt(2·9) = 24 %, and the root-mean-square of ten 4-batch error estimates by about
    sqrt(2/3 / 10) / 2 = 13 %; their ratio by about 27 % per parameter. The median over the
    scene's parameters must lie within [0.6, 1.6]: a miscalibration by a factor of 2 (a
    missing sqrt(k), variance for standard deviation) fails it.
    """
    from sensaov_cli.buffer.statistics import SUM_VALUE
    from sensaov_cli.job.load import load_job
    from sensaov_cli.progress import Progress
    from sensaov_cli.render.adjoint import run_adjoint
    from sensaov_cli.render.loading import load_job_scene
    from sensaov_cli.render.objectives import build_objectives

    render = {"spp": 32, "max_depth": 3, "seed": 0, "resolution": [16, 16], "batches": 4}
    job = load_job(job_writer("calibration", render=render))
    loaded = load_job_scene(job)
    objectives = build_objectives(loaded.mi, job.objectives, (16, 16), False)
    estimates, errors, element_estimates, element_errors = [], [], [], []
    for seed in range(10):
        result = run_adjoint(
            loaded, objectives, spp=32, seed=1000 + 17 * seed, deterministic=False,
            progress=Progress(quiet=True), batches=4,
        )  # fmt: skip
        stats = result.statistics
        assert stats is not None
        per_batch = stats.batch_sums["mean_luma"][:, :, SUM_VALUE]  # (P, k)
        estimates.append(per_batch.mean(axis=1))
        errors.append(pooled_stderr(per_batch.T, stats.spp))
        key = "light.emitter.radiance.value"
        element_estimates.append(result.grads["mean_luma"][key])
        element_errors.append(stats.stderr["mean_luma"][key])
    spread = np.std(np.array(estimates), axis=0, ddof=1)
    reported = np.sqrt(np.mean(np.array(errors) ** 2, axis=0))
    ratio = spread[reported > 0] / reported[reported > 0]
    assert len(ratio) >= 8 and 0.6 < np.median(ratio) < 1.6, ratio
    element_ratio = np.std(element_estimates, axis=0, ddof=1) / np.sqrt(
        np.mean(np.square(element_errors), axis=0)
    )
    assert np.all((element_ratio > 0.4) & (element_ratio < 2.5)), element_ratio


def test_pooled_variance_matches_monte_carlo() -> None:
    """pool_variance is pool_field's map with squared weights: check it on random fields."""
    from sensaov_cli.views.texels import Pool, pool_field, pool_variance

    rng = np.random.default_rng(3)
    sigma = rng.random((9, 7, 3)) + 0.1
    for pool in (Pool("gaussian", 1.5, ""), Pool("box", 2, ""), Pool("mip", 2, "")):
        for wrap in ("repeat", "clamp", "mirror"):
            draws = np.stack(
                [
                    pool_field(rng.standard_normal(sigma.shape) * sigma, pool, wrap)
                    for _ in range(3000)
                ]
            )
            ratio = draws.var(axis=0) / pool_variance(sigma**2, pool, wrap)
            # 3000 draws: each variance estimate is within ±2.6 % (1 sigma); 189 cells.
            assert abs(np.median(ratio) - 1) < 0.03 and np.abs(ratio - 1).max() < 0.15, pool


def test_texel_fields_carry_standard_errors_and_what_pooling_cut(
    job_writer: Callable[..., Path],
) -> None:
    from sensaov_cli.outputs.exr import read_exr

    render = {**RENDER, "batches": 4, "spp": 32}
    channels = [{"name": "texels", "kind": "texel"}]
    job = job_writer("texel_errors", objectives=OBJECTIVES[:1], render=render, channels=channels)
    assert sensaov("run", str(job), "-q").returncode == 0
    done = sensaov("project", str(job), "-q")
    assert done.returncode == 0, done.stderr
    textures = sorted((job.parent / "out" / "textures").glob("*.exr"))
    assert textures
    channels_, header = read_exr(textures[0])
    assert {"stderr_raw.R", "stderr_pooled.R"} <= set(channels_)
    info = json.loads(header["sensaov/texel"])
    assert 0 < info["stderr_reduction"] < 1  # pooling averages texels: their error shrinks
    raw = channels_["stderr_raw.R"]
    assert raw.max() > 0 and np.all(raw >= 0)


def test_forward_channels_are_rendered_by_batched_runs_and_skipped_by_shards(
    job_writer: Callable[..., Path],
) -> None:
    """A batched run pushes each batch at its own seeds, so it writes the forward sidecar and
    project its layers; a shard renders none, says so, and project names what it left out."""
    forward = [{"name": "light", "object": "light"}]
    job = job_writer(
        "forward_batches", objectives=OBJECTIVES[:1], render={**RENDER, "batches": 2},
        forward=forward,
    )  # fmt: skip
    done = sensaov("run", str(job))
    assert done.returncode == 0, done.stderr
    assert "rendered by whole runs only" not in done.stderr
    assert (job.parent / "out" / "forward.npz").is_file()
    done = sensaov("project", str(job))
    assert done.returncode == 0, done.stderr
    assert "no forward or transport layers" not in done.stderr
    assert "forward.light" in OpenEXR.File(str(job.parent / "out" / "objective.exr")).channels()
    done = sensaov("run", str(job), "--shard", "1/2")
    assert done.returncode == 0, done.stderr
    assert "rendered by whole runs only" in done.stderr
    shard = job.parent / "out" / "buffer.shard-1-of-2.npz"
    done = sensaov("project", str(job), "--buffer", str(shard))
    assert done.returncode == 0, done.stderr
    assert "no forward or transport layers" in done.stderr
