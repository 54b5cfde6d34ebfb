"""Sweep Mitsuba's public scene data: does every scene load, and does every `verified` kind agree
with finite differences there?

For each scene XML given (a checkout of ``mitsuba-renderer/mitsuba-data``: ``docs/scenes``,
``tests/scenes``), a plain job (32x24, the scene's own integrator and depth) is prepared and
loaded as ``sensaov run`` would; one parameter of each kind the run would label `verified` is
checked against central differences: at the same seed where the parameter does not steer
sampling, with independent seeds at a higher sample count where it does (roughness, IOR,
blend and lobe weights, opacity, bump and normal maps, extinction, anisotropy), as
``scripts/trust_table.py`` does. Prints a markdown table: the scene, whether it loads (or why
not), the kinds checked, and any verified kind that disagrees.

    .venv/bin/python scripts/public_scenes.py /path/to/mitsuba-data/docs/scenes/bsdf_*.xml
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import yaml

from sensaov_cli.errors import SensaovError
from sensaov_cli.job.load import load_job
from sensaov_cli.render.loading import LoadedScene, load_job_scene
from sensaov_cli.render.objectives import build_objectives
from sensaov_cli.render.verify.fdcheck import check_parameter

STEERING = ("roughness", "eta", "weight", "opacity", "bump", "normal", "sigma_t", "g",
            "metallic", "spec_trans", "clearcoat", "specular", "anisotropic")  # fmt: skip
SAME_SEED_PLUGINS = ("conductor", "roughconductor")  # their eta and k steer nothing
WIDTH, HEIGHT, SPP, SEEDS = 32, 24, 32, 6
AD_SPP, FD_SPP, IND_SEEDS = 64, 1024, 8


def job_for(scene: Path, folder: Path) -> Path:
    job = {
        "version": 1,
        "scene": str(scene.absolute()),
        "variant": "llvm_ad_rgb",
        "render": {"spp": SPP, "seed": 0, "resolution": [WIDTH, HEIGHT]},
        "objectives": [{"name": "mean_luma", "type": "mean_luminance"}],
        "output": str(folder / "out"),
    }
    path = folder / "job.yaml"
    path.write_text(yaml.safe_dump(job, sort_keys=False))
    return path


def steers(plugin: str, ptype: str) -> bool:
    return ptype in STEERING and not (plugin in SAME_SEED_PLUGINS and ptype in ("eta", "k"))


def sweep(scene: Path, kinds_per_scene: int) -> str:
    started = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="sensaov-public-") as tmp:
        try:
            job = load_job(job_for(scene, Path(tmp)))
            loaded = load_job_scene(job)
        except SensaovError as exc:
            return f"| {scene.name} | refused: {str(exc)[:120]} | | |"
        except Exception as exc:  # noqa: BLE001 - a sweep reports every failure and goes on
            return f"| {scene.name} | FAILED: {type(exc).__name__}: {str(exc)[:100]} | | |"
        (objective,) = build_objectives(loaded.mi, job.objectives, (HEIGHT, WIDTH), False)
        checked, wrong = [], []
        for info in _representatives(loaded)[:kinds_per_scene]:
            if steers(info.plugin, info.type):
                check = check_parameter(
                    loaded, objective, info, spp=AD_SPP, fd_spp=FD_SPP,
                    seeds=list(range(IND_SEEDS)),
                )  # fmt: skip
            else:
                check = check_parameter(loaded, objective, info, spp=SPP, seeds=list(range(SEEDS)))
            checked.append(f"{info.plugin} {info.type}: {check.verdict}")
            if check.verdict == "disagrees":
                wrong.append(f"`{info.key}` {check.adjoint:+.3e} vs {check.finite_difference:+.3e}")
    seconds = time.perf_counter() - started
    loads = f"loads ({loaded.prepared.integrator}, {seconds:.0f} s)"
    return f"| {scene.name} | {loads} | {'; '.join(checked)} | {'; '.join(wrong) or 'none'} |"


def _representatives(loaded: LoadedScene) -> list:
    """One selected, verified parameter per (plugin, type) kind, textures apart."""
    seen: dict = {}
    for info in loaded.selected:
        if info.trust == "verified":
            seen.setdefault((info.plugin, info.type, info.is_texture), info)
    return list(seen.values())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("scenes", nargs="+", type=Path)
    parser.add_argument("--kinds", type=int, default=6, help="verified kinds checked per scene")
    args = parser.parse_args()
    print("| scene | loads | verified kinds checked | disagreeing |\n|---|---|---|---|")
    for scene in args.scenes:
        print(sweep(scene, args.kinds), flush=True)
        print(f"done {scene}", file=sys.stderr)


if __name__ == "__main__":
    main()
