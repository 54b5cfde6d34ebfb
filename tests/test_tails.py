"""Heavy tails and lost zeros in verification: near-specular lobes are repaired, zero albedo and
extinction are caught, and ``sensaov check`` says noisy or inconclusive, with its reason, where
it cannot decide (render/verify/tails.py, selfcheck.py, fdcheck.py)."""

from __future__ import annotations

import json
import math
from pathlib import Path
from types import ModuleType

import numpy as np
import pytest
import yaml

from sensaov_cli.buffer.model import ParamRecord, SensitivityBuffer
from sensaov_cli.job.load import load_job
from sensaov_cli.pipeline.run import run_job
from sensaov_cli.progress import Progress
from sensaov_cli.render.adjoint import render_primal
from sensaov_cli.render.loading import LoadedScene, assign, load_job_scene
from sensaov_cli.render.objectives import build_objectives, value_and_adjoint
from sensaov_cli.render.verify.fdcheck import (
    SAME_SEED_TOLERANCE,
    audit,
    check_parameter,
    judge,
    plan_audit,
)
from sensaov_cli.render.verify.repair import planned
from sensaov_cli.render.verify.selfcheck import check_gradients
from sensaov_cli.render.verify.tails import NEAR_SPECULAR_ROUGHNESS
from tests.conftest import sensaov

SCENES = Path(__file__).resolve().parent / "scenes"
ETA = "glass_ball.bsdf.eta"  # roughness checkerboard 0 / 0.4
ALPHA0 = "glass_ball.bsdf.alpha.color0.value"
FROSTED = "frosted_ball.bsdf.eta"  # roughness 0.3
ALBEDO = "fog.albedo.value.value"  # (0.8, 0, 0.6)


def _job(folder: Path, scene: str, **render: object) -> Path:
    job = {
        "version": 1, "scene": str(SCENES / scene), "variant": "llvm_ad_rgb",
        "render": {"spp": 16, "seed": 0, "resolution": [16, 16], **render},
        "objectives": [{"name": "mean_luma", "type": "mean_luminance"}],
        "repair": {"budget": 20, "seeds": 8},
        "output": str(folder / "out"),
    }  # fmt: skip
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "job.yaml").write_text(yaml.safe_dump(job))
    return folder / "job.yaml"


@pytest.fixture(scope="module")
def near_job(tmp_path_factory: pytest.TempPathFactory) -> Path:
    return _job(tmp_path_factory.mktemp("near_specular"), "near_specular.xml", batches=4)


@pytest.fixture(scope="module")
def near_loaded(mi: ModuleType, near_job: Path) -> LoadedScene:
    return load_job_scene(load_job(near_job))


@pytest.fixture(scope="module")
def near_buffer(near_job: Path) -> SensitivityBuffer:
    return run_job(load_job(near_job), allow_python=False, progress=Progress(quiet=True))


# --- near-specular lobes go to a repair ----------------------------------------------------


def test_near_specular_parameters_are_planned_for_repair(near_loaded: LoadedScene) -> None:
    reasons = planned(near_loaded)
    for key in (ETA, ALPHA0, "glass_ball.bsdf.alpha.color1.value"):
        assert key in reasons and "near-specular: its roughness goes down to 0" in reasons[key]
    assert FROSTED not in reasons and "frosted_ball.bsdf.alpha.value" not in reasons
    assert 0.0 < NEAR_SPECULAR_ROUGHNESS <= 0.05  # at 0.05 reverse mode is as tame as a repair


def test_a_near_specular_eta_is_never_verified_and_agrees_with_central_differences(
    near_buffer: SensitivityBuffer, near_job: Path
) -> None:
    """The acceptance: its η is repaired, so it is not reverse mode's heavy-tailed value; it is
    not labelled verified (the repair of this kind is not measured); and it lies within 3
    combined standard errors of central differences at other seeds and samples."""
    record = near_buffer.param(ETA)
    assert record.estimator == "finite-difference" and record.trust != "verified"
    assert "near-specular" in record.note
    repair = near_buffer.repairs[ETA]
    estimates = repair.estimates["mean_luma"][:, 0]
    value, error = estimates.mean(), estimates.std(ddof=1) / math.sqrt(len(estimates))
    reference, ref_error = _central_differences(near_job, ETA, seeds=range(100, 112), spp=32)
    assert abs(value - reference) <= 3 * math.hypot(error, ref_error), (value, reference)
    assert near_buffer.param(FROSTED).estimator == "reverse"  # a rough lobe keeps reverse mode


