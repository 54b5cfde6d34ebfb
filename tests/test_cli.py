"""The command line's shape: one module per command, the exit-code epilog, a fast --help.

The commands' output is covered where their stages are (test_run, test_project, test_report);
here is what belongs to cli/ itself and to the ``check`` orchestration behind it.
"""

from __future__ import annotations

import importlib
import pkgutil
import subprocess
import sys
from importlib.metadata import entry_points
from pathlib import Path
from types import SimpleNamespace

import pytest
from click.testing import CliRunner

import sensaov_cli.cli
from sensaov_cli import interrupts
from sensaov_cli.cli import console, main
from sensaov_cli.errors import EXIT_BAD_INPUT, EXIT_JOB_FAILED, EXIT_MEANINGS, EXIT_OK

REPO = Path(__file__).resolve().parents[1]
COMMANDS = (
    "validate",
    "schema",
    "params",
    "run",
    "project",
    "check",
    "merge",
    "rank",
    "sunburst",
    "report",
    "view",
)
CLI_MODULES = [f"sensaov_cli.cli.{m.name}" for m in pkgutil.iter_modules(sensaov_cli.cli.__path__)]


@pytest.fixture
def runner(monkeypatch: pytest.MonkeyPatch) -> CliRunner:
    # pytest keeps its own Ctrl-C handling: the commands' signal handlers are not installed
    monkeypatch.setattr(interrupts, "install", lambda **_: None)
    return CliRunner()


def test_one_module_per_command() -> None:
    assert set(main.commands) == set(COMMANDS)
    assert set(CLI_MODULES) == {f"sensaov_cli.cli.{c}" for c in COMMANDS} | {
        "sensaov_cli.cli.options"
    }
    for name in COMMANDS:
        module = importlib.import_module(f"sensaov_cli.cli.{name}")
        assert main.commands[name] is getattr(module, name)


@pytest.mark.parametrize("command", COMMANDS)
def test_help_has_an_example_and_every_exit_code(runner: CliRunner, command: str) -> None:
    result = runner.invoke(main, [command, "--help"])
    assert result.exit_code == EXIT_OK, result.output
    assert "Example:" in result.output and f"sensaov {command} " in result.output
    for code, meaning in EXIT_MEANINGS.items():
        assert f"  {code}  {meaning}\n" in result.output


def test_group_help_lists_the_exit_codes(runner: CliRunner) -> None:
    result = runner.invoke(main, ["--help"], prog_name="sensaov")
    assert result.exit_code == EXIT_OK
    codes = result.output.split("Exit codes:\n", 1)[1].splitlines()
    assert [line.split()[0] for line in codes] == [str(code) for code in EXIT_MEANINGS]


