"""Measure the trust table of docs/verification.md: sensaov's gradients against finite differences.

One tiny scene per plugin kind (32x32, a unit sphere before a checkered wall, lit by an area
light, or lit by the emitter under test), loaded through sensaov's own scene stage so every
parameter is named, typed and routed (prb or path) exactly as in a run. Each parameter is
checked with sensaov's fdcheck: same-seed central differences where θ does not change how
paths are sampled, independent-seed differences at a high sample count where it does (lobe
selection, roughness, eta, blend weights: a shared seed does not give shared paths there).

    .venv/bin/python scripts/trust_table.py            # about 8 minutes on 2 quiet cores
    .venv/bin/python scripts/trust_table.py --only plastic,envmap

It prints the markdown that docs/verification.md holds: one row per parameter checked, then one
label per (plugin, type) kind, the worst of its rows. sensaov_cli/render/verify/trust.py must
say the same (tests/test_trust.py compares them).
"""

from __future__ import annotations

import argparse
import datetime
import os
import sys
import tempfile
import time
from dataclasses import dataclass
from importlib.metadata import version
from pathlib import Path

import numpy as np
import yaml

from sensaov_cli.job.load import load_job
from sensaov_cli.render.loading import load_job_scene
from sensaov_cli.render.objectives import build_objectives
from sensaov_cli.render.runtime import import_mitsuba
from sensaov_cli.render.verify.fdcheck import GradientCheck, check_parameter
from sensaov_cli.render.verify.trust import COMPOSITES, TABLE, Context

RES, SPP, SEEDS = 32, 32, 8  # same-seed checks
IND_SPP, IND_FD_SPP, IND_SEEDS = 32, 1024, 12  # independent-seed checks
WORST_FIRST = ("no_gradient", "biased", "suspect", "unverified", "verified")

STAGE = """<scene version="3.0.0">
  <integrator type="{integrator}"><integer name="max_depth" value="5"/></integrator>
  <sensor type="perspective" id="sensor">
    <float name="fov" value="40"/>
    <transform name="to_world">
      <lookat origin="0, 0.3, 3.4" target="0, 0, 0" up="0, 1, 0"/></transform>
    <sampler type="independent"><integer name="sample_count" value="16"/></sampler>
    <film type="hdrfilm"><integer name="width" value="{res}"/><integer name="height" value="{res}"/>
      <rfilter type="box"/></film>
  </sensor>
  <shape type="sphere" id="object"><float name="radius" value="1"/>{bsdf}</shape>
  <shape type="rectangle" id="wall">
    <transform name="to_world"><scale value="4"/><translate z="-2"/></transform>
    <bsdf type="diffuse"><texture type="checkerboard" name="reflectance">
      <transform name="to_uv"><scale value="6"/></transform></texture></bsdf>
  </shape>
  <shape type="rectangle" id="floor">
    <transform name="to_world">
      <scale value="4"/><rotate x="1" angle="-90"/><translate y="-1"/></transform>
    <bsdf type="diffuse"><rgb name="reflectance" value="0.6, 0.25, 0.2"/></bsdf>
  </shape>
  {lights}
</scene>"""
AREA = """<shape type="rectangle" id="light">
    <transform name="to_world">
      <rotate x="1" angle="90"/><translate x="0.5" y="3" z="2"/></transform>
    <emitter type="area">{radiance}</emitter></shape>"""
AREA_RGB = AREA.format(radiance='<rgb name="radiance" value="9, 8, 7"/>')
DIFFUSE = '<bsdf type="diffuse"><rgb name="reflectance" value="0.5, 0.6, 0.4"/></bsdf>'
RGB = '<rgb name="{}" value="{}"/>'
SPOT_AT = '<transform name="to_world"><lookat origin="0, 3, 2" target="0, 0, 0"/></transform>'


@dataclass(frozen=True)
class Case:
    name: str  # what the scene shows, e.g. "conductor (smooth)"
    bsdf: str = DIFFUSE
    lights: str = AREA_RGB
    include: tuple[str, ...] = ("object.bsdf.*",)
    independent: tuple[str, ...] = ()  # key suffixes checked with independent seeds
    kind: bool = True  # False: a condition the self-checks catch, not evidence for its kind
    composite: bool = False  # shown with its contexts in the composites' table
    ad_spp: int = IND_SPP  # independent checks of small or noisy derivatives need more
    fd_spp: int = IND_FD_SPP
    integrator: str = "path"  # "volpath" for media: sensaov differentiates them with prbvolpath


