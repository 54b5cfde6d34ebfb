"""Trust labels: the table agrees with docs/verification.md, and the run-time self-checks catch
what they claim to (no gradient, zero components, broken emission identities)."""

from __future__ import annotations

import re
from collections.abc import Callable
from pathlib import Path
from types import ModuleType
from typing import Any

import numpy as np
import pytest
import yaml

from sensaov_cli.buffer.model import ParamRecord
from sensaov_cli.job.load import load_job
from sensaov_cli.progress import Progress
from sensaov_cli.render import adjoint
from sensaov_cli.render.loading import load_job_scene
from sensaov_cli.render.objectives import build_objectives
from sensaov_cli.render.verify.fdcheck import check_parameter
from sensaov_cli.render.verify.selfcheck import (
    MIN_TOLERANCE,
    PAIR_TOLERANCE,
    EmitterTerms,
    LinearObjective,
    check_gradients,
    tolerance,
)
from sensaov_cli.render.verify.trust import (
    COMPOSITE_TABLE,
    COMPOSITES,
    DELTA_LOBE_REASON,
    NO_FLOW_REASON,
    PRINCIPLED_LOBE_REASON,
    REPAIRS,
    SPOT_TEXTURE_REASON,
    TABLE,
)

DOC = Path(__file__).resolve().parents[1] / "docs" / "verification.md"
WORST_FIRST = ("no_gradient", "biased", "suspect", "unverified", "verified")

# --- the table and its document -------------------------------------------------------------


def _markdown_rows(text: str, header: str) -> list[list[str]]:
    """The cells of the rows of the markdown table whose header line is ``header``."""
    lines = text.splitlines()
    start = lines.index(header) + 2  # skip the |---| line
    rows = []
    for line in lines[start:]:
        if not line.startswith("|"):
            break
        rows.append([cell.strip() for cell in line.strip("|").split("|")])
    return rows


def _measured() -> str:
    doc = DOC.read_text()
    return doc.split("<!-- trust_table.py begins -->")[1].split("<!-- trust_table.py ends -->")[0]


def test_trust_table_is_the_documented_one() -> None:
    labels = _markdown_rows(_measured(), "| plugin | type | label |")
    documented = {(plugin, ptype): label for plugin, ptype, label in labels}
    assert documented == {kind: entry.trust for kind, entry in TABLE.items()}


def test_each_documented_label_is_the_weakest_of_its_measurements() -> None:
    measured = _measured().split("Conditions the run-time self-checks catch")[0]
    header = next(
        line for line in measured.splitlines() if line.startswith("| plugin | type | case")
    )
    weakest: dict[tuple[str, str], str] = {}
    for cells in _markdown_rows(measured, header):
        kind, label = (cells[0], cells[1]), cells[-1]
        weakest[kind] = min(weakest.get(kind, "verified"), label, key=WORST_FIRST.index)
    labels = _markdown_rows(_measured(), "| plugin | type | label |")
    assert weakest == {(plugin, ptype): label for plugin, ptype, label in labels}


def test_only_verified_kinds_go_without_a_note() -> None:
    for kind, entry in [*TABLE.items(), *COMPOSITE_TABLE.items()]:
        assert (entry.note == "") == (entry.trust == "verified"), kind


def test_composite_labels_are_the_documented_ones() -> None:
    labels = _markdown_rows(_measured(), "| composite | role | children | label |")
    documented = {(c, role, children): label for c, role, children, label in labels}
    assert documented == {context: entry.trust for context, entry in COMPOSITE_TABLE.items()}


def test_each_composite_label_is_the_weakest_of_its_evidence() -> None:
    """A row counts for its composites where it is a composite's own parameter or its own kind
    is verified (a row of a kind known biased says nothing of the composite)."""
    measured = _measured().split("Composites: each parameter")[1]
    header = next(line for line in measured.splitlines() if line.startswith("| composites |"))
    kinds = {kind: entry.trust for kind, entry in TABLE.items()}
    weakest: dict[tuple[str, ...], str] = {}
    for cells in _markdown_rows(measured, header):
        contexts, plugin, ptype, label = cells[0], cells[1], cells[2], cells[-1]
        if kinds.get((plugin, ptype)) != "verified" and plugin not in COMPOSITES:
            continue
        for context in contexts.split(", "):
            name, role, children = context.replace("(", "").replace(")", "").split()
            key = (name, role, children)
            weakest[key] = min(weakest.get(key, "verified"), label, key=WORST_FIRST.index)
    labels = _markdown_rows(_measured(), "| composite | role | children | label |")
    assert weakest == {(c, role, children): label for c, role, children, label in labels}


def _repairs_measured() -> str:
    doc = DOC.read_text()
    return doc.split("<!-- repair_table.py begins -->")[1].split("<!-- repair_table.py ends -->")[0]


