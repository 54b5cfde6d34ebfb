"""Hostile changes to a finished project, for the bad-input corpus (test_bad_inputs.py).

A workspace is what a user has after ``run``, ``project --png`` and two farm shards of a tiny
cbox job: ``job.yaml``, ``scene/`` (the scene and its texture), ``out/`` (buffer, primal, camera
EXRs, previews) and ``shards/`` (two shards and their primals). Each case copies it, breaks one
thing the way the issue's classes describe (an output onto an input, a special file, shard
metadata, a corrupt EXR, an odd command-line value, a memory setting...) and returns the
command line; the test asserts exit 2 (or the case's code), one line, nothing written.
"""

from __future__ import annotations

import io
import json
import os
import shutil
import struct
import zipfile
import zlib
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from .conftest import SCENES
from .conftest import sensaov as run_command

SHARD = "shards/buffer.shard-{}-of-2.npz"
SHARD_PRIMAL = "shards/primal.shard-{}-of-2.exr"
JOB = {
    "version": 1,
    "scene": "scene/scene.xml",
    "variant": "llvm_ad_rgb",
    "render": {"spp": 2, "max_depth": 2, "seed": 0, "resolution": [16, 16]},
    "objectives": [{"name": "m", "type": "mean_luminance"}],
    "inspection_cameras": [
        {"name": "objective", "objective": True},
        {
            "name": "cam",
            "look_at": {"origin": [0, 0, 3.9], "target": [0, 0, 0], "up": [0, 1, 0]},
            "resolution": [16, 16],
            "vis_spp": 4,
        },
    ],
    "channels": [{"name": "objects", "kind": "object"}],
    "output": "out",
}


@dataclass(frozen=True)
class Hostile:
    id: str
    build: Callable[[Path], list[str]]  # breaks the copied workspace, returns the arguments
    codes: tuple[int, ...] = (2,)
    env: dict[str, str] = field(default_factory=dict)
    stdout: str = "pipe"  # "closed": >&-; "gone": a pipe whose reader has exited
    timeout: float = 60


def sensaov(folder: Path, *args: str) -> None:
    done = run_command(*args, cwd=folder)
    assert done.returncode == 0, done.stderr


def make_workspace(root: Path) -> Path:
    """The finished project every case starts from (~8 s: one run, one project, two shards)."""
    shutil.copytree(SCENES / "cbox", root / "scene")
    write_job(root, JOB)
    write_job(root, {**JOB, "output": "shards"}, "job_shards.yaml")
    sensaov(root, "run", "-q", "job.yaml")
    sensaov(root, "project", "-q", "--png", "job.yaml")
    for index in (1, 2):
        sensaov(root, "run", "-q", "--shard", f"{index}/2", "job_shards.yaml")
    return root


def write_job(root: Path, job: dict, name: str = "job.yaml") -> Path:
    (root / name).write_text(yaml.safe_dump(job, sort_keys=False))
    return root / name


# --- hostile files -----------------------------------------------------------------------


def png_declaring(width: int, height: int) -> bytes:
    """A small, valid-looking PNG whose header declares ``width`` x ``height`` RGB pixels."""

    def chunk(kind: bytes, body: bytes) -> bytes:
        crc = zlib.crc32(kind + body) & 0xFFFFFFFF
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", crc)

    header = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    data = zlib.compress(b"\0" + b"\x80" * 3 * min(width, 4096))
    return (
        b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", data) + chunk(b"IEND", b"")
    )


def jpeg_declaring(width: int, height: int) -> bytes:
    """A JPEG's start and baseline frame header declaring ``width`` x ``height``, 3 channels."""
    frame = struct.pack(">BHHB", 8, height, width, 3) + bytes.fromhex("011100021100031100")
    return b"\xff\xd8\xff\xc0" + struct.pack(">H", len(frame) + 2) + frame + b"\xff\xd9"


def exr_declaring(source: Path, target: Path, width: int, height: int) -> None:
    """A copy of an EXR whose header's data window claims ``width`` x ``height`` pixels."""
    data = bytearray(source.read_bytes())
    at = data.index(b"dataWindow\0box2i\0") + len(b"dataWindow\0box2i\0") + 4
    data[at : at + 16] = struct.pack("<iiii", 0, 0, width - 1, height - 1)
    target.write_bytes(bytes(data))