def _bsdf(kind: str, *children: str) -> str:
    return f'<bsdf type="{kind}">{"".join(children)}</bsdf>'


def _bitmap(name: str, file: str) -> str:
    return (
        f'<texture type="bitmap" name="{name}"><string name="filename" value="{file}"/></texture>'
    )


ROUGH_PLASTIC = _bsdf(
    "roughplastic",
    '<float name="alpha" value="0.3"/>',
    RGB.format("diffuse_reflectance", "0.3, 0.5, 0.2"),
)
CONDUCTOR = _bsdf("conductor", RGB.format("eta", "0.2, 0.9, 1.1"), RGB.format("k", "3.9, 2.4, 2.2"))
ROUGH_CONDUCTOR = _bsdf(
    "roughconductor",
    '<float name="alpha" value="0.3"/>',
    RGB.format("eta", "0.2, 0.9, 1.1"),
    RGB.format("k", "3.9, 2.4, 2.2"),
)
OPACITY = '<float name="opacity" value="0.6"/>'
BUMP = (
    '<texture type="bitmap" name="bump"><string name="filename" value="tex.exr"/>'
    '<boolean name="raw" value="true"/></texture><float name="scale" value="0.5"/>'
)
NORMALS = (
    '<texture type="bitmap" name="normalmap"><string name="filename" value="normals.exr"/>'
    '<boolean name="raw" value="true"/></texture>'
)
# Parameters that change which lobe is sampled (plastics, blends, Fresnel-weighted choices,
# principled's lobe weights): checked with independent seeds. Roughness changes sampled
# directions continuously, so a shared seed still gives nearby paths: same seed, more seeds.
PRINCIPLED_LOBES = ("metallic.value", "spec_trans.value", "clearcoat.value", "specular")
CASES = (
    Case("diffuse, uniform colour"),
    Case("diffuse, bitmap", _bsdf("diffuse", _bitmap("reflectance", "tex.exr"))),
    Case(
        "diffuse, checkerboard",
        _bsdf(
            "diffuse",
            '<texture type="checkerboard" name='
            '"reflectance"><rgb name="color0" value="0.7, 0.5, 0.3"/></texture>',
        ),
    ),
    Case("twosided diffuse", _bsdf("twosided", DIFFUSE), composite=True),
    Case(
        "plastic (smooth)",
        _bsdf(
            "plastic",
            RGB.format("diffuse_reflectance", "0.3, 0.5, 0.2"),
            RGB.format("specular_reflectance", "0.8, 0.8, 0.8"),
        ),
        independent=("diffuse_reflectance.value", "specular_reflectance.value"),
        fd_spp=4096,
    ),
    Case(
        "roughplastic",
        _bsdf(
            "roughplastic",
            RGB.format("diffuse_reflectance", "0.3, 0.5, 0.2"),
            '<float name="alpha" value="0.2"/>',
        ),
        independent=("diffuse_reflectance.value", "alpha", "eta"),
    ),
    Case(
        "conductor (smooth)",
        _bsdf(
            "conductor",
            RGB.format("eta", "0.2, 0.9, 1.1"),
            RGB.format("k", "3.9, 2.4, 2.2"),
            RGB.format("specular_reflectance", "0.9, 0.9, 0.9"),
        ),
    ),
    Case(
        "roughconductor",
        _bsdf(
            "roughconductor",
            RGB.format("eta", "0.2, 0.9, 1.1"),
            RGB.format("k", "3.9, 2.4, 2.2"),
            '<float name="alpha" value="0.2"/>',
        ),
        independent=("alpha.value",),
        ad_spp=1024,
        fd_spp=4096,
    ),
    Case(
        "dielectric (smooth)",
        _bsdf(
            "dielectric",
            RGB.format("specular_reflectance", "0.9, 0.9, 0.9"),
            RGB.format("specular_transmittance", "0.9, 0.8, 0.7"),
        ),
    ),
    Case(
        "roughdielectric",
        _bsdf("roughdielectric", '<float name="alpha" value="0.2"/>'),
        independent=("eta", "alpha.value"),
        ad_spp=512,
        fd_spp=4096,
    ),
    Case(
        "thindielectric",
        _bsdf("thindielectric", RGB.format("specular_transmittance", "0.9, 0.8, 0.7")),
        independent=("eta",),
    ),
    Case(
        "principled",
        _bsdf(
            "principled",
            RGB.format("base_color", "0.6, 0.4, 0.3"),
            '<float name="metallic" value="0.3"/><float name="roughness" value="0.4"/>'
            '<float name="sheen" value="0.3"/><float name="clearcoat" value="0.3"/>'
            '<float name="spec_trans" value="0.2"/>',
        ),
        independent=PRINCIPLED_LOBES,
    ),
    Case(
        "blendbsdf (diffuse + roughconductor)",
        _bsdf(
            "blendbsdf",
            '<float name="weight" value="0.4"/>',
            DIFFUSE,
            _bsdf("roughconductor", '<float name="alpha" value="0.3"/>'),
        ),
        include=("object.bsdf.weight.value", "object.bsdf.bsdf_0.*"),
        independent=("weight.value",),
        composite=True,
    ),
    # Composites, each over a rough and a smooth child (docs/verification.md, "Composites").
    Case(
        "blendbsdf (roughplastic + smooth conductor), bitmap weight",
        _bsdf("blendbsdf", _bitmap("weight", "tex.exr"), ROUGH_PLASTIC, CONDUCTOR),
        independent=("weight.data", "alpha", "eta"),
        composite=True,
    ),
    Case(
        "blendbsdf (diffuse + smooth conductor)",
        _bsdf("blendbsdf", '<float name="weight" value="0.4"/>', DIFFUSE, CONDUCTOR),
        independent=("weight.value",),
        composite=True,
    ),
    Case(
        "blendbsdf (diffuse + roughconductor), children",
        _bsdf("blendbsdf", '<float name="weight" value="0.4"/>', DIFFUSE, ROUGH_CONDUCTOR),
        include=("object.bsdf.bsdf_*",),
        independent=("alpha.value",),
        composite=True,
        ad_spp=1024,
        fd_spp=4096,
    ),
    Case(
        "mask (diffuse)",
        _bsdf("mask", OPACITY, DIFFUSE),
        independent=("opacity.value",),
        composite=True,
    ),  # fmt: skip
    Case(
        "mask (smooth conductor)",
        _bsdf("mask", OPACITY, CONDUCTOR),
        independent=("opacity.value",),
        composite=True,
    ),  # fmt: skip
    Case("twosided (smooth conductor)", _bsdf("twosided", CONDUCTOR), composite=True),
    Case(
        "bumpmap (roughconductor)",
        _bsdf("bumpmap", BUMP, ROUGH_CONDUCTOR),
        independent=("nested_texture.data", "alpha.value"),
        composite=True,
    ),
    Case(
        "bumpmap (smooth conductor)",
        _bsdf("bumpmap", BUMP, CONDUCTOR),
        independent=("nested_texture.data",),
        composite=True,
    ),  # fmt: skip
    Case(
        "normalmap (roughconductor)",
        _bsdf("normalmap", NORMALS, ROUGH_CONDUCTOR),
        independent=("normalmap.data", "alpha.value"),
        composite=True,
    ),
    Case(
        "normalmap (smooth conductor)",
        _bsdf("normalmap", NORMALS, CONDUCTOR),
        independent=("normalmap.data",),
        composite=True,
        ad_spp=256,
        fd_spp=4096,
    ),
    # Media, differentiated by prbvolpath (the scene renders them with volpath).
    Case(
        "homogeneous medium in a null sphere",
        '<bsdf type="null"/><medium type="homogeneous" name="interior">'
        '<rgb name="albedo" value="0.8, 0.7, 0.6"/><float name="sigma_t" value="1.5"/>'
        '<phase type="hg"><float name="g" value="0.3"/></phase></medium>',
        include=("object.interior_medium.*",),
        independent=("sigma_t.value.value", "g"),
        integrator="volpath",
        ad_spp=256,
        fd_spp=4096,
    ),
    Case(
        "heterogeneous medium in a null sphere",
        '<bsdf type="null"/><medium type="heterogeneous" name="interior">'
        '<volume type="gridvolume" name="sigma_t"><string name="filename" value="density.vol"/>'
        '<transform name="to_world"><translate value="-0.5"/><scale value="1.4"/></transform>'
        '</volume><volume type="gridvolume" name="albedo">'
        '<string name="filename" value="albedo.vol"/>'
        '<transform name="to_world"><translate value="-0.5"/><scale value="1.4"/></transform>'
        '</volume><float name="scale" value="1.5"/></medium>',
        include=("object.interior_medium.*",),
        independent=("sigma_t.data",),
        integrator="volpath",
        ad_spp=256,
        fd_spp=4096,
    ),
    Case("area, uniform", include=("light.emitter.*",)),
    Case(
        "area, bitmap",
        lights=AREA.format(radiance=_bitmap("radiance", "tex.exr")),
        include=("light.emitter.*",),
    ),
    Case(
        "point",
        lights=f'<emitter type="point" id="lamp"><point name="position" x="0.5" '
        f'y="2.5" z="2"/>{RGB.format("intensity", "20, 18, 15")}</emitter>',
        include=("lamp.*",),
    ),
    Case(
        "spot, bitmap texture",
        lights=f'<emitter type="spot" id="lamp">{SPOT_AT}'
        f'{RGB.format("intensity", "40, 36, 30")}<float name="cutoff_angle" value="25"/>'
        f"{_bitmap('texture', 'tex.exr')}</emitter>",
        include=("lamp.*",),
    ),
    Case(
        "directional",
        lights='<emitter type="directional" id="sun"><vector name="direction" '
        'x="-0.3" y="-1" z="-0.4"/><rgb name="irradiance" value="3, 2.8, 2.5"/></emitter>',
        include=("sun.*",),
    ),
    Case(
        "constant",
        lights='<emitter type="constant" id="sky">'
        '<rgb name="radiance" value="0.8, 0.9, 1.0"/></emitter>',
        include=("sky.*",),
    ),
    Case(
        "diffuse, reflectance exactly 0 (an area light's default BSDF)",
        include=("light.bsdf.*",),
        kind=False,
    ),
    Case(
        "envmap",
        lights='<emitter type="envmap" id="sky"><string name="filename" '
        'value="sky.exr"/><float name="scale" value="1.5"/></emitter>',
        include=("sky.*",),
    ),
)