def test_repair_labels_are_the_documented_ones() -> None:
    labels = _markdown_rows(_repairs_measured(), "| plugin | type | label |")
    documented = {(plugin, ptype): label for plugin, ptype, label in labels}
    assert documented == {kind: entry.trust for kind, entry in REPAIRS.items()}


def test_a_repair_is_verified_only_where_every_row_is_within_3_standard_errors() -> None:
    measured = _repairs_measured()
    header = next(
        line for line in measured.splitlines() if line.startswith("| plugin | type | par")
    )
    rows = _markdown_rows(measured, header)
    assert rows, "docs/verification.md has no measured repair rows"
    earned: dict[tuple[str, str], str] = {}
    for cells in rows:
        z_crn, z_independent = cells[7], cells[9]
        assert z_crn, f"{cells[2]}: no common-random-numbers reference"
        within = all(abs(float(z)) <= 3 for z in (z_crn, z_independent) if z)
        kind = (cells[0], cells[1])
        still = within and earned.get(kind, "verified") == "verified"
        earned[kind] = "verified" if still else "unverified"
    assert earned == {kind: entry.trust for kind, entry in REPAIRS.items()}
    for kind, entry in REPAIRS.items():  # an unverified repair says why
        assert (entry.note == "") == (entry.trust == "verified"), kind


# --- the self-checks on plain arrays --------------------------------------------------------


def record(key: str, ptype: str = "radiance", trust: str = "verified") -> ParamRecord:
    return ParamRecord(key, ptype, ("o",), (3,), False, "x", (), trust, "")


def run_check(
    records: list[ParamRecord],
    values: dict[str, Any],
    grads: dict[str, Any],
    emitters: tuple[EmitterTerms, ...] = (),
    m: float = 1.0,
) -> dict[str, ParamRecord]:
    arrays = {k: np.asarray(v, np.float32) for k, v in values.items()}
    gradients = {"m": {k: np.asarray(v, np.float32) for k, v in grads.items()}}
    linear = {"m": LinearObjective(m, effective_pixels=1e6)}
    done = check_gradients(
        records, arrays, gradients, linear, emitters, 64, {k: "prb" for k in values}
    )
    return {r.key: r for r in done.params}


def test_a_gradient_zero_for_every_objective_is_no_gradient() -> None:
    done = run_check([record("a"), record("b")], {"a": [1, 1, 1], "b": [1, 1, 1]},
                     {"a": [0, 0, 0], "b": [0, 1e-9, 0]})  # fmt: skip
    assert (done["a"].trust, done["a"].note) == ("no_gradient", NO_FLOW_REASON)
    assert done["b"].trust == "verified"


@pytest.mark.parametrize(
    ("plugin", "ptype", "key", "integrator", "reason"),
    [
        ("conductor", "eta", "m.bsdf.eta.value", "prb", DELTA_LOBE_REASON),
        ("conductor", "eta", "m.bsdf.eta.value", "path", NO_FLOW_REASON),
        ("spot", "radiance", "lamp.texture.value", "prb", SPOT_TEXTURE_REASON),
        ("principled", "sheen", "p.bsdf.sheen.value", "prb", PRINCIPLED_LOBE_REASON),
        ("principled", "reflectance", "p.bsdf.base_color.value", "prb", NO_FLOW_REASON),
    ],
)
def test_no_gradient_names_the_known_reason(
    plugin: str, ptype: str, key: str, integrator: str, reason: str
) -> None:
    zero = ParamRecord(key, ptype, ("o",), (1,), False, plugin, (), "verified", "")
    values, grads = {key: np.ones(1, np.float32)}, {"m": {key: np.zeros(1, np.float32)}}
    done = check_gradients([zero], values, grads, {}, (), 16, {key: integrator})
    assert (done.params[0].trust, done.params[0].note) == ("no_gradient", reason)


def test_zero_components_make_a_verified_reflectance_unverified() -> None:
    records = [record("r", "reflectance"), record("q", "reflectance", "biased"), record("e")]
    values = {"r": [0, 0.5, 0.3], "q": [0, 0.5, 0.3], "e": [0, 1, 1]}
    done = run_check(records, values, {k: [1, 1, 1] for k in values})
    assert done["r"].trust == "unverified" and "components [0] of 3" in done["r"].note
    assert done["q"].trust == "biased"  # a weaker label stays
    assert done["e"].trust == "verified"  # radiance: a zero does not end a path