def exr_with_header(source: Path, target: Path, edit: Callable[[dict], None]) -> None:
    """``source`` rewritten with its header (strings) edited, channels as they were."""
    import OpenEXR

    with OpenEXR.File(str(source), separate_channels=True) as exr:
        header = dict(exr.header())
        channels = {n: np.array(c.pixels) for n, c in exr.channels().items()}
    edit(header)
    header = {k: v for k, v in header.items() if k in ("compression", "type") or "/" in k}
    with OpenEXR.File(header, channels) as exr:
        exr.write(str(target))


def exr_without(source: Path, target: Path, channel: str) -> None:
    import OpenEXR

    with OpenEXR.File(str(source), separate_channels=True) as exr:
        header = {k: v for k, v in dict(exr.header()).items() if "/" in k}
        channels = {n: np.array(c.pixels) for n, c in exr.channels().items() if n != channel}
    with OpenEXR.File(header, channels) as exr:
        exr.write(str(target))


def small_exr(target: Path, size: int) -> None:
    import OpenEXR

    pixels = {name: np.full((size, size), 0.5, np.float32) for name in "RGB"}
    with OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION}, pixels) as exr:
        exr.write(str(target))


def edit_provenance(path: Path, edit: Callable[[dict], None]) -> None:
    """Rewrite a buffer with its provenance edited (the header member is JSON text)."""
    with zipfile.ZipFile(path) as zf:
        members = [(info.filename, zf.read(info)) for info in zf.infolist()]
    with zipfile.ZipFile(path, "w") as zf:
        for name, data in members:
            if name == "header.npy":
                header = json.loads(str(np.load(io.BytesIO(data))[()]))
                edit(header["provenance"])
                stream = io.BytesIO()
                np.lib.format.write_array(stream, np.array(json.dumps(header)))
                data = stream.getvalue()
            zf.writestr(name, data)


def shard_edit(edit: Callable[[dict], None]) -> Callable[[Path], list[str]]:
    def build(ws: Path) -> list[str]:
        edit_provenance(ws / SHARD.format(2), edit)
        return merge(ws)

    return build


def merge(ws: Path, output: str = "merged.npz") -> list[str]:
    return ["merge", "-q", str(ws / SHARD.format(1)), str(ws / SHARD.format(2)), "-o", output]


def fifo(path: Path) -> Path:
    path.unlink(missing_ok=True)
    os.mkfifo(path)
    return path


def link(path: Path, target: str) -> Path:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path)
    else:
        path.unlink(missing_ok=True)
    path.symlink_to(target)
    return path


def scene_with(ws: Path, old: str, new: str) -> None:
    scene = ws / "scene" / "scene.xml"
    text = scene.read_text()
    assert old in text
    scene.write_text(text.replace(old, new, 1))


GREEN = '<bsdf type="diffuse" id="green">'  # a line of cbox's scene.xml to add things before


def with_include(ws: Path, name: str) -> None:
    scene_with(ws, GREEN, f'<include filename="{name}"/>{GREEN}')


def with_mesh(ws: Path, name: str) -> None:
    shape = f'<shape type="ply" id="mesh"><string name="filename" value="{name}"/></shape>'
    scene_with(ws, GREEN, shape + GREEN)


def with_job(ws: Path, **changes: object) -> None:
    write_job(ws, {**JOB, **changes})


def camera(vis_spp: int, size: int) -> dict:
    return {
        "name": "big",
        "look_at": JOB["inspection_cameras"][1]["look_at"],
        "resolution": [size, size],
        "vis_spp": vis_spp,
    }


def run_here(ws: Path) -> None:
    """Render the copied workspace's buffer again, so its provenance names the copy's files."""
    sensaov(ws, "run", "-q", "job.yaml")


def _rank_exr(make: Callable[[Path, Path], None]) -> Callable[[Path], list[str]]:
    def build(ws: Path) -> list[str]:
        make(ws / "out" / "cam.exr", ws / "bad.exr")
        return [
            "rank",
            str(ws / "out" / "buffer.npz"),
            "--by",
            "object",
            "--exr",
            str(ws / "bad.exr"),
        ]

    return build


