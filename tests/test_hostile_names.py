"""Names from scenes and buffers are data, never paths: hostile names through every writer."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from sensaov_cli.outputs.atomic import MAX_TOKEN, file_token
from sensaov_cli.outputs.contact_sheets import write_manifest, write_previews
from sensaov_cli.outputs.layered_exr import SensitivityLayer
from sensaov_cli.outputs.tables import format_table
from sensaov_cli.views.channels import robust_scale

HOSTILE = [
    "/etc/passwd", "../../outside", "..", ".", "", "a/b\\c", "tab\tnew\nline\x00nul",
    "x" * 300, "Ünïcødé ✓ 名前", "-rf", ".hidden", "con:aux|*?<>",
]  # fmt: skip


@pytest.mark.parametrize("name", HOSTILE)
def test_a_token_is_one_safe_file_name(name: str) -> None:
    token = file_token(name)
    assert 0 < len(token) <= MAX_TOKEN and token not in (".", "..")
    assert token.isascii() and "/" not in token and "\\" not in token
    assert token.isprintable() and not token.startswith((".", "-")) and ".." not in token


def test_distinct_names_get_distinct_tokens() -> None:
    assert len({file_token(n) for n in HOSTILE}) == len(HOSTILE)
    assert file_token("mean_luma") == "mean_luma"  # a safe name stays as it is


def test_previews_stay_inside_their_folder(tmp_path: Path) -> None:
    folder = tmp_path / "out" / "previews"
    data = np.linspace(-1, 1, 16, dtype=np.float32).reshape(4, 4)
    scale = robust_scale({"../cam": [data]})
    layers = [
        (SensitivityLayer(name, name, data, {"encoding": "linear", "unverified": "[]"}), scale)
        for name in HOSTILE[:4] + HOSTILE[5:]
    ]
    coverage = np.ones((4, 4), np.float32)

    class Visibility:
        coverage_hit = coverage

    entries = write_previews(folder, "../cam", layers, None, Visibility(), {})  # type: ignore[arg-type]
    manifest = write_manifest(folder, "../cam", entries, {})
    written = [folder / entry.file for entry in entries] + [manifest]
    assert written and all(p.resolve().is_relative_to(folder.resolve()) for p in written)
    assert {p for p in tmp_path.rglob("*") if p.is_file()} == set(written)


def test_a_newline_in_a_key_stays_in_its_row() -> None:
    lines = format_table([["key", "score"], ["a\nb\rc", "1"], ["d", "2"]])
    assert len(lines) == 3 and lines[1].startswith("a\\nb\\rc")
