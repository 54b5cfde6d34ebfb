"""The hand-written baseline of figures 1 and 6: what a user would type without sensaov.

Load the scene, render the primal once without AD, hand dM/dI of the mean Rec. 709 luminance to
prb's ``render_backward``, read the gradients back. No sensaov import: the scene text and the
keys to differentiate are written out beforehand, so both sides do the same work.

    python bench/plain_mitsuba.py scene.xml --resolver DIR --sensor ID --keys keys.json --spp 32
"""

from __future__ import annotations

import argparse
import json

import numpy as np

LUMA = (0.2126, 0.7152, 0.0722)


def parse() -> argparse.Namespace:
    parser = argparse.ArgumentParser(description="hand-written primal + render_backward")
    parser.add_argument("xml")
    parser.add_argument("--resolver", required=True, help="folder relative file names start in")
    parser.add_argument("--sensor", required=True, help="id of the objective sensor")
    parser.add_argument("--keys", required=True, help="JSON list of the keys to differentiate")
    parser.add_argument("--spp", type=int, required=True)
    parser.add_argument("--variant", default="llvm_ad_rgb")
    parser.add_argument("--primal-only", action="store_true", help="stop after the primal")
    return parser.parse_args()


def main() -> None:
    args = parse()
    import drjit as dr
    import mitsuba as mi

    mi.set_variant(args.variant)
    mi.file_resolver().prepend(args.resolver)  # type: ignore[operator]
    scene = mi.load_file(args.xml, optimize=False)
    sensor = next(s for s in scene.sensors() if s.id() == args.sensor)
    integrator = scene.integrator()
    params = mi.traverse(scene)
    keys = json.loads(open(args.keys).read())
    for key in keys:
        dr.enable_grad(params[key])
    params.update()

    with dr.suspend_grad():
        image = integrator.render(scene, sensor, seed=0, spp=args.spp)
    pixels = np.array(image)  # forces the render to finish
    if args.primal_only:
        print(json.dumps({"pixels": int(pixels.size)}))
        return
    height, width, channels = pixels.shape
    weights = np.zeros((height, width, channels), np.float32)
    weights[..., :3] = np.array(LUMA, np.float32) / (height * width)
    integrator.render_backward(
        scene, params, grad_in=mi.TensorXf(weights), sensor=sensor, seed=1, spp=args.spp
    )
    grads = {key: np.array(dr.grad(params[key])) for key in keys}
    print(json.dumps({"params": len(grads), "components": sum(g.size for g in grads.values())}))


if __name__ == "__main__":
    main()