def _report_o(target: str) -> Callable[[Path], list[str]]:
    return lambda ws: ["report", "job.yaml", "-o", target]


def _texture_fifo(command: str) -> Callable[[Path], list[str]]:
    def build(ws: Path) -> list[str]:
        fifo(ws / "scene" / "textures" / "wall.png")
        return [command, "job.yaml"] if command != "run" else ["run", "-q", "job.yaml"]

    return build


def _merge_after(
    step: Callable[[Path], object], output: str = "merged.npz"
) -> Callable[[Path], list[str]]:
    def build(ws: Path) -> list[str]:
        step(ws)
        return merge(ws, output)

    return build


def _shards_here(ws: Path) -> None:
    """Render the copy's shards again, so their provenance names the copy's scene files."""
    for index in (1, 2):
        sensaov(ws, "run", "-q", "--shard", f"{index}/2", "job_shards.yaml")


def _then(*steps: Callable[[Path], object], args: list[str]) -> Callable[[Path], list[str]]:
    def build(ws: Path) -> list[str]:
        for step in steps:
            step(ws)
        return list(args)

    return build


BUFFER = "out/buffer.npz"
RANK = ["rank", BUFFER]
VIEW = ["view", "-q", "job.yaml", "--port", "0"]  # refused before it serves

# By the classes; "(new)" marks the cases this round invented beyond the text.
HOSTILE = [
    # 1. an output onto an input of the job, the command or the scene
    Hostile("report -o the buffer", _report_o(BUFFER)),
    Hostile("report -o the job file", _report_o("job.yaml")),
    Hostile("report -o a scene texture", _report_o("scene/textures/wall.png")),
    Hostile("report -o the primal", _report_o("out/primal.exr")),
    Hostile("report -o the scene XML", _report_o("scene/scene.xml")),
    Hostile("report -o a camera EXR (new)", _report_o("out/cam.exr")),
    Hostile("report -o a preview it embeds (new)", _report_o("out/previews/cam_m.png")),
    Hostile(
        "report -o a link to the buffer (new)",
        _then(lambda ws: link(ws / "r.html", BUFFER), args=["report", "job.yaml", "-o", "r.html"]),
    ),
    Hostile("merge -o the scene XML", _merge_after(_shards_here, "scene/scene.xml"), timeout=90),
    Hostile("merge -o a shard", lambda ws: merge(ws, SHARD.format(2))),
    Hostile(
        "merge -o the shards' job file (new)",
        _merge_after(_shards_here, "job_shards.yaml"),
        timeout=90,
    ),
    Hostile("sunburst -o the buffer", lambda ws: ["sunburst", BUFFER, "-o", BUFFER]),
    Hostile(
        "sunburst -o a scene texture",
        _then(run_here, args=["sunburst", BUFFER, "-o", "scene/textures/wall.png"]),
    ),
    Hostile(
        "sunburst -o a hard link to the job (new)",
        _then(
            run_here,
            lambda ws: os.link(ws / "job.yaml", ws / "s.svg"),
            args=["sunburst", BUFFER, "-o", "s.svg"],
        ),
    ),
    Hostile(
        "merge -o the scene's texture, named by the shards (new)",
        _merge_after(_shards_here, "scene/textures/wall.png"),
        timeout=90,
    ),
    # 2. special files: refused in one line before anything renders
    Hostile("texture is a FIFO: validate", _texture_fifo("validate"), timeout=20),
    Hostile("texture is a FIFO: params", _texture_fifo("params"), timeout=20),
    Hostile("texture is a FIFO: run", _texture_fifo("run"), timeout=20),
    Hostile(
        "include is a FIFO",
        _then(
            lambda ws: with_include(ws, "inc.xml"),
            lambda ws: fifo(ws / "scene" / "inc.xml"),
            args=["validate", "job.yaml"],
        ),
        timeout=20,
    ),
    Hostile(
        "include is /dev/zero",
        _then(
            lambda ws: with_include(ws, "inc.xml"),
            lambda ws: link(ws / "scene" / "inc.xml", "/dev/zero"),
            args=["validate", "job.yaml"],
        ),
        timeout=20,
    ),
    Hostile(
        "include is a directory (new)",
        _then(
            lambda ws: with_include(ws, "inc.xml"),
            lambda ws: (ws / "scene" / "inc.xml").mkdir(),
            args=["validate", "job.yaml"],
        ),
    ),
    Hostile(
        "mesh is a FIFO (new)",
        _then(
            lambda ws: with_mesh(ws, "mesh.ply"),
            lambda ws: fifo(ws / "scene" / "mesh.ply"),
            args=["run", "-q", "job.yaml"],
        ),
        timeout=20,
    ),
    Hostile(
        "texture is a loop of links (new)",
        _then(
            lambda ws: link(ws / "scene" / "textures" / "wall.png", "wall.png"),
            args=["validate", "job.yaml"],
        ),
    ),
    Hostile(
        "a FIFO among the previews",
        _then(lambda ws: fifo(ws / "out" / "previews" / "zz.png"), args=["report", "job.yaml"]),
        timeout=20,
    ),
    Hostile(
        "primal.exr is a FIFO (new)",
        _then(lambda ws: fifo(ws / "out" / "primal.exr"), args=["report", "job.yaml"]),
        timeout=20,
    ),
    Hostile(
        "camera EXR is a FIFO (new)",
        _then(lambda ws: fifo(ws / "bad.exr"), args=[*RANK, "--by", "object", "--exr", "bad.exr"]),
        timeout=20,
    ),
    Hostile(
        "a shard's primal is a FIFO (new)",
        _merge_after(lambda ws: fifo(ws / SHARD_PRIMAL.format(2))),
        timeout=20,
    ),
    Hostile(
        "scene XML over 256 MiB (new)",
        _then(
            lambda ws: with_include(ws, "big.xml"),
            lambda ws: os.truncate(_touch(ws / "scene" / "big.xml"), 300 << 20),
            args=["validate", "job.yaml"],
        ),
    ),
    Hostile(
        "job file over 16 MiB (new)",
        _then(
            lambda ws: os.truncate(_touch(ws / "huge.yaml"), 17 << 20),
            args=["validate", "huge.yaml"],
        ),
    ),
    Hostile(
        "view: texture is a FIFO (new)",
        _then(lambda ws: fifo(ws / "scene" / "textures" / "wall.png"), args=VIEW),
        timeout=20,
    ),
    Hostile(
        "view: the buffer is a FIFO (new)",
        _then(lambda ws: fifo(ws / BUFFER), args=VIEW),
        timeout=20,
    ),
    Hostile("view: --buffer is a directory (new)", lambda ws: [*VIEW, "--buffer", "scene"]),
    # 6. closed pipes: refused before any work
    Hostile("rank with stdout closed", lambda ws: list(RANK), stdout="closed"),
    Hostile("schema with stdout closed", lambda ws: ["schema"], stdout="closed"),
    Hostile(
        "run into a pipe nobody reads (new)", lambda ws: ["run", "-q", "job.yaml"], stdout="gone"
    ),
    Hostile(
        "rank --json into a pipe nobody reads (new)", lambda ws: [*RANK, "--json"], stdout="gone"
    ),
    Hostile("view with stdout closed (new)", lambda ws: list(VIEW), stdout="closed"),
    # 7. output folders that lead nowhere
    Hostile(
        "output folder is a dangling link",
        _then(lambda ws: link(ws / "out", "nowhere"), args=["run", "-q", "job.yaml"]),
    ),
    Hostile(
        "output folder is a loop of links",
        _then(lambda ws: link(ws / "out", "out"), args=["run", "-q", "job.yaml"]),
    ),
    Hostile(
        "report -o into a dangling folder (new)",
        _then(lambda ws: link(ws / "d", "nowhere"), args=["report", "job.yaml", "-o", "d/r.html"]),
    ),
    Hostile(
        "sunburst -o into a loop (new)",
        _then(lambda ws: link(ws / "d", "d"), args=["sunburst", BUFFER, "-o", "d/s.svg"]),
    ),
    # 8. shard metadata merge relies on
    Hostile("shard: task.shard missing keys", shard_edit(lambda p: p["task"].update(shard={}))),
    Hostile(
        "shard: index not an integer", shard_edit(lambda p: p["task"]["shard"].update(index="2"))
    ),
    Hostile("shard: index out of range", shard_edit(lambda p: p["task"]["shard"].update(index=3))),
    Hostile("shard: index 0 (new)", shard_edit(lambda p: p["task"]["shard"].update(index=0))),
    Hostile(
        "shard: count a float (new)", shard_edit(lambda p: p["task"]["shard"].update(count=2.0))
    ),
    Hostile("shard: spp 0", shard_edit(lambda p: p.update(spp=0))),
    Hostile("shard: spp says twice its share (new)", shard_edit(lambda p: p.update(spp=2))),
    Hostile("shard: spp 2^31 (new)", shard_edit(lambda p: p.update(spp=2**31))),
    Hostile("shard: job_spp missing (new)", shard_edit(lambda p: p.pop("job_spp"))),
    Hostile("shard: no primal_seed (new)", shard_edit(lambda p: p.pop("primal_seed"))),
    Hostile("shard: task missing (new)", shard_edit(lambda p: p.pop("task"))),
    Hostile(
        "shard: job.objectives missing (new)", shard_edit(lambda p: p["job"].pop("objectives"))
    ),
    Hostile(
        "shard: a primal of another size",
        _merge_after(lambda ws: small_exr(ws / SHARD_PRIMAL.format(2), 8)),
    ),
    # 9. corrupt EXR inputs and Cryptomatte manifests
    Hostile("shard primal truncated", _merge_after(lambda ws: _cut(ws / SHARD_PRIMAL.format(2)))),
    Hostile(
        "primal.exr truncated",
        _then(lambda ws: _cut(ws / "out" / "primal.exr"), args=["report", "job.yaml"]),
    ),
    Hostile(
        "manifest not JSON", _rank_exr(lambda s, t: exr_with_header(s, t, _manifest("{not json")))
    ),
    Hostile(
        "manifest a JSON list (new)",
        _rank_exr(lambda s, t: exr_with_header(s, t, _manifest("[1, 2]"))),
    ),
    Hostile(
        "manifest IDs that are no hash of their names (new)",
        _rank_exr(lambda s, t: exr_with_header(s, t, _manifest('{"left_wall": "zzzzzzzz"}'))),
    ),
    Hostile(
        "manifest: two names, one ID (new)",
        _rank_exr(
            lambda s, t: exr_with_header(
                s, t, _manifest('{"left_wall": "3f800000", "floor": "3f800000"}')
            )
        ),
    ),
    Hostile(
        "Cryptomatte coverage channel missing (new)",
        _rank_exr(lambda s, t: exr_without(s, t, "CryptoObject00.G")),
    ),
    Hostile(
        "camera EXR is a PNG (new)",
        _rank_exr(lambda s, t: shutil.copy(s.parent / "previews" / "cam_m.png", t)),
    ),
    # 10. odd command-line values: one line, exit 2
    Hostile("--shard with a superscript digit", lambda ws: ["run", "job.yaml", "--shard", "²/2"]),
    Hostile(
        "--shard with Arabic-Indic digits (new)", lambda ws: ["run", "job.yaml", "--shard", "١/٢"]
    ),
    Hostile("--shard 0/0 (new)", lambda ws: ["run", "job.yaml", "--shard", "0/0"]),
    Hostile("--shard 3/2 (new)", lambda ws: ["run", "job.yaml", "--shard", "3/2"]),
    Hostile("--top 0", lambda ws: [*RANK, "--top", "0"]),
    Hostile("a missing argument", lambda ws: ["rank"]),
    Hostile("an unknown command", lambda ws: ["nosuch"]),
    Hostile("--beauty-spp -1 (new)", lambda ws: ["project", "job.yaml", "--beauty-spp", "-1"]),
    Hostile(
        "--beauty-spp 2^32 (new)", lambda ws: ["project", "job.yaml", "--beauty-spp", str(2**32)]
    ),
    Hostile("--by nonsense (new)", lambda ws: [*RANK, "--by", "nonsense"]),
    Hostile("an unknown option (new)", lambda ws: [*RANK, "--bogus"]),
    # 11. previews that lead nowhere
    Hostile(
        "previews is a dangling link",
        _then(
            lambda ws: link(ws / "out" / "previews", "nowhere"),
            args=["project", "-q", "--png", "job.yaml"],
        ),
    ),
    Hostile(
        "previews is a loop of links (new)",
        _then(
            lambda ws: link(ws / "out" / "previews", "previews"),
            args=["project", "-q", "--png", "job.yaml"],
        ),
    ),
    # 12. memory: settings and declared sizes against the budget, before allocating
    Hostile(
        "vis_spp of a billion",
        _then(
            lambda ws: with_job(ws, inspection_cameras=[camera(10**9, 256)]),
            args=["validate", "job.yaml"],
        ),
    ),
    Hostile(
        "a PNG texture declaring 40000x40000",
        _then(
            lambda ws: (ws / "scene" / "textures" / "wall.png").write_bytes(
                png_declaring(40000, 40000)
            ),
            args=["validate", "job.yaml"],
        ),
    ),
    Hostile(
        "a JPEG texture declaring 65000x65000 (new)",
        _then(
            lambda ws: (ws / "scene" / "textures" / "wall.png").write_bytes(
                jpeg_declaring(65000, 65000)
            ),
            args=["validate", "job.yaml"],
        ),
    ),
    Hostile(
        "an EXR texture declaring 100000x100000 (new)",
        _then(
            lambda ws: exr_declaring(
                ws / "out" / "primal.exr", ws / "scene" / "textures" / "wall.exr", 100000, 100000
            ),
            lambda ws: scene_with(ws, "textures/wall.png", "textures/wall.exr"),
            args=["validate", "job.yaml"],
        ),
    ),
    Hostile(
        "a PLY declaring four billion vertices (new)",
        _then(
            lambda ws: with_mesh(ws, "mesh.ply"),
            lambda ws: (ws / "scene" / "mesh.ply").write_text(_BILLION_PLY),
            args=["validate", "job.yaml"],
        ),
    ),
    Hostile(
        "a camera EXR declaring 100000x100000 (new)",
        _rank_exr(lambda s, t: exr_declaring(s, t, 100000, 100000)),
    ),
    Hostile(
        "render.spp over a small budget (new)",
        _then(
            lambda ws: with_job(ws, render={**JOB["render"], "resolution": [512, 512]}),
            args=["run", "-q", "job.yaml"],
        ),
        env={"SENSAOV_MEMORY_BUDGET": "16M"},
    ),
    Hostile(
        "view over a small memory budget (new)",
        lambda ws: list(VIEW),
        env={"SENSAOV_MEMORY_BUDGET": "1M"},
    ),
    Hostile(
        "a memory budget that is not a size (new)",
        lambda ws: ["run", "-q", "job.yaml"],
        env={"SENSAOV_MEMORY_BUDGET": "banana"},
    ),
    # Low: NaN and infinities in the scene; exit 2 means nothing was written
    Hostile(
        "a NaN texel in an EXR texture",
        _then(
            lambda ws: _nan_exr(ws / "scene" / "textures" / "wall.exr"),
            lambda ws: scene_with(ws, "textures/wall.png", "textures/wall.exr"),
            args=["run", "-q", "job.yaml"],
        ),
    ),
    Hostile(
        "NaN in an rgb value",
        _then(
            lambda ws: scene_with(ws, "0.105421, 0.37798, 0.076425", "nan, 0.3, 0.1"),
            args=["validate", "job.yaml"],
        ),
    ),
]

_BILLION_PLY = (
    "ply\nformat binary_little_endian 1.0\nelement vertex 4000000000\nproperty float x\n"
    "property float y\nproperty float z\nend_header\n"
)


def _touch(path: Path) -> Path:
    path.write_bytes(b"")
    return path


def _cut(path: Path) -> None:
    data = path.read_bytes()
    path.write_bytes(data[: len(data) * 2 // 3])


def _manifest(text: str) -> Callable[[dict], None]:
    def edit(header: dict) -> None:
        key = next(k for k, v in header.items() if k.endswith("/name") and v == "CryptoObject")
        header[key.removesuffix("name") + "manifest"] = text

    return edit


def _nan_exr(path: Path) -> None:
    import OpenEXR

    pixels = np.full((8, 8, 3), 0.5, np.float32)
    pixels[2, 3, 1] = np.nan
    with OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION}, {"RGB": pixels}) as exr:
        exr.write(str(path))
