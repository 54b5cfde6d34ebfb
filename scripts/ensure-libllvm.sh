#!/usr/bin/env bash
# Make sure a libLLVM >= 19 is present: Dr.Jit's CPU backend needs it, and the machine image's
# LLVM 15 is accepted by Dr.Jit and then aborts the process (see docs/install.md).
set -euo pipefail

find_llvm() {
    ls /usr/lib/*-linux-gnu/libLLVM*.so* /usr/lib/llvm-*/lib/libLLVM*.so* 2>/dev/null \
        | grep -E 'libLLVM(-|\.so\.)(19|[2-9][0-9])' | head -n 1
}

if [ -n "${DRJIT_LIBLLVM_PATH:-}" ] && [ -f "$DRJIT_LIBLLVM_PATH" ]; then
    echo "libLLVM: $DRJIT_LIBLLVM_PATH (from DRJIT_LIBLLVM_PATH)"
    exit 0
fi
found=$(find_llvm || true)
if [ -n "$found" ]; then
    echo "libLLVM: $found"
    exit 0
fi
if [ "$(id -u)" -ne 0 ]; then
    echo "error: no libLLVM >= 19 found; run 'sudo apt-get install libllvm19' (or set DRJIT_LIBLLVM_PATH)" >&2
    exit 1
fi
echo "libLLVM >= 19 not found; installing Debian's libllvm19 ..."
export DEBIAN_FRONTEND=noninteractive
apt-get install -y -q libllvm19 >/dev/null 2>&1 || { apt-get update -q >/dev/null && apt-get install -y -q libllvm19 >/dev/null; }
found=$(find_llvm || true)
[ -n "$found" ] || { echo "error: libllvm19 installed but no libLLVM found" >&2; exit 1; }
echo "libLLVM: $found"
