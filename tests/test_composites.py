"""Trust by composition: a parameter's label and integrator follow the composites its
gradient passes. A diffuse child beside a smooth conductor in a blend is right only through
``path`` (prb is 40 % off), the blend's weight is wrong either way and says so, a mask's opacity
goes through ``path``; ``run`` applies it (docs/verification.md, "Composites").
"""

from __future__ import annotations

import re
from pathlib import Path
from types import ModuleType

import pytest
import yaml

from sensaov_cli.job.load import load_job
from sensaov_cli.progress import Progress
from sensaov_cli.render.loading import LoadedScene, load_job_scene
from sensaov_cli.render.objectives import build_objectives
from sensaov_cli.render.verify.fdcheck import audit, check_parameter, plan_audit
from sensaov_cli.render.verify.trust import COMPOSITE_TABLE
from tests.conftest import sensaov, use_scene, write_job

SCENE = """<scene version="3.0.0">
  <integrator type="path"><integer name="max_depth" value="4"/></integrator>
  <sensor type="perspective" id="sensor"><float name="fov" value="40"/>
    <transform name="to_world"><lookat origin="0, 0.3, 3.4" target="0, 0, 0" up="0, 1, 0"/>
    </transform>
    <film type="hdrfilm"><integer name="width" value="16"/><integer name="height" value="16"/>
      <rfilter type="box"/></film></sensor>
  <shape type="sphere" id="blend"><point name="center" x="-0.5" y="0" z="0"/>
    <float name="radius" value="0.5"/>
    <bsdf type="blendbsdf"><float name="weight" value="0.4"/>
      <bsdf type="diffuse"><rgb name="reflectance" value="0.5, 0.6, 0.4"/></bsdf>
      <bsdf type="conductor"/></bsdf></shape>
  <shape type="sphere" id="leaf"><point name="center" x="0.6" y="0" z="0"/>
    <float name="radius" value="0.4"/>
    <bsdf type="mask"><float name="opacity" value="0.6"/><bsdf type="diffuse"/></bsdf></shape>
  <shape type="rectangle" id="floor">
    <transform name="to_world"><scale value="3"/><rotate x="1" angle="-90"/>
      <translate y="-0.5"/></transform>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.6, 0.25, 0.2"/></bsdf></shape>
  <shape type="rectangle" id="light">
    <transform name="to_world"><rotate x="1" angle="90"/><translate x="0.5" y="3" z="2"/>
    </transform><emitter type="area"><rgb name="radiance" value="9, 8, 7"/></emitter></shape>
</scene>"""
WEIGHT, CHILD, OPACITY = (
    "blend.bsdf.weight.value",
    "blend.bsdf.bsdf_0.reflectance.value",
    ("leaf.bsdf.opacity.value"),
)


@pytest.fixture(scope="module")
def job(tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("composites")
    (folder / "scene.xml").write_text(SCENE)
    path = write_job(folder, render={"spp": 16, "seed": 0, "resolution": [16, 16]},
                     parameters={"include": ["blend.*", "leaf.*"]})  # fmt: skip
    use_scene(path, folder / "scene.xml")
    return path


@pytest.fixture(scope="module")
def loaded(mi: ModuleType, job: Path) -> LoadedScene:
    return load_job_scene(load_job(job))


def test_labels_and_integrators_follow_the_composites(loaded: LoadedScene) -> None:
    records = {r.key: r for r in loaded.selected}
    assert loaded.contexts[WEIGHT] == (("blendbsdf", "weight", "smooth"),)
    assert loaded.contexts[CHILD] == (("blendbsdf", "child", "smooth"),)
    assert records[WEIGHT].trust == "biased" and "smooth (delta) child" in records[WEIGHT].note
    assert records[WEIGHT].note == COMPOSITE_TABLE[("blendbsdf", "weight", "smooth")].note
    assert records[CHILD].trust == "verified"
    assert records[OPACITY].trust == "verified"
    assert {loaded.routes[k] for k in (WEIGHT, CHILD, OPACITY)} == {"path"}
    assert loaded.routes["leaf.bsdf.nested_bsdf.reflectance.value"] == "prb"


def test_a_rough_child_beside_a_smooth_one_agrees_only_through_path(
    loaded: LoadedScene, job: Path
) -> None:
    """Same-seed central differences (the child's reflectance does not steer sampling)."""
    (objective,) = build_objectives(loaded.mi, load_job(job).objectives, (16, 16), False)
    info = next(r for r in loaded.selected if r.key == CHILD)
    through_path = check_parameter(loaded, objective, info, spp=16, seeds=[1, 2, 3])
    assert through_path.verdict == "agrees" and through_path.relative_error < 1e-3
    loaded.routes[CHILD] = "prb"  # what sensaov did before: prb for every rough parameter
    try:
        through_prb = check_parameter(loaded, objective, info, spp=16, seeds=[1, 2, 3])
    finally:
        loaded.routes[CHILD] = "path"
    assert through_prb.relative_error > 0.1, through_prb


def test_run_labels_the_blend_weight_in_its_rankings(job: Path, tmp_path: Path) -> None:
    """Without repairs the biased weight is ranked with its mark and its reason; with them
    (the default budget) run computes it again by central differences and says so."""
    spec = yaml.safe_load(job.read_text())
    unrepaired = job.parent / "no_repair.yaml"
    spec.update(repair={"budget": 0}, output=str(tmp_path / "out"))
    unrepaired.write_text(yaml.safe_dump(spec))
    result = sensaov("run", str(unrepaired))
    assert result.returncode == 0, result.stderr
    line = _ranked_row(result.stdout)
    assert " ! " in line and "reverse" in line  # ranked with its mark, its reason in the legend
    assert "a blendbsdf with a smooth (delta) child" in result.stdout
    repaired = sensaov("run", str(job))
    assert repaired.returncode == 0, repaired.stderr
    line = _ranked_row(repaired.stdout)
    assert "finite-difference" in line and " ! " not in line


def _ranked_row(text: str) -> str:
    """The weight's row of the parameters' ranking (a row starts with its rank)."""
    return next(
        line for line in text.splitlines() if WEIGHT in line and re.match(r"\s+\d+\s", line)
    )


def test_check_takes_each_parameters_own_route(loaded: LoadedScene, job: Path) -> None:
    """``sensaov check`` computes its adjoints as a run does: the diffuse child of a blend over a
    smooth conductor through path (its route), not prb (its plugin's integrator), so the
    one-seed comparison agrees to float precision instead of missing by more than 10 %."""
    (objective,) = build_objectives(loaded.mi, load_job(job).objectives, (16, 16), False)
    plan = plan_audit(loaded, [CHILD], full=False)
    assert [r.key for r in plan.one_seed] == [CHILD]
    (check,) = audit(loaded, objective, plan, spp=16, seeds=[1], progress=Progress(quiet=True))
    assert check.verdict == "agrees" and check.relative_error < 1e-3, check
