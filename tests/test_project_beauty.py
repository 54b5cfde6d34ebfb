"""The objective camera's beauty is run's own primal when it can stand in for the quick pass."""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from sensaov_cli.outputs.atomic import PROVENANCE_ATTRIBUTE
from sensaov_cli.outputs.exr import read_exr, write_exr

from .conftest import sensaov

CAMERAS = [
    {"name": "objective", "objective": True, "vis_spp": 4},
    {
        "name": "high",
        "look_at": {"origin": [0.3, 0.6, 3.2], "target": [0, -0.2, 0], "up": [0, 1, 0]},
        "fov": 45,
        "resolution": [20, 16],
        "vis_spp": 4,
    },
]
RUN_SPP = 16  # conftest's job


@pytest.fixture(scope="module")
def ran(job_writer: Callable[..., Path]) -> Path:
    job = job_writer("project_beauty", inspection_cameras=CAMERAS)
    done = sensaov("run", "-q", str(job))
    assert done.returncode == 0, done.stderr
    return job


@pytest.fixture
def copy(ran: Path, tmp_path: Path) -> Path:
    """The job and its run's outputs in a folder of the test's own, as deep as the first one
    (the job's version hashes its paths relative to its folder)."""
    shutil.copytree(ran.parent, tmp_path, dirs_exist_ok=True)
    job = tmp_path / "job.yaml"
    job.write_text(job.read_text().replace(str(ran.parent), str(tmp_path)))
    return job


def _beauty(out: Path, camera: str) -> tuple[np.ndarray, dict]:
    channels, header = read_exr(out / f"{camera}.exr")
    made = json.loads(header[PROVENANCE_ATTRIBUTE])
    return np.stack([channels[c] for c in "RGBA"], axis=-1), made


def _primal(out: Path) -> np.ndarray:
    channels, _ = read_exr(out / "primal.exr")
    return np.stack([channels[c] for c in "RGB"], axis=-1)


def test_the_objective_camera_shows_the_runs_primal_and_the_others_a_quick_trace(
    copy: Path,
) -> None:
    done = sensaov("project", str(copy))
    assert done.returncode == 0, done.stderr
    out = copy.parent / "out"
    beauty, made = _beauty(out, "objective")
    np.testing.assert_array_equal(beauty[..., :3], _primal(out))  # the very pixels, not a copy
    assert made["beauty"] == f"primal.exr of the buffer's run ({RUN_SPP} spp)"
    assert "beauty: primal.exr" in done.stdout
    alpha = beauty[..., 3]
    assert 0 < alpha.min() <= alpha.max() <= 1  # the visibility coverage: cbox is closed
    _, high = _beauty(out, "high")
    assert high["beauty"] == "path trace at 4 spp"


def test_asking_for_more_samples_than_the_run_had_renders_the_quick_pass(copy: Path) -> None:
    done = sensaov("project", str(copy), "--camera", "objective", "--beauty-spp", "32")
    assert done.returncode == 0, done.stderr
    assert f"it has {RUN_SPP} spp, fewer than the 32 asked for" in done.stderr
    out = copy.parent / "out"
    beauty, made = _beauty(out, "objective")
    assert made["beauty"] == "path trace at 32 spp"
    assert not np.array_equal(beauty[..., :3], _primal(out))


def test_a_primal_of_another_buffer_is_not_shown(copy: Path) -> None:
    out = copy.parent / "out"
    channels, header = read_exr(out / "primal.exr")
    provenance = json.loads(header[PROVENANCE_ATTRIBUTE])
    provenance["buffer_id"] = "another-run"
    write_exr(out / "primal.exr", channels, {PROVENANCE_ATTRIBUTE: json.dumps(provenance)})
    done = sensaov("project", str(copy), "--camera", "objective")
    assert done.returncode == 0, done.stderr
    said = (
        "primal.exr not used as the objective camera's beauty: it was not written with this buffer"
    )
    assert said in done.stderr
    beauty, made = _beauty(out, "objective")
    assert made["beauty"] == "path trace at 4 spp"
    assert not np.array_equal(beauty[..., :3], _primal(out))


def test_a_truncated_primal_is_said_and_the_view_still_written(copy: Path) -> None:
    primal = copy.parent / "out" / "primal.exr"
    primal.write_bytes(primal.read_bytes()[:300])
    done = sensaov("project", str(copy), "--camera", "objective")
    assert done.returncode == 0, done.stderr
    assert "primal.exr not used as the objective camera's beauty" in done.stderr
    assert _beauty(copy.parent / "out", "objective")[1]["beauty"] == "path trace at 4 spp"


def test_force_renders_the_beauty_since_the_scene_may_have_changed(copy: Path) -> None:
    primal = copy.parent / "out" / "primal.exr"
    primal.write_bytes(primal.read_bytes()[:300])  # not even read with --force: nothing said
    done = sensaov("project", str(copy), "--camera", "objective", "--force")
    assert done.returncode == 0, done.stderr
    assert "primal.exr" not in done.stderr
    assert _beauty(copy.parent / "out", "objective")[1]["beauty"] == "path trace at 4 spp"


def test_no_beauty_asked_means_none_even_with_a_primal(copy: Path) -> None:
    done = sensaov("project", str(copy), "--camera", "objective", "--beauty-spp", "0")
    assert done.returncode == 0, done.stderr
    channels, header = read_exr(copy.parent / "out" / "objective.exr")
    assert "R" not in channels
    assert json.loads(header[PROVENANCE_ATTRIBUTE])["beauty"] == "none (--beauty-spp 0)"


def test_a_camera_named_primal_may_not_overwrite_the_runs_primal(copy: Path) -> None:
    text = copy.read_text().replace("name: high", "name: primal")
    copy.write_text(text)
    primal = copy.parent / "out" / "primal.exr"
    before = primal.read_bytes()
    done = sensaov("project", str(copy), "--camera", "primal")
    assert done.returncode == 2, done.stderr
    assert "Traceback" not in done.stderr and len(done.stderr.strip().splitlines()) == 1
    assert primal.read_bytes() == before
