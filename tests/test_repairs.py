"""Repairs (render/verify/repair.py): known-wrong gradients computed again by finite differences.

The acceptance test of repairs runs tests/scenes/repair_mix.xml (roughplastic α and η, smooth
plastic, a reflectance component exactly 0, the light's own reflectance 0, a blend over a smooth
conductor) and compares every repaired gradient with central differences computed here, apart
from the repair: other seeds, four times the samples, twice the step. They must agree within 3
combined standard errors, while the reverse-mode gradients the repairs replaced do not (so the
comparison can fail). docs/verification.md ("Repairs") has the full table, against
independent-seed differences too (scripts/repair_table.py).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from sensaov_cli.buffer.model import ParamRecord, SensitivityBuffer
from sensaov_cli.buffer.npz import buffer_writer, read_buffer
from sensaov_cli.job.load import load_job
from sensaov_cli.job.spec import RepairSpec, UntilSpec
from sensaov_cli.outputs.tables import summary_text
from sensaov_cli.pipeline.run import run_job
from sensaov_cli.progress import Progress
from sensaov_cli.render.adjoint import render_primal
from sensaov_cli.render.loading import assign, load_job_scene
from sensaov_cli.render.objectives import build_objectives, value_and_adjoint
from sensaov_cli.render.verify.repair import TEXTURE_REASON, plan, sign_resolved
from tests.conftest import use_scene

SCENE = Path(__file__).parent / "scenes" / "repair_mix.xml"
OBJECTIVES = [
    {"name": "mean_luma", "type": "mean_luminance"},
    {"name": "left", "type": "region_luminance", "region": [0.0, 0.2, 0.5, 0.9]},
]
REPAIRED = {  # key -> its kind's reason to be repaired
    "varnish_ball.bsdf.alpha": "biased",
    "varnish_ball.bsdf.eta": "biased",
    "plastic_ball.bsdf.diffuse_reflectance.value": "biased",
    "blend_ball.bsdf.weight.value": "a blendbsdf with a smooth (delta) child",  # trust.py
    "floor.bsdf.reflectance.value": "value exactly 0",
    "light.bsdf.reflectance.value": "no gradient",
}
REFERENCE_SEEDS, REFERENCE_SPP = range(1000, 1008), 64
# Reverse mode is wrong here by many standard errors (measured: the blend weight -0.040 against
# +0.004, alpha 5x too small, eta of the wrong sign, the zero components 0 or 6 % low).
FAR_FROM_REVERSE = ["varnish_ball.bsdf.alpha", "varnish_ball.bsdf.eta",
                    "blend_ball.bsdf.weight.value", "light.bsdf.reflectance.value"]  # fmt: skip


def _job(job_writer: Callable[..., Path], name: str, **overrides: object) -> Path:
    # one batch: repairs are the subject here, and with the default batches each batch takes a
    # seed of its own (test_batches_give_repaired_gradients_their_statistics covers batches)
    render = {"spp": 16, "max_depth": 5, "seed": 0, "resolution": [32, 32], "batches": 1}
    job = job_writer(name, render=render, objectives=OBJECTIVES, **overrides)
    use_scene(job, SCENE)
    return job


@pytest.fixture(scope="module")
def repaired(job_writer: Callable[..., Path]) -> SensitivityBuffer:
    job = _job(job_writer, "repairs", repair={"budget": 50, "seeds": 8})
    return run_job(load_job(job), allow_python=False, progress=Progress(quiet=True))


def _reference(job: Path, key: str, step: float, one_sided: tuple[tuple[int, int], ...]) -> dict:
    """objective -> (mean, standard error) per component of central differences at other
    seeds, spp and step than the repair's (forward three-point ones at components 0)."""
    spec = load_job(job)
    loaded = load_job_scene(spec)
    width, height = loaded.resolution
    objectives = build_objectives(loaded.mi, spec.objectives, (height, width), False)

    def measure(seed: int) -> np.ndarray:
        image = render_primal(loaded, REFERENCE_SPP, seed)
        return np.array([value_and_adjoint(loaded.mi, o, image)[0] for o in objectives])

    theta = np.array(loaded.params[key], dtype=np.float32).ravel()
    shape = next(r.shape for r in loaded.selected if r.key == key)
    rows = np.zeros((len(REFERENCE_SEEDS), theta.size, len(objectives)))
    away = dict(one_sided)
    for c in range(theta.size):
        h = step * max(1.0, abs(float(theta[c]))) * away.get(c, 1)
        sides = []
        for multiple in (0, 1, 2) if c in away else (1, -1):
            moved = theta.copy()
            moved[c] += multiple * h
            assign(loaded, key, moved.reshape(shape))
            sides.append(np.array([measure(seed) for seed in REFERENCE_SEEDS]))
        assign(loaded, key, theta.reshape(shape))
        if c in away:
            rows[:, c] = (-3 * sides[0] + 4 * sides[1] - sides[2]) / (2 * h)
        else:
            rows[:, c] = (sides[0] - sides[1]) / (2 * h)
    count = math.sqrt(len(REFERENCE_SEEDS))
    return {
        o.spec.name: (rows[:, :, j].mean(axis=0), rows[:, :, j].std(axis=0, ddof=1) / count)
        for j, o in enumerate(objectives)
    }


