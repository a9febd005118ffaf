"""``abrdf-jax evaluate``: the protocol's metrics (``PROTOCOL.md``) of a reconstruction against a reference."""

from __future__ import annotations

import json
import math

from . import _common as common


def register(sub) -> None:
    e = common.command(
        sub,
        "evaluate",
        run,
        "protocol metrics of a reconstruction",
        "Compare a reconstructed table with a reference (PROTOCOL.md metrics).",
    )
    e.add_argument("rec", metavar="REC", help="reconstructed table (.npz/.exr)")
    e.add_argument("ref", metavar="REF", help="reference table (.npz/.exr); sets the exposure")
    e.add_argument("--json", action="store_true", help="print JSON (non-finite values as null)")


def run(args) -> int:
    from .. import io

    rec = io.read_table(args.rec)  # both read (numpy only) before the metrics import JAX
    ref = io.read_table(args.ref)
    from .. import metrics

    m = {k: float(v) for k, v in metrics.evaluate(rec, ref).items()}
    if args.json:
        doc = {"rec": str(args.rec), "ref": str(args.ref)}
        doc.update({k: v if math.isfinite(v) else None for k, v in m.items()})
        print(json.dumps(doc, indent=2))
    else:
        print(f"{'metric':<8} {'value':>10}")
        for key, label in common.METRICS.items():
            print(f"{label:<8} {m[key]:>10.4g}{' dB' if key == 'psnr' else ''}")
    return 0