def write_case(case: Case, folder: Path) -> Path:
    """The case's scene, its textures and a job selecting its parameters, in ``folder``."""
    rng = np.random.default_rng(1)
    mi = import_mitsuba("llvm_ad_rgb")  # VolumeGrid needs a variant (Bitmap does not)

    mi.Bitmap(0.2 + 0.6 * rng.random((8, 8, 3), dtype=np.float32)).write(str(folder / "tex.exr"))
    tilt = rng.normal(0, 0.25, (8, 8, 2)).astype(np.float32)  # unit normals, tilted at random
    normals = np.concatenate([tilt, np.ones((8, 8, 1), np.float32)], axis=2)
    normals /= np.linalg.norm(normals, axis=2, keepdims=True)
    mi.Bitmap(0.5 + 0.5 * normals).write(str(folder / "normals.exr"))
    sky = 0.3 + rng.random((8, 16, 3), dtype=np.float32)
    sky[1:3, 3:5] = 20.0  # a small sun, so the map is not flat
    mi.Bitmap(sky).write(str(folder / "sky.exr"))
    grid = 0.5 + rng.random((6, 6, 6, 1), dtype=np.float32)  # a heterogeneous medium's density
    mi.VolumeGrid(grid).write(str(folder / "density.vol"))
    mi.VolumeGrid(0.4 + 0.5 * rng.random((6, 6, 6, 3), dtype=np.float32)).write(
        str(folder / "albedo.vol")
    )
    text = STAGE.format(res=RES, bsdf=case.bsdf, lights=case.lights, integrator=case.integrator)
    (folder / "scene.xml").write_text(text)
    job = {
        "version": 1,
        "scene": "scene.xml",
        "variant": "llvm_ad_rgb",
        "render": {"spp": SPP, "max_depth": 5, "seed": 0, "resolution": [RES, RES]},
        "parameters": {"include": list(case.include)},
        "objectives": [{"name": "mean_luma", "type": "mean_luminance"}],
        "output": "out",
    }
    (folder / "job.yaml").write_text(yaml.safe_dump(job, sort_keys=False))
    return folder / "job.yaml"


