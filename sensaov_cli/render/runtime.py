"""Bring up Dr.Jit and Mitsuba safely: the right libLLVM, then the right variant.

Dr.Jit reads ``DRJIT_LIBLLVM_PATH`` once, at ``import drjit``; left to itself it may pick LLVM
15, which aborts the process on the first kernel (MITSUBA-NOTES). So the path is chosen before
the first import, and the loaded version checked before anything is rendered.
"""

from __future__ import annotations

import glob
import os
import re
from pathlib import Path
from types import ModuleType
from typing import Any

from sensaov_cli import interrupts
from sensaov_cli.errors import EnvironmentProblem

MIN_LLVM_MAJOR = 19
LLVM_HINT = "install Debian's libllvm19 (apt-get install libllvm19) or set DRJIT_LIBLLVM_PATH"
_SEARCH_GLOBS = (
    "/usr/lib/*-linux-gnu/libLLVM*.so*",
    "/usr/lib/llvm-*/lib/libLLVM*.so*",
    "/usr/lib64/libLLVM*.so*",
    "/usr/local/lib/libLLVM*.so*",
)


def llvm_major_from_name(path: str) -> int | None:
    """The LLVM major version a library file name announces (``libLLVM.so.19.1`` -> 19)."""
    match = re.search(r"libLLVM(?:-|\.so\.)(\d+)", os.path.basename(path))
    return int(match.group(1)) if match else None


def find_libllvm() -> str | None:
    """The newest libLLVM on this machine that Dr.Jit can use, or None."""
    candidates = []
    for pattern in _SEARCH_GLOBS:
        for path in glob.glob(pattern):
            major = llvm_major_from_name(path)
            if major is not None and major >= MIN_LLVM_MAJOR and os.path.isfile(path):
                candidates.append((major, path))
    return max(candidates)[1] if candidates else None


def configure_libllvm() -> str:
    """Point Dr.Jit at a usable libLLVM before it is imported; returns the chosen path."""
    chosen = os.environ.get("DRJIT_LIBLLVM_PATH")
    if chosen:
        if not Path(chosen).is_file():
            raise EnvironmentProblem(
                f"DRJIT_LIBLLVM_PATH points to {chosen!r}, which does not exist", hint=LLVM_HINT
            )
        return chosen
    found = find_libllvm()
    if found is None:
        raise EnvironmentProblem(
            f"no libLLVM >= {MIN_LLVM_MAJOR} found (Dr.Jit's CPU backend needs it)",
            hint=LLVM_HINT,
        )
    os.environ["DRJIT_LIBLLVM_PATH"] = found
    return found


def cuda_available(dr: ModuleType) -> bool:
    try:
        return bool(dr.has_backend(dr.JitBackend.CUDA))
    except Exception:  # noqa: BLE001 - any failure to probe CUDA means "not usable"
        return False


def import_mitsuba(variant: str) -> ModuleType:
    """Import Mitsuba with ``variant`` set (``auto`` picks CUDA when usable, else LLVM); signals
    are deferred meanwhile (a KeyboardInterrupt in the extensions' set-up aborts the process)."""
    with interrupts.deferred():
        llvm_problem = None
        if not variant.startswith("cuda"):
            try:
                configure_libllvm()
            except EnvironmentProblem as problem:  # fatal only if the LLVM backend is chosen
                llvm_problem = problem
        import drjit as dr
        import mitsuba as mi

        if variant == "auto":
            variant = "cuda_ad_rgb" if cuda_available(dr) else "llvm_ad_rgb"
        if variant.startswith("llvm"):
            if llvm_problem is not None:
                raise llvm_problem
            version = tuple(dr.detail.llvm_version())
            if not version or version[0] == 0:
                raise EnvironmentProblem(
                    f"Dr.Jit could not load libLLVM from {os.environ.get('DRJIT_LIBLLVM_PATH')}",
                    hint=LLVM_HINT,
                )
            if version[0] < MIN_LLVM_MAJOR:
                raise EnvironmentProblem(
                    f"Dr.Jit loaded LLVM {'.'.join(map(str, version))}, "
                    f"but sensaov needs LLVM >= {MIN_LLVM_MAJOR}",
                    hint=LLVM_HINT,
                )
        elif not cuda_available(dr):
            raise EnvironmentProblem(
                f"variant {variant!r} needs a usable CUDA device and none was found",
                hint="use variant: auto or an llvm_ad_* variant",
            )
        if variant not in mi.variants():
            raise EnvironmentProblem(
                f"this Mitsuba build has no variant {variant!r}",
                hint=f"available: {', '.join(mi.variants())}",
            )
        mi.set_variant(variant)
        _log_to_stderr(mi)
        return mi


def library_versions(mi: ModuleType) -> dict[str, str]:
    """The versions of the Mitsuba and Dr.Jit that are loaded (what ran), for provenance."""
    import drjit as dr

    drjit_version = dr.__version__  # type: ignore[attr-defined]  # set at import, not in stubs
    return {"mitsuba_version": mi.__version__, "drjit_version": str(drjit_version)}


def _log_to_stderr(mi: ModuleType) -> None:
    """Mitsuba logs to stdout, where `--json` output goes: send its messages to stderr."""
    import sys

    class StderrAppender(mi.Appender):  # type: ignore[name-defined]
        def append(self, level: Any, text: str) -> None:
            print(text, file=sys.stderr, flush=True)

        def log_progress(self, *args: Any) -> None:
            pass  # sensaov reports its own progress

    logger = mi.logger()
    logger.clear_appenders()
    logger.add_appender(StderrAppender())
