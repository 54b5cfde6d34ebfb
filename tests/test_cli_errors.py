"""A malformed job on the command line: exit code 2, one line on stderr, nothing written.

The same table as test_spec's, run through the command line (``main``, as the executable runs
it), so the whole path from job file to stderr is covered: no traceback, no half-made output
directory.
"""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest

from sensaov_cli.errors import EXIT_BAD_INPUT

from .conftest import sensaov
from .spec_cases import CASE_PARAMS, CASES, SpecCase, expected_where, write_fixture

VALIDATE_CASES = [
    pytest.param(case, id=case.id)
    for case in CASES
    if case.id
    in {
        "unknown top-level key",
        "duplicate YAML key",
        "YAML syntax error",
        "missing target file",
        "empty file",
    }
]


def run_cli(command: str, job: Path, cwd: Path) -> subprocess.CompletedProcess[str]:
    return sensaov(command, str(job), cwd=cwd)


def listing(root: Path) -> set[str]:
    return {str(path.relative_to(root)) for path in root.rglob("*")}


def check_refused(command: str, tmp_path: Path, case: SpecCase) -> None:
    job = write_fixture(tmp_path, case.text)
    before = listing(tmp_path)
    result = run_cli(command, job, tmp_path)
    assert result.returncode == EXIT_BAD_INPUT, result.stderr
    assert "Traceback" not in result.stderr
    lines = result.stderr.splitlines()
    assert len(lines) == 1 and lines[0].strip(), result.stderr
    assert expected_where(str(job), case) in lines[0]
    assert case.says in lines[0]
    assert listing(tmp_path) == before


@pytest.mark.parametrize("case", CASE_PARAMS)
def test_run_refuses_malformed_job(tmp_path: Path, case: SpecCase) -> None:
    check_refused("run", tmp_path, case)


@pytest.mark.parametrize("case", VALIDATE_CASES)
def test_validate_refuses_malformed_job(tmp_path: Path, case: SpecCase) -> None:
    check_refused("validate", tmp_path, case)