def label(check: GradientCheck) -> str:
    if check.verdict == "agrees":
        return "verified"
    if check.verdict == "inconclusive":
        return "unverified"
    return "no_gradient" if check.adjoint == 0 else "biased"


Row = tuple[Case, GradientCheck, bool, tuple[Context, ...]]


def measure(case: Case) -> list[Row]:
    with tempfile.TemporaryDirectory(prefix="sensaov-trust-") as tmp:
        job = load_job(write_case(case, Path(tmp)))
        loaded = load_job_scene(job)
        (objective,) = build_objectives(loaded.mi, job.objectives, (RES, RES), False)
        rows = []
        for info in loaded.selected:
            independent = info.key.endswith(case.independent) if case.independent else False
            if independent:
                check = check_parameter(
                    loaded,
                    objective,
                    info,
                    spp=case.ad_spp,
                    fd_spp=case.fd_spp,
                    seeds=list(range(IND_SEEDS)),
                )
            else:
                check = check_parameter(loaded, objective, info, spp=SPP, seeds=list(range(SEEDS)))
            rows.append((case, check, independent, loaded.contexts[info.key]))
        return rows


def row(case: Case, c: GradientCheck, independent: bool, contexts: tuple[Context, ...]) -> str:
    how = (
        f"independent seeds, AD {case.ad_spp} spp, FD {case.fd_spp} spp"
        if independent
        else f"same seed, {SPP} spp"
    )
    seeds = IND_SEEDS if independent else SEEDS
    error = f"{c.relative_error:.1e}" if c.finite_difference else "n/a"
    noise = c.standard_error / max(abs(c.finite_difference), 1e-30)
    prefix = f"{_contexts(contexts)} | " if case.composite else ""
    return (
        f"| {prefix}{c.plugin} | {c.type} | {case.name}: `{c.key}` | {c.adjoint:+.4e} | "
        f"{c.finite_difference:+.4e} | {error} | {noise:.1e} | {how} | {seeds} | {label(c)} |"
    )