def _central_differences(job: Path, key: str, seeds: range, spp: int) -> tuple[float, float]:
    """Mean and standard error over ``seeds`` of (M(θ+ε) − M(θ−ε)) / 2ε, ε = 0.02 (twice the
    repair's step), each seed's sides with common random numbers."""
    spec = load_job(job)
    loaded = load_job_scene(spec)
    (objective,) = build_objectives(loaded.mi, spec.objectives, (16, 16), False)
    theta = np.array(loaded.params[key], dtype=np.float32)
    rows = []
    for seed in seeds:
        sides = []
        for sign in (1, -1):
            assign(loaded, key, theta + sign * 0.02)
            image = render_primal(loaded, spp, seed)
            sides.append(value_and_adjoint(loaded.mi, objective, image)[0])
        rows.append((sides[0] - sides[1]) / 0.04)
    assign(loaded, key, theta)
    return float(np.mean(rows)), float(np.std(rows, ddof=1) / math.sqrt(len(rows)))


# --- zero values outside BSDFs ----------------------------------------------------------------


def test_a_zero_albedo_channel_is_repaired(near_buffer: SensitivityBuffer) -> None:
    """prbvolpath ends the path at a scattering event of albedo 0, so its gradient there is 0
    (central differences: about +0.02 here); the self-check catches it and the repair
    replaces it."""
    record = near_buffer.param(ALBEDO)
    assert record.estimator == "finite-difference" and record.trust != "verified"
    assert "zero throughput ends the path" in record.note
    assert near_buffer.repairs[ALBEDO].reverse["mean_luma"][1] == 0.0  # reverse mode lost it
    assert near_buffer.grad("mean_luma", ALBEDO)[1] > 0.003


@pytest.mark.parametrize(
    ("plugin", "ptype", "found"),
    [
        ("homogeneous", "albedo", "zero throughput ends the path"),
        ("heterogeneous", "albedo", "zero throughput ends the path"),
        ("homogeneous", "sigma_t", "no interaction"),
        ("heterogeneous", "scale", "no interaction"),
        ("diffuse", "reflectance", "zero throughput ends the path"),
        ("area", "radiance", None),  # a zero radiance ends no path
        ("envmap", "scale", None),
    ],
)
def test_zero_values_that_lose_the_derivative(plugin: str, ptype: str, found: str | None) -> None:
    record = ParamRecord("k", ptype, ("o",), (3,), False, plugin, (), "verified", "")
    values = {"k": np.array([0.5, 0.0, 0.2], np.float32)}
    grads = {"m": {"k": np.ones(3, np.float32)}}
    (done,) = check_gradients([record], values, grads, {}, (), 16, {"k": "prb"}).params
    if found is None:
        assert done.trust == "verified"
    else:
        assert done.trust == "unverified" and found in done.note and "[1] of 3" in done.note


# --- sensaov check: references valid for the scene, and reasons ------------------------------


@pytest.fixture(scope="module")
def roulette(mi: ModuleType, tmp_path_factory: pytest.TempPathFactory):  # noqa: ANN201
    spec = load_job(
        _job(tmp_path_factory.mktemp("roulette"), "roulette_box.xml", resolution=[12, 12])
    )
    loaded = load_job_scene(spec)
    (objective,) = build_objectives(loaded.mi, spec.objectives, (12, 12), False)
    return loaded, objective


def test_under_russian_roulette_one_seed_is_no_reference(roulette) -> None:  # noqa: ANN001
    """rr_depth 1 < max_depth 12: at one seed the difference of a reflectance misses reverse
    mode by percent (paths that end on one side survive on the other), so check compares it
    over seeds, and keeps one seed for the light's radiance, which ends no path."""
    loaded, objective = roulette
    white = next(r for r in loaded.selected if r.key == "white.reflectance.value")
    gaps = [
        check_parameter(loaded, objective, white, spp=16, seeds=[s]).relative_error
        for s in range(4)
    ]
    assert max(gaps) > 10 * SAME_SEED_TOLERANCE  # what made check cry wolf
    plan = plan_audit(loaded, None, full=False)
    assert [r.key for r in plan.seeds] == ["white.reflectance.value"]
    assert [r.key for r in plan.one_seed] == ["bulb.emitter.radiance.value"]
    (note,) = plan.notes
    assert "Russian roulette (rr_depth 1 < max_depth 12)" in note
    checks = audit(loaded, objective, plan, spp=16, seeds=range(6), progress=Progress(quiet=True))
    verdicts = {c.key: c.verdict for c in checks}
    assert verdicts == {"bulb.emitter.radiance.value": "agrees",
                        "white.reflectance.value": "agrees"}  # fmt: skip


