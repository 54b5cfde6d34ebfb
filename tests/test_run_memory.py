"""``run``'s memory budget holds for large textures: their gradients are counted up front, so a
run is refused in one line before any pass, or its peak resident memory stays within the budget
(measured on a real process)."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

from sensaov_cli.outputs.exr import write_exr
from sensaov_cli.render.loading import gradient_bytes

QUAD = Path(__file__).parent / "scenes" / "texel_quad.xml"
SIDE = 512  # an RGB texture of 786,432 components: its gradients outweigh the 16² passes
MIB = 1 << 20


@pytest.fixture(scope="module")
def texture(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("run_memory") / "texture.exr"
    rng = np.random.default_rng(0)
    write_exr(path, {c: rng.random((SIDE, SIDE), dtype=np.float32) * 0.8 for c in "RGB"}, {})
    return path


def _job(folder: Path, texture: Path, batches: int) -> Path:
    job = {
        "version": 1,
        "scene": str(QUAD),
        "variant": "llvm_ad_rgb",
        "scene_args": {"texture": str(texture)},
        "render": {"spp": 4, "max_depth": 2, "seed": 0, "resolution": [16, 16], "batches": batches},
        "objectives": [{"name": "luma", "type": "mean_luminance"}],
        "output": str(folder / "out"),
    }
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "job.yaml").write_text(yaml.safe_dump(job))
    return folder / "job.yaml"


# The command in a fresh interpreter that writes its own peak resident memory (VmHWM, its
# address space's high-water mark) when it ends: the rusage of a child counts the parent's
# memory at the fork too, so a large test process would hide the command's own peak.
_PEAK_WRAPPER = """
import sys
from pathlib import Path
from sensaov_cli import interrupts
interrupts.install(raising=False)
from sensaov_cli.cli import main
try:
    main(prog_name="sensaov", args=sys.argv[2:])
finally:
    status = Path("/proc/self/status").read_text()
    peak = next(line.split()[1] for line in status.splitlines() if line.startswith("VmHWM:"))
    Path(sys.argv[1]).write_text(peak)  # KiB
"""


def _run(job: Path, budget: str) -> tuple[int, str, float]:
    """Exit code, stderr and peak resident memory (MiB) of ``sensaov run`` in its own process."""
    env = {**os.environ, "SENSAOV_MEMORY_BUDGET": budget}
    peak = job.parent / "peak.txt"
    done = subprocess.run(
        [sys.executable, "-c", _PEAK_WRAPPER, str(peak), "run", str(job), "-q"],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, env=env, text=True, check=False,
    )  # fmt: skip
    return done.returncode, done.stderr, int(peak.read_text()) / 1024


def test_gradients_grow_with_objectives_and_batches() -> None:
    one = gradient_bytes(1000, objectives=1, batches=1)
    assert 0 < one < gradient_bytes(1000, objectives=2, batches=1)
    assert gradient_bytes(1000, objectives=1, batches=4) < gradient_bytes(
        1000, objectives=1, batches=8
    )
    assert gradient_bytes(2000, objectives=1, batches=4) == 2 * gradient_bytes(
        1000, objectives=1, batches=4
    )


def test_a_texture_over_the_budget_is_refused_before_any_pass_and_one_within_stays_within(
    tmp_path: Path, texture: Path
) -> None:
    job = _job(tmp_path / "batched", texture, batches=4)
    code, stderr, refused_peak = _run(job, "200M")
    assert code == 2, stderr
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"sensaov: error: {job}: parameters: "), stderr
    assert "'quad.bsdf.reflectance.data', has 786,432 (512x512x3)" in lines[0]
    assert "in 4 batch(es)" in lines[0] and "Traceback" not in stderr
    need = float(re.search(r"needs about ([0-9.]+) MiB", lines[0]).group(1))  # type: ignore[union-attr]
    assert refused_peak < need  # refused before the passes allocated what it counted
    assert not (job.parent / "out" / "buffer.npz").exists()
    # The budget the check asked for (and a little for the process's own variation) is enough,
    # and the run's measured peak stays within it.
    budget = need + 16
    code, stderr, peak = _run(job, f"{budget:.0f}M")
    assert code == 0, stderr
    assert peak <= budget, f"peak {peak:.0f} MiB over the {budget:.0f} MiB budget"
    assert (job.parent / "out" / "buffer.npz").is_file()
