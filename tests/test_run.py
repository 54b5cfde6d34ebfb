"""`sensaov run` end to end through the command line, as a user or a Makefile calls it."""

from __future__ import annotations

import json
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from sensaov_cli.buffer.npz import read_buffer

from .conftest import sensaov

JOB_EXTRAS = {
    "objectives": [
        {"name": "mean_luma", "type": "mean_luminance"},
        {"name": "centre", "type": "region_luminance", "region": [0.25, 0.25, 0.75, 0.75]},
    ]
}


@pytest.fixture(scope="module")
def first_run(job_writer: Callable[..., Path]) -> tuple[Path, object]:
    job = job_writer("run_a", **JOB_EXTRAS)
    return job, sensaov("run", str(job))


def test_run_writes_buffer_and_primal_and_a_ranked_summary(first_run) -> None:  # noqa: ANN001
    job, done = first_run
    assert done.returncode == 0, done.stderr
    out = job.parent / "out"
    assert sorted(p.name for p in out.iterdir()) == ["buffer.npz", "primal.exr"]  # no leftovers
    assert "objective 'mean_luma'" in done.stdout and "objective 'centre'" in done.stdout
    assert "light.emitter.radiance.value" in done.stdout
    # roughplastic's known-biased gradients are repaired, and the summary says by what
    assert "repairs: 2 parameters known wrong in reverse mode" in done.stdout
    estimators = {p.key: p.estimator for p in read_buffer(out / "buffer.npz").params}
    assert estimators["blue_plastic.eta"] == estimators["blue_plastic.alpha"] == "finite-difference"
    assert estimators["glass.eta"] == "reverse"
    assert "backward pass for 'centre'" in done.stderr  # progress goes to stderr
    assert "repair 2/2 blue_plastic." in done.stderr


def test_buffer_records_how_it_was_made(first_run) -> None:  # noqa: ANN001
    job, _ = first_run
    buffer = read_buffer(job.parent / "out" / "buffer.npz")
    prov = buffer.provenance
    for field in (
        "tool_version",
        "mitsuba_version",
        "drjit_version",
        "variant",
        "scene_fingerprint",
        "job_hash",
        "spp",
        "primal_seed",
        "gradient_seeds",
        "resolution",
        "integrator",
        "wall_time_s",
        "deterministic",
    ):
        assert field in prov, field
    assert prov["resolution"] == [24, 24] and prov["integrator"] == "prb"
    from importlib.metadata import version  # the installed packages the modules came from

    assert (prov["mitsuba_version"], prov["drjit_version"]) == (
        version("mitsuba"),
        version("drjit"),
    )
    seeds = prov["gradient_seeds"]
    assert len(set(seeds.values()) | {prov["primal_seed"]}) == 3  # primal and gradient seeds differ
    assert [o.name for o in buffer.objectives] == ["mean_luma", "centre"]
    assert buffer.objective("centre").definition["region"] == [0.25, 0.25, 0.75, 0.75]


def test_primal_exr_is_the_beauty_with_provenance(first_run) -> None:  # noqa: ANN001
    import OpenEXR

    job, _ = first_run
    with OpenEXR.File(str(job.parent / "out" / "primal.exr")) as exr:
        provenance = json.loads(exr.header()["sensaov/provenance"])
        pixels = exr.channels()["RGB"].pixels.copy()
    assert pixels.shape == (24, 24, 3) and pixels.dtype == np.float32
    assert np.isfinite(pixels).all() and pixels.mean() > 0
    assert provenance["tool"] == "sensaov"


def test_json_summary_is_machine_readable(job_writer: Callable[..., Path]) -> None:
    job = job_writer("run_json")
    done = sensaov("run", str(job), "--json", "-q")
    assert done.returncode == 0 and done.stderr == ""
    summary = json.loads(done.stdout)
    assert summary["files"]["buffer"].endswith("buffer.npz")
    params = summary["objectives"][0]["parameters"]
    assert any(p["verified"] is False for p in params) or all("verified" in p for p in params)