@pytest.fixture(scope="module")
def references(repaired: SensitivityBuffer, job_writer: Callable[..., Path]) -> dict:
    job = _job(job_writer, "references")
    return {
        key: _reference(job, key, 2 * r.step, r.one_sided) for key, r in repaired.repairs.items()
    }


def test_every_known_wrong_gradient_is_repaired_and_labelled(repaired: SensitivityBuffer) -> None:
    assert sorted(repaired.repairs) == sorted(REPAIRED)
    for key, why in REPAIRED.items():
        record = repaired.param(key)
        assert record.estimator == "finite-difference", record
        assert "repaired by finite differences" in record.note
        # the trust table's repair rows: a diffuse reflectance's repair is measured unverified
        diffuse = key in ("floor.bsdf.reflectance.value", "light.bsdf.reflectance.value")
        assert record.trust == ("unverified" if diffuse else "verified"), record
        assert ("measured 3.1 standard errors" in record.note) == diffuse, record
        assert why in repaired.repairs[key].reason, (key, repaired.repairs[key].reason)
    assert repaired.repairs["floor.bsdf.reflectance.value"].one_sided == ((1, 1),)
    assert repaired.param("back.bsdf.reflectance.value").estimator == "reverse"
    assert repaired.param("blend_ball.bsdf.bsdf_1.eta.value").estimator == "reverse-path"
    assert repaired.provenance["repairs"]["not_repaired"] == {}


def test_repaired_gradients_agree_with_independent_central_differences(
    repaired: SensitivityBuffer, references: dict
) -> None:
    """The repairs' acceptance: within 3 combined standard errors, every component and objective;
    the reverse-mode gradients that were replaced are far outside that."""
    far = []
    for key, repair in repaired.repairs.items():
        for name, (ref, ref_se) in references[key].items():
            stored = repaired.grad(name, key).ravel()
            combined = np.sqrt(repair.stderr(name) ** 2 + ref_se**2)
            assert np.all(np.abs(stored - ref) <= 3 * combined), (key, name, stored, ref, combined)
            np.testing.assert_allclose(stored, repair.mean(name), rtol=1e-6, atol=1e-12)
            far.append((key, bool(np.any(np.abs(repair.reverse[name] - ref) > 3 * combined))))
    for key in FAR_FROM_REVERSE:
        assert (key, True) in far, key


def test_repairs_survive_the_file(repaired: SensitivityBuffer, tmp_path: Path) -> None:
    path = tmp_path / "buffer.npz"
    buffer_writer(repaired)(path)
    again = read_buffer(path)
    for key, repair in repaired.repairs.items():
        back = again.repairs[key]
        assert (back.seeds, back.spp, back.step, back.one_sided) == (
            repair.seeds, repair.spp, repair.step, repair.one_sided,
        )  # fmt: skip
        for name in repair.estimates:
            np.testing.assert_array_equal(back.estimates[name], repair.estimates[name])
            np.testing.assert_array_equal(back.reverse[name], repair.reverse[name])
        assert again.param(key).estimator == "finite-difference"
        np.testing.assert_array_equal(
            again.reverse_grad("mean_luma", key).ravel(),
            repair.reverse["mean_luma"].astype(np.float32),
        )


def test_summary_shows_the_repairs_with_their_own_errors(repaired: SensitivityBuffer) -> None:
    text = summary_text(repaired, top=20)
    assert "repairs: 6 parameters known wrong in reverse mode, by central differences" in text
    assert "finite-difference = repaired (reverse mode is known wrong there)" in text
    assert "varnish_ball.bsdf.alpha: -" in text and " ± " in text


def test_over_budget_stays_labelled_and_named(job_writer: Callable[..., Path]) -> None:
    job = load_job(_job(job_writer, "small_budget", repair={"budget": 0.15}))
    buffer = run_job(job, allow_python=False, progress=Progress(quiet=True))
    left = buffer.provenance["repairs"]["not_repaired"]
    assert left and set(left) | set(buffer.repairs) == set(REPAIRED)
    for key, why in left.items():
        record = buffer.param(key)
        assert record.estimator != "finite-difference" and record.trust != "verified"
        assert why.startswith("over the repair budget") and f"not repaired: {why}" in record.note
    assert "not repaired, still labelled: " in summary_text(buffer)


