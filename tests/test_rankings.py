"""`sensaov rank --by`: every cut agrees with a direct computation from the raw ``.npz``."""

from __future__ import annotations

import csv
import io
import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from click.testing import CliRunner

from sensaov_cli import interrupts
from sensaov_cli.buffer.model import ObjectiveRecord, ParamRecord, SensitivityBuffer
from sensaov_cli.buffer.npz import read_buffer
from sensaov_cli.cli import main
from sensaov_cli.errors import EXIT_BAD_INPUT
from sensaov_cli.outputs.layered_exr import metadata, rank_channels, seen_names
from sensaov_cli.outputs.tables import COLUMNS, summary_text
from tests.bad_buffers import write_buffer

from .conftest import sensaov

OBJECTIVES = ("brightness", "centre")


def record(
    key: str, type_: str, owners: tuple[str, ...], shape: tuple[int, ...], trust: str = "verified"
) -> ParamRecord:
    note = "" if trust == "verified" else "a reason"
    return ParamRecord(key, type_, owners, shape, len(shape) == 3, "diffuse", (), trust, note)


def make_buffer() -> SensitivityBuffer:
    """Shared and unshared parameters, a texture, a no-gradient one and an unverified one."""
    params = (
        record("wall.bsdf.reflectance.value", "reflectance", ("wall",), (3,)),
        record("white.reflectance.value", "reflectance", ("floor", "ceiling"), (3,)),
        record("floor.bsdf.alpha.value", "roughness", ("floor",), (1,), "biased"),
        record("lamp.emitter.radiance.value", "radiance", ("lamp",), (3,)),
        record("wall.bsdf.reflectance.data", "reflectance", ("wall",), (4, 5, 3)),
        record("glass.eta", "eta", ("ball",), (1,), "no_gradient"),
        record("exposure.scale", "scale", (), (1,)),
    )
    rng = np.random.default_rng(7)
    values = {p.key: rng.uniform(0.1, 2.0, p.shape).astype(np.float32) for p in params}
    grads = {
        name: {
            p.key: (
                np.zeros(p.shape, np.float32)
                if p.trust == "no_gradient"
                else rng.normal(0.0, 1.0 + i, p.shape).astype(np.float32)
            )
            for i, p in enumerate(params)
        }
        for name in OBJECTIVES
    }
    return SensitivityBuffer(
        provenance={"spp": 4},
        objects=("ball", "ceiling", "floor", "lamp", "wall"),
        params=params,
        objectives=tuple(
            ObjectiveRecord(n, {"type": "mean"}, 0.5, i) for i, n in enumerate(OBJECTIVES)
        ),
        values=values,
        grads=grads,
    )


