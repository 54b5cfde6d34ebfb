#!/usr/bin/env python3
"""Load and render every corpus scene in plain Mitsuba (no sensaov code involved).

For each job: ``mi.load_file(scene.xml, optimize=False, **args)``, ``mi.render(scene, spp=4)``,
then check that the image is finite and not black, and that the scene holds exactly the
named shapes and emitters (and the number of unnamed ones) that README.md lists. Also checks
that the committed assets match make_assets.py byte for byte, and that a scene with a
required parameter refuses to load without it. Prints one line per job; exit status 1 if
anything failed.

    python scenes/corpus/check_corpus.py              # all jobs, 4 spp
    python scenes/corpus/check_corpus.py glass_table  # jobs whose name starts with this

If DRJIT_LIBLLVM_PATH is unset, a system libLLVM >= 19 is looked for and used (Dr.Jit's own
pick can land on an older libLLVM that aborts the process on the first kernel).
"""

from __future__ import annotations

import argparse
import glob
import os
import re
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent

# (job name, scene folder, scene arguments, expected content)
# expected: named shape ids, number of unnamed shapes, named emitter ids, number of unnamed
# emitters. Area emitters count as emitters; an area emitter without its own id is unnamed.
JOBS: list[tuple[str, str, dict[str, str], dict]] = [
    (
        "shaderball",
        "shaderball",
        {},
        {
            "shapes": ["ground", "ball"],
            "unnamed_shapes": 1,
            "emitters": ["sky"],
            "unnamed_emitters": 0,
        },
    ),
    (
        "shaderball:material=gold",
        "shaderball",
        {"material": "gold"},
        {
            "shapes": ["ground", "ball"],
            "unnamed_shapes": 1,
            "emitters": ["sky"],
            "unnamed_emitters": 0,
        },
    ),
    (
        "cbox_spectral",
        "cbox_spectral",
        {},
        {
            "shapes": ["light", "back_wall", "left_wall", "right_wall"]
            + ["tall_box", "copper_ball", "card"],
            "unnamed_shapes": 3,
            "emitters": [],
            "unnamed_emitters": 1,
        },
    ),
    (
        "instanced_shelf",
        "instanced_shelf",
        {},
        {
            "shapes": ["pot_a", "pot_b", "shelf_board", "floor"],
            "unnamed_shapes": 2,
            "emitters": ["bulb"],
            "unnamed_emitters": 1,
        },
    ),
    (
        "texture_lab",
        "texture_lab",
        {},
        {
            "shapes": ["tile_repeat", "tile_mirror", "tile_clamp", "tile_nested", "metal_ball"],
            "unnamed_shapes": 1,
            "emitters": ["spot_key"],
            "unnamed_emitters": 1,
        },
    ),
    (
        "glass_table",
        "glass_table",
        {"ior": "1.5"},
        {
            "shapes": ["slab", "glass_ball", "frosted_blob", "pane", "lamp"],
            "unnamed_shapes": 1,
            "emitters": ["sky"],
            "unnamed_emitters": 1,
        },
    ),
    (
        "emitter_zoo",
        "emitter_zoo",
        {},
        {
            "shapes": ["backdrop", "pillar", "chrome_ball", "leaf", "panel"],
            "unnamed_shapes": 2,
            "emitters": ["strip_light", "spot", "sun", "ambient"],
            "unnamed_emitters": 2,
        },
    ),
]

# scenes with a parameter that has no <default>: loading without it must fail
REQUIRED = [("glass_table", "ior")]


def ensure_libllvm() -> None:
    if os.environ.get("DRJIT_LIBLLVM_PATH") or sys.platform != "linux":
        return
    best: tuple[int, str] | None = None
    candidates = glob.glob("/usr/lib/*/libLLVM*.so*")
    candidates += glob.glob("/usr/lib/llvm-*/lib/libLLVM*.so*")
    for path in candidates:
        m = re.search(r"libLLVM(?:-|\.so\.)(\d+)", path)
        if m and int(m.group(1)) >= 19 and (best is None or int(m.group(1)) > best[0]):
            best = (int(m.group(1)), path)
    if best is not None:
        os.environ["DRJIT_LIBLLVM_PATH"] = best[1]