def test_check_leaves_near_specular_kinds_to_the_repair(near_loaded: LoadedScene) -> None:
    """The default plan does not measure what run repairs: it picks another parameter of the
    kind (the frosted ball's η, roughness 0.3); named, the near-specular one is measured."""
    plan = plan_audit(near_loaded, None, full=False)
    measured = {r.key for r in plan.one_seed + plan.seeds}
    assert FROSTED in measured and ETA not in measured and ALPHA0 not in measured
    assert [r.key for r in plan_audit(near_loaded, [ETA], full=False).seeds] == [ETA]


def _record(plugin: str = "roughdielectric", ptype: str = "eta") -> ParamRecord:
    return ParamRecord("k", ptype, (), (1,), False, plugin, (), "verified", "")


def test_heavy_tailed_seeds_are_noisy_not_a_disagreement() -> None:
    """Reverse mode of a near-specular η per seed (−100 to +12 where differences give +0.03):
    the gap is many standard errors, but the error is no measure of it."""
    adjoints = np.array([0.8, -1.2, 0.3, 0.5, -0.6, 0.2, -99.7, 1.1])
    check = judge(_record(), adjoints, np.full(8, 0.03) + np.linspace(-1e-3, 1e-3, 8))
    assert check.verdict == "noisy" and "differences over 8 seeds: heavy-tailed" in check.reason


def test_heavy_tailed_values_whose_seeds_pair_up_are_judged_by_their_gaps() -> None:
    """A light reached by rare paths: its per-seed values are heavy-tailed, but at a shared
    seed the difference carries the same paths, so the gaps are tiny and the check agrees."""
    values = np.array([0.01, 0.012, 0.011, 0.009, 0.6, 0.01, 0.013, 0.008])
    gaps = np.array([1, -2, 1, 0, 40, -1, 2, 1]) * 1e-7  # float rounding, one far seed
    check = judge(_record("area", "radiance"), values + gaps, values)
    assert check.verdict == "agrees", check


def test_inconclusive_says_why() -> None:
    rng = np.random.default_rng(3)
    noise, other = rng.standard_normal(6), rng.standard_normal(6)
    differences = 0.01 + 0.005 * other
    wide = judge(_record(), 0.01 + 0.01 * noise, differences)
    assert wide.verdict == "inconclusive" and "too noisy" in wide.reason
    tight = judge(_record(), differences + 1e-5 * noise, differences)
    assert tight.verdict == "agrees" and tight.reason == ""


def test_reverse_mode_far_wider_than_the_differences_is_noisy() -> None:
    """Per-seed adjoints −70 to +50 where the differences at the same seeds stay within ±0.2
    (measured on a rough dielectric with roughness texels at 0): not "inconclusive, raise
    --spp", but noisy: reverse mode's derivative is carried by rare paths."""
    rng = np.random.default_rng(4)
    differences = 0.03 + 0.1 * rng.standard_normal(6)
    check = judge(_record(), 30.0 * rng.standard_normal(6), differences)
    assert check.verdict == "noisy" and "wider over 6 seeds" in check.reason


def test_check_on_the_near_specular_eta_says_so_and_passes(tmp_path: Path) -> None:
    """Named, the heavy-tailed η is measured: never "agrees" or a contradiction of the table,
    but noisy or inconclusive with its reason, and check exits 0."""
    job = _job(tmp_path, "near_specular.xml")  # no buffer: the duality column is skipped
    result = sensaov("check", str(job), "--key", ETA, "--seeds", "6", "--json", "-q")
    assert result.returncode == 0, result.stderr
    (row,) = json.loads(result.stdout)["finite_differences"]
    assert row["verdict"] in ("noisy", "inconclusive") and row["reason"], row