def test_all_emitters_against_m() -> None:
    records = [record("lamp"), record("sun")]
    values = {"lamp": [1, 1, 1], "sun": [2, 2, 2]}
    grads = {"lamp": [0.1, 0.1, 0.1], "sun": [0.05, 0.05, 0.05]}  # Σθ·∂M/∂θ = 0.6
    emitters = (EmitterTerms("lamp", ("lamp",), None), EmitterTerms("sun", ("sun",), None))
    assert run_check(records, values, grads, emitters, m=0.6)["sun"].trust == "verified"
    broken = run_check(records, values, grads, emitters, m=0.9)
    assert broken["lamp"].trust == broken["sun"].trust == "suspect"
    assert "0.6 vs 0.9 (-33.3%, tolerance 1.0%)" in broken["lamp"].note
    one_missing = (emitters[0], EmitterTerms("sun", None, None))
    assert run_check(records, values, grads, one_missing, m=0.9)["lamp"].trust == "verified"


def test_an_emitters_radiance_against_its_scale() -> None:
    records = [record("sky.data"), record("sky.scale")]
    values = {"sky.data": [1, 2, 3], "sky.scale": [1.5, 0, 0]}
    emitters = (EmitterTerms("sky", ("sky.data",), ("sky.scale",)),)
    good = {"sky.data": [0.1, 0.1, 0.1], "sky.scale": [0.4, 0, 0]}  # 0.6 both
    assert run_check(records, values, good, emitters, m=0.6)["sky.data"].trust == "verified"
    bad = {**good, "sky.data": [0.1, 0.1, 0.1 * (1 + 3 * PAIR_TOLERANCE)]}
    done = run_check(records, values, bad, emitters, m=0.6)
    assert (
        done["sky.scale"].trust == "suspect"
        and "radiance vs of its scale" in done["sky.scale"].note
    )


def test_tolerance_shrinks_with_samples_down_to_its_floor() -> None:
    assert tolerance(64, 128 * 128) == pytest.approx(40 / 1024)
    assert tolerance(4096, 1024 * 1024) == MIN_TOLERANCE


# --- the self-checks and workarounds in a run ---------------------------------------------

SCENE = """<scene version="3.0.0">
  <integrator type="path"><integer name="max_depth" value="4"/></integrator>
  <sensor type="perspective" id="sensor"><float name="fov" value="45"/>
    <transform name="to_world">
      <lookat origin="0, 0.5, 4" target="0, 0, 0" up="0, 1, 0"/></transform>
    <film type="hdrfilm"><integer name="width" value="16"/><integer name="height" value="16"/>
      <rfilter type="box"/></film></sensor>
  <shape type="sphere" id="mirror"><point name="center" x="-0.6" y="0" z="0"/>
    <float name="radius" value="0.5"/>
    <bsdf type="conductor">
      <rgb name="eta" value="0.2, 0.9, 1.1"/><rgb name="k" value="3.9, 2.4, 2.2"/></bsdf></shape>
  <shape type="sphere" id="ball"><point name="center" x="0.6" y="0" z="0"/>
    <float name="radius" value="0.5"/>
    <bsdf type="diffuse"><rgb name="reflectance" value="0, 0.5, 0.3"/></bsdf></shape>
  <shape type="rectangle" id="floor">
    <transform name="to_world">
      <scale value="3"/><rotate x="1" angle="-90"/><translate y="-0.5"/></transform>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.6, 0.5, 0.4"/></bsdf></shape>
  <emitter type="envmap" id="sky"><string name="filename" value="sky.exr"/>
    <float name="scale" value="1.5"/></emitter>
</scene>"""


@pytest.fixture(scope="module")
def mixed_job(mi: ModuleType, tmp_path_factory: pytest.TempPathFactory) -> Path:
    folder = tmp_path_factory.mktemp("trust")
    sky = 0.3 + np.random.default_rng(0).random((8, 16, 3), dtype=np.float32)
    sky[1:3, 3:5] = 10.0
    mi.Bitmap(sky).write(str(folder / "sky.exr"))
    (folder / "scene.xml").write_text(SCENE)
    job = {
        "version": 1, "scene": "scene.xml", "variant": "llvm_ad_rgb",
        "render": {"spp": 16, "max_depth": 4, "seed": 0, "resolution": [16, 16]},
        "parameters": {"include": ["mirror.*", "ball.*", "sky.*"]},
        "objectives": [{"name": "mean_luma", "type": "mean_luminance"}],
        "output": "out",
    }  # fmt: skip
    (folder / "job.yaml").write_text(yaml.safe_dump(job))
    return folder / "job.yaml"


def run(job_path: Path) -> tuple[Any, adjoint.AdjointResult]:
    job = load_job(job_path)
    loaded = load_job_scene(job)
    objectives = build_objectives(loaded.mi, job.objectives, (16, 16), False)
    result = adjoint.run_adjoint(
        loaded, objectives, spp=16, seed=0, deterministic=True, progress=Progress(quiet=True)
    )
    return loaded, result


