"""Do two buffers of one job agree within their standard errors? (scripts/slurm-demo.sh)

Prints, per objective, how many gradient components differ by more than 2 and 3 combined
standard errors (sqrt(se_a² + se_b²)), and the same for each object's signed sum; exits 1 when
more than 10 % of the components lie beyond 3 (normal errors put 0.3 % there; error estimates
from few batches are themselves noisy, hence the margin).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from sensaov_cli.buffer.npz import read_buffer
from sensaov_cli.views.hierarchy import Uncertainty, ranked_groups


def main(first: str, second: str) -> int:
    a, b = read_buffer(Path(first)), read_buffer(Path(second))
    if a.statistics is None or b.statistics is None:
        print("compare: both buffers need statistics (shards or render.batches >= 2)")
        return 2
    worst = 0.0
    for objective in (o.name for o in a.objectives):
        z = []
        for key in a.keys:
            se = np.hypot(a.statistics.stderr[objective][key], b.statistics.stderr[objective][key])
            diff = np.abs(a.grad(objective, key).astype(np.float64) - b.grad(objective, key))
            z.append((diff[se > 0] / se[se > 0]).ravel())
        zs = np.concatenate(z)
        beyond3 = float(np.mean(zs > 3))
        worst = max(worst, beyond3)
        zo = []
        for keys in ranked_groups(a)["object"].values():
            sums, errors = [], []
            for buf in (a, b):
                noise = Uncertainty(buf, objective, "sum", "value")
                signed = noise.batch_values(keys, 0.0)[1]
                sums.append(float(np.average(signed, weights=noise.spp)))
                errors.append(noise.error(keys, 0.0).signed_se)
            se = float(np.hypot(*errors))
            if se > 0:
                zo.append(abs(sums[0] - sums[1]) / se)
        print(
            f"{objective}: M {a.objective(objective).value:.5f} vs "
            f"{b.objective(objective).value:.5f}; "
            f"{len(zs)} components: {100 * np.mean(zs > 2):.1f} % beyond 2 SE, "
            f"{100 * beyond3:.1f} % beyond 3 SE (normal: 4.6 %, 0.3 %); "
            f"object signed sums: max {max(zo, default=0.0):.2f} SE over {len(zo)} objects"
        )
    print("compare: agree within the standard errors" if worst <= 0.10 else "compare: DISAGREE")
    return 0 if worst <= 0.10 else 1


if __name__ == "__main__":
    sys.exit(main(*sys.argv[1:3]))