def test_no_budget_repairs_nothing(job_writer: Callable[..., Path]) -> None:
    job = load_job(_job(job_writer, "no_budget", repair={"budget": 0}))
    buffer = run_job(job, allow_python=False, progress=Progress(quiet=True))
    assert buffer.repairs == {} and set(buffer.provenance["repairs"]["not_repaired"]) == set(
        REPAIRED
    )
    weight = buffer.param("blend_ball.bsdf.weight.value")  # its composite's row: biased
    assert weight.trust == "biased" and "a blendbsdf with a smooth (delta) child" in weight.note


def _record(key: str, shape: tuple[int, ...], texture: bool = False) -> ParamRecord:
    return ParamRecord(key, "roughness", ("o",), shape, texture, "roughplastic", (), "biased", "")


def test_plan_leaves_textures_and_spends_the_budget_on_what_matters_most() -> None:
    records = [_record("tex", (8, 8, 1), texture=True), _record("big", (1,)),
               _record("small", (1,))]  # fmt: skip
    values = {r.key: np.full(r.shape, 0.3, np.float32) for r in records}
    grads = {"m": {"tex": np.ones((8, 8, 1)), "big": np.array([-2.0]), "small": np.array([0.1])}}
    reasons = {r.key: "biased" for r in records}

    def planned(budget: float):  # noqa: ANN202
        settings = RepairSpec(budget=budget, seeds=4)
        return plan(reasons, records, values, grads, settings, pixels=128 * 128, spp=16,
                    passes=1, seeds=[1, 2, 3, 4])  # fmt: skip

    enough = planned(10)
    assert [t.key for t in enough.targets] == ["big", "small"] and enough.spp == 16
    assert enough.skipped == {"tex": TEXTURE_REASON}
    assert enough.samples <= enough.budget_samples
    tight = planned(0.45)  # one parameter fits at 1 spp, not two
    assert [t.key for t in tight.targets] == ["big"] and tight.spp >= 1
    assert tight.skipped["small"].startswith("over the repair budget")
    assert planned(0).targets == ()


def test_batches_give_repaired_gradients_their_statistics(job_writer: Callable[..., Path]) -> None:
    render = {"spp": 16, "max_depth": 5, "seed": 0, "resolution": [24, 24], "batches": 2}
    job = _job(job_writer, "repair_batches", repair={"budget": 20, "seeds": 4})
    spec = load_job(job)
    spec = dataclasses.replace(spec, render=dataclasses.replace(spec.render, **render))
    buffer = run_job(spec, allow_python=False, progress=Progress(quiet=True))
    assert buffer.statistics is not None and buffer.repairs
    key, repair = next(iter(buffer.repairs.items()))
    batch_means = [repair.estimates["mean_luma"][b::2].mean(axis=0) for b in range(2)]
    spread = np.std(batch_means, axis=0, ddof=1) / math.sqrt(2)
    np.testing.assert_allclose(
        buffer.statistics.stderr["mean_luma"][key].ravel(), spread, rtol=1e-4
    )
    np.testing.assert_allclose(
        buffer.grad("mean_luma", key).ravel(), np.mean(batch_means, axis=0), rtol=1e-5
    )


def test_repairs_add_seeds_while_their_sign_is_unresolved(job_writer: Callable[..., Path]) -> None:
    """Under render.until (here at its first spp: no batch is added), the repairs add rounds
    of seeds, one per batch, within repair.budget, while a repaired sign is unresolved; what
    stays unresolved is named. Without until nothing is added (the repaired fixture)."""
    render = {"spp": 8, "max_depth": 5, "seed": 0, "resolution": [16, 16], "batches": "auto"}
    job = _job(job_writer, "repair_until", repair={"budget": 50, "seeds": 4})
    spec = load_job(job)
    until = {"until": UntilSpec(resolved=1, max_spp=8)}
    spec = dataclasses.replace(spec, render=dataclasses.replace(spec.render, **render, **until))
    buffer = run_job(spec, allow_python=False, progress=Progress(quiet=True))
    figures = buffer.provenance["repairs"]
    batches = len(buffer.provenance["batches"])
    assert batches == 8 and figures["samples"] <= figures["budget_samples"]
    for key, fixed in buffer.repairs.items():
        added = figures["added_seeds"].get(key, 0)
        assert len(fixed.seeds) == len(figures["seeds"]) + added == len(set(fixed.seeds))
        assert added % batches == 0
        assert (key in figures["unresolved"]) == (not sign_resolved(fixed))
        if added:  # a round was added only while the sign was unresolved: the last one was
            before = dataclasses.replace(
                fixed,
                spp=fixed.spp[:-batches],
                seeds=fixed.seeds[:-batches],
                estimates={n: e[:-batches] for n, e in fixed.estimates.items()},
            )
            assert not sign_resolved(before)
    assert figures["added_seeds"], "a budget of 50 leaves room for rounds: some must be added"


def test_without_until_repairs_keep_their_planned_seeds(repaired: SensitivityBuffer) -> None:
    figures = repaired.provenance["repairs"]
    assert figures["added_seeds"] == {}
    assert all(len(r.seeds) == len(figures["seeds"]) for r in repaired.repairs.values())