def check_assets() -> tuple[bool, str]:
    sys.path.insert(0, str(HERE))
    sys.dont_write_bytecode = True  # no __pycache__ inside the corpus folder
    try:
        import make_assets
    finally:
        sys.path.pop(0)
    files = make_assets.build()
    differ = [rel for rel, data in files.items() if (HERE / rel).read_bytes() != data]
    total = sum(len(d) for d in files.values())
    if differ:
        return False, f"assets differ from make_assets.py output: {', '.join(differ)}"
    return True, f"{len(files)} files, {total} B, identical to make_assets.py output"


def content_problems(scene, expected: dict) -> list[str]:
    shape_ids = [s.id() for s in scene.shapes()]
    emitter_ids = [e.id() for e in scene.emitters()]
    problems = []
    for kind, ids in (("shapes", shape_ids), ("emitters", emitter_ids)):
        named = sorted(i for i in ids if i)
        if named != sorted(expected[kind]):
            problems.append(f"named {kind} {named} != {sorted(expected[kind])}")
        unnamed = sum(1 for i in ids if not i)
        if unnamed != expected["unnamed_" + kind]:
            problems.append(f"{unnamed} unnamed {kind}, expected {expected['unnamed_' + kind]}")
    return problems


def main() -> int:
    ap = argparse.ArgumentParser(description="render every corpus scene in plain Mitsuba")
    ap.add_argument("only", nargs="*", help="job name prefixes to run (default: all)")
    ap.add_argument("--spp", type=int, default=4)
    ap.add_argument("--variant", default="llvm_ad_rgb")
    args = ap.parse_args()

    ensure_libllvm()
    import mitsuba as mi
    import numpy as np

    mi.set_variant(args.variant)
    failures = 0

    ok, msg = check_assets()
    print(f"{'assets':26s} {'ok' if ok else 'FAIL':4s} {msg}")
    failures += not ok

    for name, folder, scene_args, expected in JOBS:
        if args.only and not any(name.startswith(p) for p in args.only):
            continue
        path = HERE / folder / "scene.xml"
        t0 = time.perf_counter()
        try:
            scene = mi.load_file(str(path), optimize=False, **scene_args)
            img = np.array(mi.render(scene, spp=args.spp), dtype=np.float64)
            dt = time.perf_counter() - t0
            problems = content_problems(scene, expected)
            finite = bool(np.isfinite(img).all())
            mean = float(img.mean()) if finite else float("nan")
            lit = float((img.sum(axis=-1) > 0).mean())
            if not finite:
                problems.append("non-finite pixels")
            if not mean > 1e-3 or lit < 0.5:
                problems.append(f"image (nearly) black: mean {mean:.4g}, {lit:.0%} lit pixels")
            h, w = img.shape[:2]
            line = f"mean {mean:.4f}  {lit:4.0%} lit  {w}x{h}  {dt:5.2f} s"
        except Exception as e:  # noqa: BLE001 - report any loader/render failure per scene
            problems = [f"{type(e).__name__}: {str(e).splitlines()[0]}"]
            line = ""
        status = "FAIL" if problems else "ok"
        failures += bool(problems)
        sep = "  " if line and problems else ""
        print(f"{name:26s} {status:4s} {line}{sep}{'; '.join(problems)}")

    for folder, param in REQUIRED:
        if args.only and not any(folder.startswith(p) for p in args.only):
            continue
        try:
            mi.load_file(str(HERE / folder / "scene.xml"), optimize=False)
            ok, msg = False, f"loaded without ${param}, but it has no default"
        except Exception as e:  # noqa: BLE001
            text = str(e)
            ok = f"${param}" in text
            msg = f"refused as expected: {text.splitlines()[0][-60:]}" if ok else text[:120]
        print(f"{folder + ' (no ' + param + ')':26s} {'ok' if ok else 'FAIL':4s} {msg}")
        failures += not ok

    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
