"""One consistent state: every output records its buffer, and nothing mixes two states.

Which outputs belong together, played on one small job in order (each step's result recorded
once, checked by its own test): rename an objective and re-run; re-run `run` alone; project a
buffer of an earlier job version; share an output folder with another job; `rank --exr` with an
EXR of another buffer.
"""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path
from typing import Any

import pytest
import yaml

from sensaov_cli.errors import EXIT_BAD_INPUT
from sensaov_cli.outputs.exr import read_exr
from sensaov_cli.outputs.previews import read_png_text

from .conftest import sensaov, write_job
from .test_rankings import DEMO_CAMERAS

Steps = dict[str, Any]


def _rename(job: Path, old: str, new: str) -> None:
    data = yaml.safe_load(job.read_text())
    for objective in data["objectives"]:
        if objective["name"] == old:
            objective["name"] = new
    job.write_text(yaml.safe_dump(data, sort_keys=False))


def _set(job: Path, section: str, key: str, value: object) -> None:
    data = yaml.safe_load(job.read_text())
    data[section][key] = value
    job.write_text(yaml.safe_dump(data, sort_keys=False))


def _ok(result: subprocess.CompletedProcess[str]) -> subprocess.CompletedProcess[str]:
    assert result.returncode == 0, result.stderr
    return result


@pytest.fixture(scope="module")
def steps(tmp_path_factory: pytest.TempPathFactory) -> Steps:
    folder = tmp_path_factory.mktemp("consistency")
    channels = [{"name": "objects", "kind": "object"}]
    job = write_job(folder, inspection_cameras=DEMO_CAMERAS, channels=channels)
    out = folder / "out"
    found: Steps = {"job": job, "out": out}
    _ok(sensaov("run", "-q", str(job)))
    _ok(sensaov("project", "-q", str(job), "--png"))
    _ok(sensaov("report", str(job)))
    shutil.copy(out / "overhead.exr", folder / "before.exr")
    found["before_exr"] = folder / "before.exr"
    # 1. rename the objective: the old buffer no longer belongs to the job
    _rename(job, "mean_luma", "brightness")
    found["project_old_buffer"] = sensaov("project", "-q", str(job))
    found["report_old_buffer"] = sensaov("report", str(job))
    # ... then re-run, project and report: nothing of the old objective may show
    _ok(sensaov("run", "-q", str(job)))
    _ok(sensaov("project", "-q", str(job), "--png"))
    found["report_renamed"] = _ok(sensaov("report", str(job)))
    found["html_renamed"] = (out / "report.html").read_text(encoding="utf-8")
    found["previews_renamed"] = sorted(p.name for p in (out / "previews").rglob("*.png"))
    # 2. rank --exr with an EXR projected from the earlier buffer
    found["rank_old_exr"] = sensaov(
        "rank", str(out / "buffer.npz"), "--by", "object", "--exr", str(found["before_exr"])
    )
    found["rank_new_exr"] = sensaov(
        "rank", str(out / "buffer.npz"), "--by", "object", "--exr", str(out / "overhead.exr")
    )
    # 3. another job writing into the same folder
    other = write_job(folder / "other", output=str(out), channels=channels,
                      objectives=[{"name": "centre", "type": "region_luminance",
                                   "region": [0.3, 0.2, 0.7, 0.6]}])  # fmt: skip
    found["project_other_job"] = sensaov("project", "-q", str(other))
    # 4. re-run `run` alone at another spp: the EXRs and previews are now stale
    _set(job, "render", "spp", 8)
    _ok(sensaov("run", "-q", str(job)))
    found["report_stale"] = sensaov("report", str(job))
    return found


def _one_line(result: subprocess.CompletedProcess[str]) -> str:
    assert result.returncode == EXIT_BAD_INPUT, result.stderr
    (line,) = result.stderr.strip().splitlines()
    return line


def test_project_refuses_a_buffer_of_an_earlier_job_version(steps: Steps) -> None:
    line = _one_line(steps["project_old_buffer"])
    assert "the buffer was made by another version of job.yaml (objectives differ)" in line
    assert "re-run 'sensaov run" in line


def test_report_refuses_a_buffer_of_an_earlier_job_version(steps: Steps) -> None:
    line = _one_line(steps["report_old_buffer"])
    assert "another version of job.yaml (objectives differ)" in line


def test_after_a_rename_the_report_shows_only_the_new_objective(steps: Steps) -> None:
    assert "mean_luma" not in steps["html_renamed"]
    assert "brightness" in steps["html_renamed"]
    assert steps["previews_renamed"] and not [
        name for name in steps["previews_renamed"] if "mean_luma" in name
    ]  # project replaced its own previews of the old state


def test_every_output_records_the_buffer_it_was_made_from(steps: Steps) -> None:
    out = steps["out"]
    _, header = read_exr(out / "overhead.exr")
    made = header["sensaov/buffer_id"]
    previews = list((out / "previews").rglob("*.png"))
    assert previews and {read_png_text(p)["sensaov/buffer_id"] for p in previews} == {made}
    assert f'data-buffer-id="{made}"' in steps["html_renamed"]  # the page's sections
    assert "made from buffer id" in steps["html_renamed"]


def test_rank_refuses_an_exr_of_another_buffer(steps: Steps) -> None:
    line = _one_line(steps["rank_old_exr"])
    assert "before.exr: was made from another buffer" in line
    assert steps["rank_new_exr"].returncode == 0, steps["rank_new_exr"].stderr


def test_project_refuses_the_buffer_of_another_job_in_its_folder(steps: Steps) -> None:
    assert "another version of job.yaml" in _one_line(steps["project_other_job"])


def test_report_refuses_previews_of_an_earlier_run(steps: Steps) -> None:
    line = _one_line(steps["report_stale"])
    assert "was made from another buffer" in line and "re-run 'sensaov project" in line
