"""libLLVM discovery: the first thing that breaks on a fresh machine."""

from __future__ import annotations

import subprocess
import sys

import pytest

from sensaov_cli.errors import EnvironmentProblem
from sensaov_cli.render import runtime


@pytest.mark.parametrize(
    ("name", "major"),
    [
        ("libLLVM.so.19.1", 19),
        ("libLLVM-19.so", 19),
        ("libLLVM-15.so.1", 15),
        ("libLLVM-14.0.6.so.1", 14),
        ("libLLVMSupport.a", None),
    ],
)
def test_major_version_from_library_name(name: str, major: int | None) -> None:
    assert runtime.llvm_major_from_name(f"/usr/lib/x86_64-linux-gnu/{name}") == major


def test_find_libllvm_never_picks_a_version_below_19(monkeypatch: pytest.MonkeyPatch) -> None:
    names = ["/l/libLLVM-14.so.1", "/l/libLLVM-15.so.1", "/l/libLLVM.so.19.1", "/l/libLLVM-15.so"]
    monkeypatch.setattr(runtime.glob, "glob", lambda pattern: names)
    monkeypatch.setattr(runtime.os.path, "isfile", lambda path: True)
    assert runtime.find_libllvm() == "/l/libLLVM.so.19.1"
    monkeypatch.setattr(runtime.glob, "glob", lambda pattern: names[:2])
    assert runtime.find_libllvm() is None


def test_missing_llvm_is_an_environment_error_with_a_fix(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("DRJIT_LIBLLVM_PATH", raising=False)
    monkeypatch.setattr(runtime, "find_libllvm", lambda: None)
    with pytest.raises(EnvironmentProblem, match="libLLVM") as info:
        runtime.configure_libllvm()
    assert "apt-get install libllvm19" in str(info.value)
    assert info.value.exit_code == 3


def test_a_bad_explicit_path_is_refused(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("DRJIT_LIBLLVM_PATH", "/nonexistent/libLLVM.so.19")
    with pytest.raises(EnvironmentProblem, match="does not exist"):
        runtime.configure_libllvm()


def test_llvm_15_is_refused_before_any_kernel_runs(tmp_path) -> None:  # noqa: ANN001
    """LLVM 15 would abort the process on the first kernel; sensaov must exit cleanly instead."""
    llvm15 = "/usr/lib/x86_64-linux-gnu/libLLVM-15.so.1"
    if not runtime.os.path.isfile(llvm15):
        pytest.skip("this machine has no LLVM 15 to try")
    code = "from sensaov_cli.render.runtime import import_mitsuba; import_mitsuba('llvm_ad_rgb')"
    env = dict(runtime.os.environ, DRJIT_LIBLLVM_PATH=llvm15)
    done = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    assert done.returncode == 1  # a Python exception, not SIGABRT (-6)
    assert "needs LLVM >= 19" in done.stderr