def test_same_seed_gives_byte_identical_gradients(
    first_run, job_writer: Callable[..., Path]
) -> None:  # noqa: ANN001
    job_a, _ = first_run
    a = read_buffer(job_a.parent / "out" / "buffer.npz")
    assert a.provenance["deterministic"] is False  # the default: all threads
    render = {"spp": 16, "max_depth": 6, "seed": 0, "resolution": [24, 24], "deterministic": True}
    job_c = job_writer("run_c", render=render, **JOB_EXTRAS)
    job_b = job_writer("run_b", render=render, **JOB_EXTRAS)
    assert sensaov("run", "-q", str(job_b)).returncode == 0
    assert sensaov("run", "-q", str(job_c)).returncode == 0
    a = read_buffer(job_c.parent / "out" / "buffer.npz")
    b = read_buffer(job_b.parent / "out" / "buffer.npz")
    assert a.provenance["deterministic"] is True
    for objective in ("mean_luma", "centre"):
        for key in a.keys:
            assert a.grad(objective, key).tobytes() == b.grad(objective, key).tobytes(), key


def test_another_seed_gives_other_gradients(first_run, job_writer: Callable[..., Path]) -> None:  # noqa: ANN001
    job_a, _ = first_run
    render = {"spp": 16, "max_depth": 6, "seed": 1, "resolution": [24, 24]}
    job_c = job_writer("run_c", render=render, **JOB_EXTRAS)
    assert sensaov("run", "-q", str(job_c)).returncode == 0
    a = read_buffer(job_a.parent / "out" / "buffer.npz")
    c = read_buffer(job_c.parent / "out" / "buffer.npz")
    assert not np.array_equal(
        a.grad("mean_luma", "green.reflectance.value"),
        c.grad("mean_luma", "green.reflectance.value"),
    )


RENDERER_MODULES = ("mitsuba", "drjit")