@pytest.fixture(scope="module")
def mixed(mixed_job: Path) -> tuple[Any, adjoint.AdjointResult]:
    return run(mixed_job)


def labels(result: adjoint.AdjointResult) -> dict[str, ParamRecord]:
    return {r.key: r for r in result.params}


def test_delta_lobes_take_path_and_get_a_gradient(mixed) -> None:  # noqa: ANN001
    _, result = mixed
    mirror = [k for k in labels(result) if k.startswith("mirror.")]
    assert sorted(result.provenance["gradient_integrators"]["path"]) == sorted(mirror)
    for key in mirror:
        assert np.any(result.grads["mean_luma"][key] != 0), key
        assert labels(result)[key].trust == "verified", labels(result)[key]


def test_without_the_path_pass_delta_lobes_get_no_gradient(mixed_job: Path) -> None:
    job = load_job(mixed_job)
    loaded = load_job_scene(job)
    loaded.routes = dict.fromkeys(loaded.routes, "prb")
    objectives = build_objectives(loaded.mi, job.objectives, (16, 16), False)
    result = adjoint.run_adjoint(
        loaded, objectives, spp=16, seed=0, deterministic=True, progress=Progress(quiet=True)
    )
    eta = labels(result)["mirror.bsdf.eta.value"]
    assert (eta.trust, eta.note) == ("no_gradient", DELTA_LOBE_REASON)
    assert result.provenance["self_checks"]["no_gradient"] == sorted(
        k for k in labels(result) if k.startswith("mirror.")
    )


def test_envmap_data_gets_a_gradient_and_its_halo_none(mixed) -> None:  # noqa: ANN001
    _, result = mixed
    grad = result.grads["mean_luma"]["sky.data"]
    assert grad.shape == (8, 18, 3)  # Mitsuba's layout: a halo column on each side
    assert np.count_nonzero(grad[:, 1:-1]) > 0
    assert not np.any(grad[:, [0, -1]])


def test_envmap_data_agrees_with_finite_differences(mixed_job: Path) -> None:
    job = load_job(mixed_job)
    loaded = load_job_scene(job)
    (objective,) = build_objectives(loaded.mi, job.objectives, (16, 16), False)
    info = next(r for r in loaded.selected if r.key == "sky.data")
    result = check_parameter(loaded, objective, info, spp=16, seeds=[1, 2, 3])
    assert result.adjoint != 0 and result.verdict == "agrees", result


def test_emission_identities_hold_and_are_recorded(mixed) -> None:  # noqa: ANN001
    _, result = mixed
    identities = result.provenance["self_checks"]["emission_identities"]
    assert [i["passed"] for i in identities] == [True, True]
    assert identities[0]["keys"] == ["sky.data", "sky.scale"]
    assert labels(result)["sky.data"].trust == labels(result)["sky.scale"].trust == "verified"


def test_a_zero_reflectance_component_is_unverified(mixed) -> None:  # noqa: ANN001
    _, result = mixed
    ball = labels(result)["ball.bsdf.reflectance.value"]
    assert ball.trust == "unverified" and "components [0] of 3" in ball.note
    assert result.provenance["self_checks"]["zero_components"] == {"ball.bsdf.reflectance.value": 1}


def test_a_broken_identity_is_suspect(mixed_job: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Scale the envmap data's gradient down after the pass: both identities must object (at
    16x16 and 16 spp the tolerance against M is 62 %: the scale factor must beat it)."""
    original: Callable[..., dict[str, np.ndarray]] = adjoint.backward_pass

    def halved(*args: Any) -> dict[str, np.ndarray]:
        grads = original(*args)
        return {k: g * 0.2 if k == "sky.data" else g for k, g in grads.items()}

    monkeypatch.setattr(adjoint, "backward_pass", halved)
    _, result = run(mixed_job)
    data, scale = labels(result)["sky.data"], labels(result)["sky.scale"]
    assert data.trust == scale.trust == "suspect"
    figures = r"for 'mean_luma': [-+.\de]+ vs [-+.\de]+ \(-80\.0%, tolerance 0\.1%\)"
    assert re.search("radiance vs of its scale " + figures, data.note)
    assert "over every emitter's radiance vs M" in data.note
    assert labels(result)["ball.bsdf.reflectance.value"].trust == "unverified"  # not involved


def test_labels_agree_with_the_table(mixed) -> None:  # noqa: ANN001
    """What a run labels from the table is the table's label; self-checks only lower it."""
    loaded, result = mixed
    for before, after in zip(loaded.selected, result.params, strict=True):
        entry = TABLE.get((before.plugin, before.type))
        assert before.trust == (entry.trust if entry else "unverified"), before
        assert WORST_FIRST.index(after.trust) <= WORST_FIRST.index(before.trust), after