def _contexts(contexts: tuple[Context, ...]) -> str:
    return ", ".join(f"{c} {role} ({children})" for c, role, children in contexts) or "none"


def kinds(rows: list[Row]) -> dict[tuple[str, str], str]:
    """Each kind's label: the weakest of its rows outside the composites' cases."""
    worst: dict[tuple[str, str], str] = {}
    for case, check, *_ in rows:
        if not case.kind or case.composite:
            continue
        kind = (check.plugin, check.type)
        labels = [worst.get(kind, "verified"), label(check)]
        worst[kind] = min(labels, key=WORST_FIRST.index)
    return dict(sorted(worst.items()))


def composites(rows: list[Row], kind_labels: dict[tuple[str, str], str]) -> dict[Context, str]:
    """Each context's label: the weakest of the rows in it that are a composite's own parameter
    or whose own kind is verified (a row of a kind known biased says nothing of the composite)."""
    worst: dict[Context, str] = {}
    for case, check, _, contexts in rows:
        kind = (check.plugin, check.type)
        own = kind_labels.get(kind) or (TABLE[kind].trust if kind in TABLE else None)
        if not case.composite or (own != "verified" and check.plugin not in COMPOSITES):
            continue  # (--only: a kind not measured in this run reads as trust.py has it)
        for context in contexts:
            labels = [worst.get(context, "verified"), label(check)]
            worst[context] = min(labels, key=WORST_FIRST.index)
    return dict(sorted(worst.items()))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--only", help="comma-separated case name prefixes")
    args = parser.parse_args()
    wanted = args.only.split(",") if args.only else None
    cases = [c for c in CASES if wanted is None or c.name.startswith(tuple(wanted))]
    start = time.perf_counter()
    rows = []
    for case in cases:
        rows += measure(case)
        print(f"measured {case.name} ({time.perf_counter() - start:.0f} s)", file=sys.stderr)
    today = datetime.date.today().isoformat()
    print(
        f"Measured {today} with `scripts/trust_table.py`: Mitsuba {version('mitsuba')}, "
        f"Dr.Jit {version('drjit')}, llvm_ad_rgb, {RES}x{RES}, M = mean luminance, "
        f"{time.perf_counter() - start:.0f} s on {os.cpu_count()} CPU cores."
    )
    columns = (
        "| plugin | type | case: parameter | adjoint | finite diff. | rel. error | "
        "std. err. (rel.) | method | seeds | label |"
    )
    for kind in (True, False):
        if not kind:
            print("\nConditions the run-time self-checks catch (not evidence for a kind):")
        print(f"\n{columns}\n|---|---|---|---|---|---|---|---|---|---|")
        print("\n".join(row(*r) for r in rows if r[0].kind == kind and not r[0].composite))
    print(
        "\nThe labels, the weakest of each kind's rows:\n\n| plugin | type | label |\n|---|---|---|"
    )
    labels = kinds(rows)
    print("\n".join(f"| {p} | {t} | {lab} |" for (p, t), lab in labels.items()))
    print("\nComposites: each parameter with the composites its gradient passes (role, children):")
    print(f"\n| composites {columns}\n|---|---|---|---|---|---|---|---|---|---|---|")
    print("\n".join(row(*r) for r in rows if r[0].composite))
    print(
        "\nThe composites' labels, the weakest of the rows in each whose own kind is verified:"
        "\n\n| composite | role | children | label |\n|---|---|---|---|"
    )
    for (composite, role, children), lab in composites(rows, labels).items():
        print(f"| {composite} | {role} | {children} | {lab} |")


if __name__ == "__main__":
    main()