def run_without(modules: tuple[str, ...], *args: str) -> str:
    """Run the CLI in a fresh interpreter; fail if it imported any of ``modules``."""
    import subprocess

    code = (
        "import sys\nfrom sensaov_cli.cli import main\n"
        f"sys.argv = ['sensaov', *{list(args)!r}]\n"
        "try:\n    main()\nexcept SystemExit:\n    pass\n"
        f"loaded = [m for m in {list(modules)!r} if m in sys.modules]\n"
        "assert not loaded, f'imported {loaded}'\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    return done.stdout


def test_rank_reads_the_buffer_without_mitsuba(first_run) -> None:  # noqa: ANN001
    job, _ = first_run
    stdout = run_without(RENDERER_MODULES, "rank", str(job.parent / "out" / "buffer.npz"), "--json")
    assert json.loads(stdout)["objectives"][0]["name"] == "mean_luma"


def test_indirect_only_wall_and_hidden_light_matter(job_writer: Callable[..., Path]) -> None:
    """The paper's point: surfaces and lights not in the frame still get sensitivity."""
    job = job_writer("interior", scene="interior")
    assert sensaov("run", "-q", str(job)).returncode == 0
    buffer = read_buffer(job.parent / "out" / "buffer.npz")
    from sensaov_cli.buffer.queries import per_object

    scores = per_object(buffer, "mean_luma", method="sum", weight="value")
    assert scores["front_wall"] > 0 and scores["ceiling_light"] > 0


def test_failed_objective_leaves_no_files(tmp_path: Path) -> None:
    from .conftest import write_job

    (tmp_path / "nanobj.py").write_text(
        "import drjit as dr\ndef f(image):\n    return dr.sum(image, axis=None) * float('nan')\n"
    )
    job = write_job(
        tmp_path, objectives=[{"name": "bad", "type": "python", "function": "nanobj:f"}]
    )
    refused = sensaov("run", str(job))
    assert refused.returncode == 2 and "--allow-python" in refused.stderr
    failed = sensaov("run", str(job), "--allow-python")
    assert failed.returncode == 1
    assert "NaN" in failed.stderr.splitlines()[-1] and "Traceback" not in failed.stderr
    assert not (tmp_path / "out").exists()


def test_help_does_not_import_the_renderer_or_pydantic() -> None:
    assert "sensaov run" in run_without((*RENDERER_MODULES, "pydantic"), "--help")


def test_schema_is_json(tmp_path: Path) -> None:
    done = sensaov("schema")
    assert done.returncode == 0
    assert "objectives" in json.loads(done.stdout)["properties"]


def test_params_json_reports_converted_textures(job_writer: Callable[..., Path]) -> None:
    done = sensaov("params", str(job_writer("params")), "--json")
    assert done.returncode == 0, done.stderr
    report = json.loads(done.stdout)
    texture = next(p for p in report["selected"] if p["key"] == "checker.reflectance.data")
    assert texture["converted"] is True
    assert any(e["reason"].startswith("geometry") for e in report["excluded"])


def test_a_selection_that_matches_nothing_is_bad_input(job_writer: Callable[..., Path]) -> None:
    job = job_writer("nothing", parameters={"include": ["no_such_object.*"]})
    done = sensaov("run", str(job))
    assert done.returncode == 2
    assert "no scene parameter is selected" in done.stderr and "sensaov params" in done.stderr
    assert not (job.parent / "out").exists()


def test_a_stop_requested_during_a_kernel_writes_nothing(
    job_writer: Callable[..., Path], monkeypatch: pytest.MonkeyPatch
) -> None:
    """A KeyboardInterrupt can be swallowed inside Dr.Jit callbacks; the recorded request is not."""
    from sensaov_cli import interrupts
    from sensaov_cli.job.load import load_job
    from sensaov_cli.pipeline.run import run_job
    from sensaov_cli.progress import Progress

    job = job_writer("stopped")
    monkeypatch.setattr(interrupts, "_signal", [__import__("signal").SIGINT])
    with pytest.raises(KeyboardInterrupt):
        run_job(load_job(job), allow_python=False, progress=Progress(quiet=True))
    assert not (job.parent / "out").exists()


def test_outputs_are_replaced_together_or_not_at_all(tmp_path: Path) -> None:
    from sensaov_cli.outputs.atomic import atomic_write_all

    first, second = tmp_path / "buffer.npz", tmp_path / "primal.exr"
    first.write_text("old buffer")
    second.write_text("old primal")

    def broken(tmp: Path) -> None:
        raise OSError("disk full")

    with pytest.raises(OSError):
        atomic_write_all([(first, lambda tmp: tmp.write_text("new")), (second, broken)])
    assert first.read_text() == "old buffer" and second.read_text() == "old primal"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["buffer.npz", "primal.exr"]


def test_an_output_name_taken_by_a_folder_fails_before_rendering(
    job_writer: Callable[..., Path],
) -> None:
    job = job_writer("taken")
    (job.parent / "out" / "primal.exr").mkdir(parents=True)
    done = sensaov("run", str(job))
    assert done.returncode == 2 and "primal.exr is a directory" in done.stderr
    assert "primal render" not in done.stderr  # refused before any work
    assert sorted(p.name for p in (job.parent / "out").iterdir()) == ["primal.exr"]


def test_json_stays_json_when_mitsuba_logs(job_writer: Callable[..., Path]) -> None:
    job = job_writer("mono", variant="llvm_ad_mono")  # Mitsuba warns about monochrome films
    done = sensaov("run", str(job), "--json", "-q")
    assert done.returncode == 0, done.stderr
    assert "Monochrome" in done.stderr
    assert json.loads(done.stdout)["objectives"][0]["value"] > 0


def test_check_refuses_an_unknown_key(job_writer: Callable[..., Path]) -> None:
    done = sensaov("check", str(job_writer("check_key")), "--key", "green.reflectance")
    assert done.returncode == 2
    assert "did you mean 'green.reflectance.value'" in done.stderr