def test_importing_the_cli_loads_no_stage_library() -> None:
    """--help stays instant: numpy, pydantic and the renderer load inside the commands."""
    code = (
        "import importlib, sys\n"
        f"for name in {CLI_MODULES!r}: importlib.import_module(name)\n"
        "print(' '.join(sorted({m.split('.')[0] for m in sys.modules})))"
    )
    result = subprocess.run(
        [sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, check=True
    )
    loaded = set(result.stdout.split())
    assert loaded & {"numpy", "mitsuba", "drjit", "pydantic", "yaml"} == set()
    assert "sensaov_cli" in loaded


def test_console_script_and_module_entry_point() -> None:
    (script,) = entry_points(group="console_scripts", name="sensaov")
    assert script.load() is console  # main, then an exit without the interpreter's teardown
    result = subprocess.run(
        [sys.executable, "-m", "sensaov_cli", "--version"],
        cwd=REPO,
        capture_output=True,
        text=True,
        check=True,
    )
    assert result.stdout == "sensaov, version 0.1.0\n"


def _gradient_check(verified: bool, verdict: str) -> SimpleNamespace:
    return SimpleNamespace(
        key="k",
        plugin="diffuse",
        type="reflectance",
        claimed_verified=verified,
        claimed="verified" if verified else "biased",
        adjoint=1.0,
        finite_difference=2.0,
        standard_error=0.01,
        verdict=verdict,
        method="seeds",
        reason="" if verdict == "agrees" else f"why it {verdict}",
    )


@pytest.mark.parametrize(
    ("verified", "verdict", "code"),
    [
        (True, "disagrees", EXIT_JOB_FAILED),
        (False, "disagrees", EXIT_OK),  # the table already says not to trust it
        (True, "agrees", EXIT_OK),
        (True, "inconclusive", EXIT_OK),
        (True, "noisy", EXIT_OK),  # heavy-tailed seeds: no evidence either way
    ],
)
def test_check_exit_code(verified: bool, verdict: str, code: int) -> None:
    from sensaov_cli.pipeline.check import exit_code

    checks = [_gradient_check(True, "agrees"), _gradient_check(verified, verdict)]
    assert exit_code(checks) == code  # type: ignore[arg-type]
    assert exit_code([]) == EXIT_OK


def test_check_command_exits_1_when_the_table_is_contradicted(
    runner: CliRunner, monkeypatch: pytest.MonkeyPatch
) -> None:
    import sensaov_cli.pipeline.check

    calls: list[dict[str, object]] = []

    plan = SimpleNamespace(skipped=(("c", "known biased"),), notes=("Russian roulette ...",))

    def fake_plan(loaded: object, keys: list[str] | None, full: bool) -> SimpleNamespace:
        calls.append({"keys": keys, "full": full})
        return plan

    def fake_audit(loaded: object, built: object, given: object, **options: object) -> list:
        calls.append({"plan": given, "spp": options["spp"], "seeds": list(options["seeds"])})
        return [_gradient_check(True, "disagrees")]

    # The scene is prepared and loaded for real; the renders of the check are faked.
    monkeypatch.setattr(sensaov_cli.pipeline.check, "plan_audit", fake_plan)
    monkeypatch.setattr(sensaov_cli.pipeline.check, "audit", fake_audit)
    args = ["--seeds", "3", "--key", "a", "--key", "b", "--buffer", "/nonexistent/buffer.npz"]
    result = runner.invoke(main, ["check", str(REPO / "configs/cbox.yaml"), *args])
    assert result.exit_code == EXIT_JOB_FAILED, result.output
    assert "CONTRADICTS THE TABLE" in result.stdout
    assert "not measured: c: known biased" in result.stdout
    assert "disagrees: k: why it disagrees" in result.stdout  # the reason, beneath the table
    assert "note: Russian roulette ..." in result.stdout
    assert "no buffer at /nonexistent/buffer.npz: duality column skipped" in result.stderr
    assert calls == [
        {"keys": ["a", "b"], "full": False},
        {"plan": plan, "spp": 64, "seeds": [0, 1, 2]},
    ]


def test_check_refuses_an_unknown_objective(runner: CliRunner) -> None:
    result = runner.invoke(main, ["check", str(REPO / "configs/cbox.yaml"), "--objective", "nope"])
    assert result.exit_code == EXIT_BAD_INPUT
    assert result.stderr == (
        "sensaov: error: --objective: no objective named 'nope' "
        "(objectives: mean_luma, back_wall_luma); no output was replaced\n"
    )


def test_a_library_error_is_one_line_and_its_exit_code(runner: CliRunner, tmp_path: Path) -> None:
    not_a_buffer = tmp_path / "buffer.npz"
    not_a_buffer.write_text("hello")
    result = runner.invoke(main, ["rank", str(not_a_buffer)])
    assert result.exit_code == EXIT_BAD_INPUT
    assert result.stdout == ""
    assert result.stderr.startswith(f"sensaov: error: {not_a_buffer}: not a sensaov buffer")
    assert len(result.stderr.splitlines()) == 1


def test_an_unexpected_error_is_an_internal_error(
    runner: CliRunner, monkeypatch: pytest.MonkeyPatch
) -> None:
    import sensaov_cli.job.load

    def broken(path: Path) -> None:
        raise ZeroDivisionError("first line\nlast line")

    monkeypatch.setattr(sensaov_cli.job.load, "load_job", broken)
    result = runner.invoke(main, ["validate", "whatever.yaml"])
    assert result.exit_code == EXIT_JOB_FAILED
    assert result.stderr == (
        "sensaov: error: internal error: ZeroDivisionError: last line "
        "(run with -vv for the traceback); no output was replaced\n"
    )
    verbose = runner.invoke(main, ["-vv", "validate", "whatever.yaml"])
    assert "Traceback" in verbose.stderr and "run with -vv" not in verbose.stderr


def test_check_table_says_biased_where_the_trust_table_does() -> None:
    from sensaov_cli.pipeline.check import checks_text

    text = checks_text([_gradient_check(False, "disagrees")])  # type: ignore[list-item]
    (row, reason) = text.splitlines()[1:]
    assert reason == "disagrees: k: why it disagrees"
    assert " biased " in row and "unverified" not in row