@pytest.fixture(scope="module")
def buffer_path(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("rankings") / "buffer.npz"
    write_buffer(path, make_buffer())
    return path


@pytest.fixture
def runner(monkeypatch: pytest.MonkeyPatch) -> CliRunner:
    monkeypatch.setattr(interrupts, "install", lambda **_: None)
    return CliRunner()


def raw_arrays(npz: Any, header: dict, p: dict, j: int) -> tuple[np.ndarray, np.ndarray]:
    """A parameter's value and objective j's gradient, from format 4's storage."""
    where = header["storage"]["params"][p["array"]]
    if "offset" in where:
        at = slice(where["offset"], where["offset"] + int(np.prod(p["shape"])))
        return npz["values"][at], npz[f"grads_{j:03d}"][at]
    g = where["grads"][j]
    grad = np.zeros(p["shape"], np.float32) if g is None else npz[f"texgrad_{g:05d}"]
    return npz[f"texture_{where['value']:05d}"], grad


def direct(
    path: Path, objective: str, by: str, method: str, weight: str, part: str = "trusted"
) -> list[dict]:
    """The ranking from the raw archive with plain numpy, as docs/rankings.md defines it:
    object and type rows of verified parameters (``part`` "trusted"), or of the others
    ("untrusted", the left-out rows); key rows of every parameter a gradient flows to."""
    with np.load(path, allow_pickle=False) as npz:
        header = json.loads(str(npz["header"]))
        j = next(o["array"] for o in header["objectives"] if o["name"] == objective)
        params = [p for p in header["params"] if p["trust"] != "no_gradient"]
        c = {}
        for p in params:
            value, grad = raw_arrays(npz, header, p, j)  # as docs/buffer-format.md reads them
            grad, value = grad.astype(np.float64).ravel(), value.astype(np.float64).ravel()
            c[p["key"]] = grad * value if weight == "value" else grad
            c[p["key"] + "/mean"] = value.mean()
    total_sq = sum(float(c[k] @ c[k]) for k in (p["key"] for p in params))
    total_abs = sum(abs(float(c[k].sum())) for k in (p["key"] for p in params))
    if by == "key":
        groups = {p["key"]: [p["key"]] for p in params}
    else:
        chosen = [p for p in params if (p["trust"] == "verified") == (part == "trusted")]
        field = "owners" if by == "object" else "type"
        names = sorted({n for p in chosen for n in (p[field] if by == "object" else [p[field]])})
        groups = {
            n: [p["key"] for p in chosen if n in (p[field] if by == "object" else [p[field]])]
            for n in names
        }
    rows = []
    for name, keys in groups.items():
        allc = np.concatenate([c[k] for k in keys])
        score = {
            "l2": math.sqrt(allc @ allc),
            "rms": math.sqrt(allc @ allc / allc.size),
            "sum": allc.sum(),
        }[method]
        rows.append(
            {
                "name": name,
                "score": score,
                "signed": allc.sum(),
                # the share follows the score: |Σc| of Σ|Σc| under sum, Σc² of Σc² else
                "share": abs(allc.sum()) / total_abs if method == "sum" else allc @ allc / total_sq,
                "value": c[name + "/mean"] if by == "key" else None,
            }
        )
    return sorted(rows, key=lambda r: -abs(r["score"]))


@pytest.mark.parametrize("by", ["key", "object", "type"])
@pytest.mark.parametrize(("method", "weight"), [("l2", "value"), ("rms", "raw"), ("sum", "value")])
def test_rank_json_agrees_with_the_raw_arrays(
    runner: CliRunner, buffer_path: Path, by: str, method: str, weight: str
) -> None:
    args = ["rank", str(buffer_path), "--by", by, "--json", "--top", "100"]
    result = runner.invoke(main, [*args, "--aggregate", method, "--weight", weight])
    assert result.exit_code == 0, result.output
    doc = json.loads(result.output)
    assert doc["format"] == "sensaov-ranking" and doc["columns"] == list(COLUMNS)
    assert doc["format_version"] == 4
    for objective in doc["objectives"]:
        for part, rows in (("trusted", objective["rows"]), ("untrusted", objective["left_out"])):
            expected = direct(buffer_path, objective["name"], by, method, weight, part)
            if by == "key" and part == "untrusted":
                expected = []  # a key is its own row, marked: nothing is left out of it
            assert [r["name"] for r in rows] == [e["name"] for e in expected]
            for row, want in zip(rows, expected, strict=True):
                for column in ("score", "signed", "share"):
                    assert row[column] == pytest.approx(want[column], rel=1e-9, abs=1e-12)
                assert row["value"] == (
                    None if want["value"] is None else pytest.approx(want["value"])
                )
                assert row["sign"] == ("+" if row["signed"] > 0 else "-")
                assert row["part"] == ("all" if by == "key" else part)
        assert [p["key"] for p in objective["no_gradient"]] == ["glass.eta"]
        assert "ball" not in {r["name"] for r in objective["rows"]}  # only no_gradient there


@pytest.mark.parametrize(("by", "method"), [("key", "sum"), ("key", "l2"), ("type", "l2")])
def test_shares_of_keys_and_of_types_add_up_to_one(
    runner: CliRunner, buffer_path: Path, by: str, method: str
) -> None:
    """Keys under either score, types under l2 (Σc² adds up; a type's |Σc| may be less than its
    keys' when they pull both ways)."""
    args = ["rank", str(buffer_path), "--by", by, "--json", "--top", "99"]
    result = runner.invoke(main, [*args, "--aggregate", method])
    for objective in json.loads(result.output)["objectives"]:
        rows = objective["rows"] + objective["left_out"]  # types: trusted and left out
        assert sum(r["share"] for r in rows) == pytest.approx(1.0)


def test_csv_carries_the_json_columns_and_numbers(runner: CliRunner, buffer_path: Path) -> None:
    base = ["rank", str(buffer_path), "--by", "key", "--objective", "centre", "--top", "3"]
    doc = json.loads(runner.invoke(main, [*base, "--json"]).output)
    table = list(csv.DictReader(io.StringIO(runner.invoke(main, [*base, "--csv"]).output)))
    assert list(table[0]) == ["objective", *COLUMNS]
    assert [o["name"] for o in doc["objectives"]] == ["centre"]
    for line, row in zip(table, doc["objectives"][0]["rows"], strict=True):
        assert line["name"] == row["name"] and line["trust"] == row["trust"]
        assert float(line["score"]) == row["score"] and float(line["share"]) == row["share"]
        assert float(line["value"]) == row["value"] and line["not_seen_by"] == ""


def test_text_marks_trust_and_lists_no_gradient(runner: CliRunner, buffer_path: Path) -> None:
    one = ["--objective", "brightness"]
    result = runner.invoke(main, ["rank", str(buffer_path), "--by", "object", *one])
    assert result.exit_code == 0
    floors = [line for line in result.output.splitlines() if line.rstrip().endswith("floor")]
    assert len(floors) == 2  # its trusted part, and its biased alpha left out, marked
    assert " ! " not in floors[0] and " ! " in floors[1]
    above = result.output.index(floors[1]) > result.output.index("left out of the rows above")
    assert above and "! = biased: disagrees with finite differences" in result.output
    assert "glass.eta (ball): a reason" in result.output
    mixed = runner.invoke(main, ["rank", str(buffer_path), "--by", "object", *one,
                                 "--untrusted", "include"]).output  # fmt: skip
    (floor,) = [line for line in mixed.splitlines() if line.rstrip().endswith("floor")]
    assert " ! " in floor and "left out" not in mixed


def test_default_output_is_the_summary(runner: CliRunner, buffer_path: Path) -> None:
    result = runner.invoke(main, ["rank", str(buffer_path), "--top", "3"])
    assert result.output == summary_text(read_buffer(buffer_path), top=3) + "\n"


@pytest.mark.parametrize(
    "extra",
    [
        ["--csv"],
        ["--objective", "centre"],
        ["--by", "key", "--json", "--csv"],
        ["--by", "type", "--exr", "x.exr"],
        ["--by", "key", "--objective", "nope"],
    ],
)
def test_option_misuse_is_bad_input(runner: CliRunner, buffer_path: Path, extra: list) -> None:
    result = runner.invoke(main, ["rank", str(buffer_path), *extra])
    assert result.exit_code == EXIT_BAD_INPUT, result.output


def crypto_header(names: list[str]) -> dict[str, Any]:
    return metadata("CryptoObject", names)


def test_seen_names_reads_coverage_not_the_manifest() -> None:
    names = ["floor", "lamp", "wall"]
    index = np.array([[[0, 2], [2, -1]]], np.int32)  # 1 x 2 pixels, 2 ranks; lamp nowhere
    coverage = np.array([[[0.75, 0.25], [1.0, 0.0]]], np.float32)
    found = rank_channels("CryptoObject", names, index, coverage)
    assert seen_names(found, crypto_header(names)) == {"floor", "wall"}


# The demo job's cameras (configs/cbox.yaml), smaller: the light on the ceiling is in the
# objective camera's frame and hidden from the overhead one, which looks down from outside.
DEMO_CAMERAS = [
    {"name": "objective", "objective": True, "vis_spp": 4},
    {
        "name": "overhead",
        "look_at": {"origin": [0.0, 0.9, 3.0], "target": [0.0, -0.4, 0.0], "up": [0.0, 1.0, 0.0]},
        "fov": 50,
        "resolution": [48, 48],
        "vis_spp": 4,
    },
]


def test_demo_light_is_not_seen_by_the_overhead_camera(job_writer: Any) -> None:
    job = job_writer(
        "offframe",
        inspection_cameras=DEMO_CAMERAS,
        channels=[{"name": "objects", "kind": "object"}],
    )
    assert sensaov("run", "-q", str(job)).returncode == 0
    done = sensaov("project", "-q", str(job))
    assert done.returncode == 0, done.stderr
    out = job.parent / "out"
    exrs = ["--exr", str(out / "objective.exr"), "--exr", str(out / "overhead.exr")]
    result = sensaov("rank", str(out / "buffer.npz"), "--by", "object", "--json", *exrs)
    assert result.returncode == 0, result.stderr
    doc = json.loads(result.stdout)
    assert doc["cameras"] == ["objective", "overhead"]
    off = {r["name"]: r["not_seen_by"] for r in doc["objectives"][0]["rows"]}
    assert off.pop("light") == ["overhead"]
    assert off and all(cameras == [] for cameras in off.values())
    assert doc["format_version"] == 4 and "off_frame" not in doc["columns"]
    text = sensaov("rank", str(out / "buffer.npz"), "--by", "object", *exrs).stdout
    assert any(line.split()[-2:] == ["light", "overhead"] for line in text.splitlines())
    # The column says what it holds: the cameras that do not see the row, never "off-frame".
    (header,) = [line for line in text.splitlines() if line.split()[:1] == ["#"]]
    assert header.split()[-4:] == ["object", "not", "seen", "by"] and "off-frame" not in text
    table = sensaov("rank", str(out / "buffer.npz"), "--by", "object", "--csv", *exrs).stdout
    lights = [row for row in csv.DictReader(io.StringIO(table)) if row["name"] == "light"]
    assert [row["not_seen_by"] for row in lights] == ["overhead"]


def test_a_missing_camera_exr_is_one_line_of_bad_input(buffer_path: Path) -> None:
    """A fresh process, so the OpenEXR library's own stderr would show if it were reached."""
    missing = buffer_path.parent / "nope.exr"
    result = sensaov("rank", str(buffer_path), "--by", "object", "--exr", str(missing))
    assert result.returncode == EXIT_BAD_INPUT
    assert result.stderr.strip().splitlines() == [
        f"sensaov: error: {missing}: the OpenEXR file does not exist; no output was replaced"
    ]


def zero_valued_buffer() -> SensitivityBuffer:
    """make_buffer() with the lamp's radiance at 0: value weighting scores it 0."""
    base = make_buffer()
    values = dict(base.values)
    values["lamp.emitter.radiance.value"] = np.zeros(3, np.float32)
    return SensitivityBuffer(
        provenance=base.provenance, objects=base.objects, params=base.params,
        objectives=base.objectives, values=values, grads=base.grads,
    )  # fmt: skip


def test_zero_valued_parameters_are_flagged_with_their_raw_gradient() -> None:
    """θ = 0 gives a value-weighted score of 0: never 'does not matter'
    without a word, in rankings, the summary, channels and the sunburst."""
    from sensaov_cli.job.spec import ChannelSpec
    from sensaov_cli.outputs.tables import ranking_json, ranking_text, summary_json
    from sensaov_cli.views.channels import channel_values
    from sensaov_cli.views.hierarchy import panels, ranked_summary, rankings

    buf, key = zero_valued_buffer(), "lamp.emitter.radiance.value"
    raw = float(buf.grad("brightness", key).astype(np.float64).sum())
    found = rankings(buf, by="key", objectives=["brightness"])
    (row,) = [r for r in found[0].rows if r.name == key]
    assert (row.score, row.zero_value, row.raw_signed) == (0.0, True, pytest.approx(raw))
    doc = json.loads(ranking_json(buf, found, method="l2", weight="value", cameras=None))
    (entry,) = doc["objectives"][0]["zero_valued"]
    assert (entry["key"], entry["hidden"], entry["size"]) == (key, 3, 3)
    text = ranking_text(found, method="l2", weight="value")
    assert "θ0" in text and f"{key} (lamp): {raw:+.3e}" in text
    (lamp,) = [r for r in rankings(buf, by="object")[0].rows if r.name == "lamp"]
    assert lamp.zero_value  # its object says so too
    summary = json.loads(summary_json(ranked_summary(buf)))["objectives"][0]
    assert [z["key"] for z in summary["zero_valued"]] == [key]
    assert "θ0 = value exactly 0" in summary_text(buf)
    (objects, *_) = channel_values(buf, (ChannelSpec("objects", "object"),))
    assert objects.zero_valued == {key: pytest.approx(raw)}
    assert [z.key for z in panels(buf, ["brightness"])[0].zero_valued] == [key]
    raw_weight = rankings(buf, by="key", weight="raw", objectives=["brightness"])[0]
    assert not any(r.zero_value for r in raw_weight.rows)  # nothing hidden per unit of θ
