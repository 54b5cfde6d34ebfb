"""Shared fixtures. Renders are expensive: anything rendered is session-scoped and tiny."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from types import ModuleType

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
SCENES = ROOT / "scenes"


@pytest.fixture(scope="session")
def mi() -> ModuleType:
    from sensaov_cli.render.runtime import import_mitsuba

    return import_mitsuba("llvm_ad_rgb")


def write_job(folder: Path, scene: str = "cbox", **overrides: object) -> Path:
    """A small job on a shipped scene (24x24, 16 spp), written to ``folder/job.yaml``."""
    job: dict[str, object] = {
        "version": 1,
        "scene": str(SCENES / scene / "scene.xml"),
        "variant": "llvm_ad_rgb",
        "render": {"spp": 16, "max_depth": 6, "seed": 0, "resolution": [24, 24]},
        "objectives": [{"name": "mean_luma", "type": "mean_luminance"}],
        "output": str(folder / "out"),
    }
    job.update(overrides)
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / "job.yaml"
    path.write_text(yaml.safe_dump(job, sort_keys=False))
    return path


@pytest.fixture(scope="session")
def job_writer(tmp_path_factory: pytest.TempPathFactory) -> Callable[..., Path]:
    def make(name: str, scene: str = "cbox", **overrides: object) -> Path:
        return write_job(tmp_path_factory.mktemp(name), scene, **overrides)

    return make


def sensaov(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess[str]:
    """Run the command line as a user would, in a fresh process."""
    return subprocess.run(
        [sys.executable, "-m", "sensaov_cli", *args], cwd=cwd, capture_output=True, text=True
    )


def use_scene(job: Path, scene: Path) -> None:
    """Point a job ``write_job`` wrote at a scene outside ``scenes/`` (a test's own)."""
    data = yaml.safe_load(job.read_text())
    data["scene"] = str(scene)
    job.write_text(yaml.safe_dump(data, sort_keys=False))
