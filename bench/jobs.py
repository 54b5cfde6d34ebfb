"""The inputs the figures run on, generated in a scratch directory (never under scenes/).

Job files are written as YAML next to nothing else of the user's: they point at the scenes in
``scenes/`` by absolute path and write their outputs into the scratch directory.
"""

from __future__ import annotations

import json
import shutil
import struct
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import yaml

REPO = Path(__file__).resolve().parent.parent
SCENES = {name: REPO / "scenes" / name / "scene.xml" for name in ("cbox", "interior")}

MEAN_LUMA = {"name": "mean_luma", "type": "mean_luminance"}
EXTRA_OBJECTIVES = (
    {"name": "centre", "type": "region_luminance", "region": [0.3, 0.2, 0.7, 0.6]},
    {"name": "left_half", "type": "region_luminance", "region": [0.0, 0.0, 0.5, 1.0]},
)
# The channels of configs/cbox.yaml: one of each kind.
CHANNELS = (
    {"name": "objects", "kind": "object"},
    {"name": "types", "kind": "type"},
    {"name": "walls", "kind": "select", "select": "*reflectance*"},
)
OVERHEAD = {"origin": [0.0, 0.9, 3.0], "target": [0.0, -0.4, 0.0], "up": [0.0, 1.0, 0.0]}


@dataclass(frozen=True)
class PlainInputs:
    """What the hand-written script needs: the scene as sensaov loads it, and the keys to free."""

    xml: Path
    resolver: Path  # directory that relative texture names resolve against
    sensor: str
    keys: Path  # JSON list of parameter keys to differentiate
    count: int


class Workspace:
    def __init__(self, root: Path, variant: str):
        self.root = root
        self.variant = variant

    def job(
        self,
        name: str,
        scene: Path,
        *,
        resolution: int,
        spp: int,
        objectives: list[dict[str, Any]] | None = None,
        deterministic: bool = False,
        exclude: tuple[str, ...] = (),
        inspection: tuple[dict[str, Any], ...] = (),
        repair_budget: float = 0.0,
    ) -> Path:
        """Write ``<root>/<name>.yaml`` and return its path; outputs go to ``<root>/out/<name>``.

        Repairs are off unless asked for: the other figures measure the passes they measured
        before repairs existed (figure 1 compares with a script that repairs nothing), and
        figure 15 measures what repairs cost."""
        job: dict[str, Any] = {
            "version": 1,
            "scene": str(scene),
            "variant": self.variant,
            "render": {
                "spp": spp,
                "max_depth": 6,
                "seed": 0,
                "resolution": [resolution, resolution],
                "deterministic": deterministic,
            },
            "parameters": {"include": ["*"], "exclude": list(exclude), "shared": "split"},
            "repair": {"budget": repair_budget},
            "objectives": objectives or [MEAN_LUMA],
            "inspection_cameras": list(inspection),
            "channels": list(CHANNELS),
            "output": str(self.root / "out" / name),
        }
        path = self.root / f"{name}.yaml"
        path.write_text(yaml.safe_dump(job, sort_keys=False))
        return path

    def config_copy(self, name: str, config: Path, **overrides: Any) -> Path:
        """A shipped job (``configs/*.yaml``) as it is, its scene by absolute path, its outputs
        in ``<root>/out/<name>``; ``overrides`` replace top-level keys (``render`` is merged)."""
        job = yaml.safe_load(config.read_text())
        job["scene"] = str((config.parent / job["scene"]).resolve())
        job["output"] = str(self.root / "out" / name)
        job["render"] = {**job.get("render", {}), **overrides.pop("render", {})}
        job.update(overrides)
        path = self.root / f"{name}.yaml"
        path.write_text(yaml.safe_dump(job, sort_keys=False))
        return path

    def textured_cbox(self, size: int) -> Path:
        """A copy of scenes/cbox whose checker wall carries a ``size``² 8-bit RGB texture."""
        folder = self.root / f"cbox_tex{size}"
        if not folder.exists():
            shutil.copytree(SCENES["cbox"].parent, folder)
            write_png(folder / "textures" / f"wall_{size}.png", checker(size))
            xml = folder / "scene.xml"
            text = xml.read_text()
            edited = text.replace('value="textures/wall.png"', f'value="textures/wall_{size}.png"')
            if edited == text:
                raise RuntimeError("scenes/cbox/scene.xml no longer names textures/wall.png")
            xml.write_text(edited)
        return folder / "scene.xml"

    def target_image(self, resolution: int) -> Path:
        """A grey EXR target for an ``l2_to_target`` objective (a non-linear objective)."""
        from sensaov_cli.outputs.exr import write_exr

        path = self.root / f"target_{resolution}.exr"
        if not path.exists():
            grey = np.full((resolution, resolution), 0.25, np.float32)
            write_exr(path, {"R": grey, "G": grey, "B": grey}, {})
        return path

    def plain_inputs(self, job_path: Path) -> PlainInputs:
        """The scene text sensaov renders for ``job_path`` and the keys it differentiates.

        Both sides of figure 1 then do the same work on the same scene; preparing the XML is
        text processing (milliseconds) and is left out of the hand-written side.
        """
        from sensaov_cli.job.load import load_job
        from sensaov_cli.render.loading import load_scene
        from sensaov_cli.scene import prepare_scene

        spec = load_job(job_path)
        prepared = prepare_scene(spec)
        xml = job_path.with_suffix(".prepared.xml")
        xml.write_text(prepared.text)
        loaded = load_scene(prepared, variant=spec.variant, parameters=spec.parameters)
        keys = [info.key for info in loaded.selected]
        keys_path = job_path.with_suffix(".keys.json")
        keys_path.write_text(json.dumps(keys))
        return PlainInputs(xml, spec.scene.parent, prepared.sensor_id, keys_path, len(keys))


def checker(size: int, cells: int = 4) -> np.ndarray:
    """``size``² RGB checker, ``cells`` squares a side, the colours of scenes/make_textures.py."""
    ij = (np.indices((size, size)) * cells) // size
    mask = ((ij[0] + ij[1]) % 2).astype(bool)
    image = np.empty((size, size, 3), np.uint8)
    image[~mask] = (200, 40, 35)
    image[mask] = (235, 215, 190)
    return image


def write_png(path: Path, image: np.ndarray) -> None:
    """An 8-bit RGB PNG with zlib alone (the format users' textures usually come in)."""
    height, width, _ = image.shape
    raw = b"".join(b"\x00" + image[row].tobytes() for row in range(height))

    def chunk(tag: bytes, data: bytes) -> bytes:
        body = tag + data
        return struct.pack(">I", len(data)) + body + struct.pack(">I", zlib.crc32(body))

    header = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header)
    png += chunk(b"IDAT", zlib.compress(raw, 6)) + chunk(b"IEND", b"")
    path.write_bytes(png)
