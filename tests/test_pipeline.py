"""The wiring of the commands: each prepares its scene once and passes the prepared value down.

The expansion reads the scene file once per preparation, so counting the reads of the main
scene file counts preparations, through whatever path a command takes (a fingerprint check, the
refusal to overwrite inputs, loading, a resume check).
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import pytest
from click.testing import CliRunner

from sensaov_cli import interrupts
from sensaov_cli.cli import main
from sensaov_cli.job.load import load_job
from sensaov_cli.scene import expand

CHANNELS = [{"name": "objects", "kind": "object"}]
CAMERAS = [{"name": "top", "look_at": {"origin": [0, 1, 3], "target": [0, 0, 0], "up": [0, 1, 0]},
            "resolution": [16, 16], "vis_spp": 1}]  # fmt: skip


@pytest.fixture
def expansions(monkeypatch: pytest.MonkeyPatch) -> Callable[[Path], int]:
    """How often each file was read as a scene XML since the fixture started."""
    reads: list[Path] = []
    original = expand.read_xml

    def counting(path: Path):  # type: ignore[no-untyped-def]
        reads.append(Path(path).resolve())
        return original(path)

    monkeypatch.setattr(expand, "read_xml", counting)
    monkeypatch.setattr(interrupts, "install", lambda **_: None)
    return lambda scene: reads.count(scene.resolve())


@pytest.mark.parametrize("command", ["run", "project", "validate", "params"])
def test_a_command_prepares_its_scene_once(
    command: str, expansions: Callable[[Path], int], job_writer: Callable[..., Path]
) -> None:
    job = job_writer(f"once_{command}", channels=CHANNELS, inspection_cameras=CAMERAS)
    scene = load_job(job).scene
    runner = CliRunner()
    if command == "project":  # needs a buffer: made first, then the count starts again
        assert runner.invoke(main, ["run", str(job), "-q"]).exit_code == 0
        before = expansions(scene)
    else:
        before = 0
    result = runner.invoke(main, [command, str(job), *(["-q"] if command == "run" else [])])
    assert result.exit_code == 0, result.output
    assert expansions(scene) - before == 1


def test_run_with_resume_prepares_once(
    expansions: Callable[[Path], int], job_writer: Callable[..., Path]
) -> None:
    job = job_writer("once_resume")
    scene = load_job(job).scene
    runner = CliRunner()
    assert runner.invoke(main, ["run", str(job), "-q"]).exit_code == 0
    assert expansions(scene) == 1
    skipped = runner.invoke(main, ["run", str(job), "--resume"])
    assert skipped.exit_code == 0 and "skipped (--resume)" in skipped.output
    assert expansions(scene) == 2


def test_the_count_sees_every_expansion(
    expansions: Callable[[Path], int], job_writer: Callable[..., Path]
) -> None:
    """The probe itself works: two expansions of the scene are two reads of its file."""
    scene = load_job(job_writer("probe")).scene
    expand.expand_scene(scene, {})
    expand.expand_scene(scene, {})
    assert expansions(scene) == 2
