"""Statistics of TOPKIDS-layout data sets side by side (synthetic vs real).

Usage
-----
    python benchmarks/noise_stats.py LABEL=DIR[:RES] [LABEL=DIR[:RES] ...]

e.g. ``real-low=../shared/data:low real-high=../shared/data:high kids-synth=/tmp/kids_synth
builtin=/tmp/builtin``. For every set (shapes other than kid00): vertex counts,
genus distribution, boundary loops, components, non-manifold edges, % of surface area
flagged unreliable (``_indmap``; "-" when the set has none) and symmetry coverage.
"""

from __future__ import annotations

import sys

import numpy as np

from topomatch.datasets.topkids import load_topkids


def describe(root: str, res: str) -> dict:
    coll = load_topkids(root, res)
    rows = []
    for name in coll.names:
        if name == coll.reference:
            continue
        s = coll[name]
        m = s.mesh
        unrel = None if s.unreliable is None else float((m.vertex_areas * s.unreliable).sum() / m.area)
        rows.append(
            {
                "n": m.n_vertices,
                "genus": m.genus,
                "loops": len(m.boundary_loops),
                "comp": m.n_components,
                "nm": len(m.non_manifold_edges),
                "unrel": unrel,
                "sym": None if s.sym is None else float(np.mean(s.sym >= 0)),
            }
        )
        coll.forget(name)
    return {"shapes": len(rows), "ref_n": coll[coll.reference].n_vertices, "rows": rows}


def rng(vals, fmt="{:.0f}"):
    vals = [v for v in vals if v is not None]
    if not vals:
        return "-"
    return f"{fmt.format(min(vals))} / {fmt.format(float(np.median(vals)))} / {fmt.format(max(vals))}"


def main(argv):
    if not argv:
        print(__doc__)
        return 2
    print("| set | shapes | null verts | verts min/med/max | genus min/med/max | genus values | boundary loops | components | non-manifold edges | unreliable area % min/med/max | sym coverage % min/med/max |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for arg in argv:
        label, rest = arg.split("=", 1)
        root, _, res = rest.partition(":")
        d = describe(root, res or "low")
        r = d["rows"]
        unrel = [None if x["unrel"] is None else 100 * x["unrel"] for x in r]
        sym = [None if x["sym"] is None else 100 * x["sym"] for x in r]
        print(
            f"| {label} | {d['shapes']} | {d['ref_n']} | {rng([x['n'] for x in r])} | {rng([x['genus'] for x in r])} | "
            f"{sorted(x['genus'] for x in r)} | {rng([x['loops'] for x in r])} | {rng([x['comp'] for x in r])} | "
            f"{rng([x['nm'] for x in r])} | {rng(unrel, '{:.1f}')} | {rng(sym, '{:.1f}')} |"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
