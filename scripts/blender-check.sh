#!/usr/bin/env bash
# Open a sensaov EXR in Blender's compositor (headless) and check passes and a Cryptomatte matte.
#
#   scripts/blender-check.sh out/cbox/camera.exr bunny [--out DIR]
#
# Needs Blender >= 3.4 on PATH (Debian: apt-get install -y blender) or in $BLENDER. Not part of
# `make test`: CI does not need Blender. Exit status: 0 all checks pass, 1 a check failed,
# 2 bad arguments or no Blender.
set -euo pipefail

if [[ $# -lt 2 ]]; then
    echo "usage: $0 EXR OBJECT_NAME [--out DIR]" >&2
    exit 2
fi
blender=${BLENDER:-blender}
if ! command -v "$blender" >/dev/null; then
    echo "$0: no '$blender' on PATH (apt-get install -y blender, or set BLENDER)" >&2
    exit 2
fi
here=$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)
exec "$blender" -b --factory-startup --python-exit-code 1 \
    --python "$here/blender_check.py" -- "$@"
