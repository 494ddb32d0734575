"""Exact 1-NN in spectral space: ``topomatch.maps.knn.nearest_neighbors`` against the alternatives.

Measures, in one run on this machine, the project's blocked-BLAS nearest neighbours
against faiss's ``IndexFlatL2`` (if installed: ``pip install faiss-cpu``) and scipy's
``cKDTree``, on random data of the sizes ZoomOut and ``deform`` use (1,500 samples;
10K and 60K vertices; d = 30 .. 110), and on real spectral embeddings when
``--data`` is given. Prints the median of ``--repeat`` runs, the ratios to ours, and
how often each backend's neighbour equals the float64 brute-force one (computed where
it fits in memory).

    python benchmarks/bench_knn.py [--data DATA] [--repeat 3] [--large]
"""

from __future__ import annotations

import argparse
import os

import numpy as np
from _common import median_seconds
from scipy.spatial import cKDTree

from topomatch.maps.knn import nearest_neighbors


def _faiss():
    try:
        import faiss
    except ImportError:
        return None

    def run(ref: np.ndarray, qry: np.ndarray) -> np.ndarray:
        index = faiss.IndexFlatL2(ref.shape[1])
        index.add(np.ascontiguousarray(ref, dtype=np.float32))
        return index.search(np.ascontiguousarray(qry, dtype=np.float32), 1)[1][:, 0].astype(np.int64)

    return run


def _exact(ref: np.ndarray, qry: np.ndarray) -> np.ndarray | None:
    if len(ref) * len(qry) > 2e8:
        return None
    out = np.empty(len(qry), dtype=np.int64)
    r2 = np.einsum("ij,ij->i", ref, ref)
    for s in range(0, len(qry), 1000):
        out[s : s + 1000] = np.argmin(r2[None] - 2.0 * qry[s : s + 1000] @ ref.T, axis=1)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--data", default=os.environ.get("TOPOMATCH_DATA"))
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--large", action="store_true", help="also 60K x 60K (high-res size; about a minute per backend)")
    ap.add_argument("--kdtree", action="store_true", help="also scipy's cKDTree (slow in these dimensions)")
    args = ap.parse_args()
    rng = np.random.default_rng(0)
    problems = [(f"random {n} x {n}, d={d}", rng.standard_normal((n, d)), rng.standard_normal((n, d)))
                for n in (1500, 10000) for d in (30, 60, 110)]
    if args.large:
        problems.append(("random 60000 x 60000, d=100", rng.standard_normal((60000, 100)), rng.standard_normal((60000, 100))))
    if args.data:
        from topomatch.datasets.topkids import load_topkids

        coll = load_topkids(args.data, "low")
        e1, e2 = coll["kid00"].mesh.eigenbasis(110).evecs, coll["kid15"].mesh.eigenbasis(110).evecs
        for d in (30, 110):
            C = np.linalg.qr(rng.standard_normal((d, d)))[0]
            problems.append((f"kid00 -> kid15 eigenbasis, d={d}", e1[:, :d] @ C.T, e2[:, :d]))
    backends = {"ours": lambda r, q: nearest_neighbors(r, q)}
    faiss_run = _faiss()
    if faiss_run is not None:
        backends["faiss"] = faiss_run
    if args.kdtree:
        backends["ckdtree"] = lambda r, q: cKDTree(r).query(q, workers=-1)[1]
    print(f"{os.cpu_count()} CPUs; median of {args.repeat}; backends: {', '.join(backends)}")
    for label, ref, qry in problems:
        exact = _exact(ref, qry)
        cells, base = [], None
        for name, fn in backends.items():
            sec, res = median_seconds(lambda fn=fn, ref=ref, qry=qry: fn(ref, qry), args.repeat)
            base = sec if base is None else base
            agree = "" if exact is None else f", {100 * np.mean(res == exact):.3f}% exact"
            cells.append(f"{name} {sec:.3f} s (x{sec / base:.2f}{agree})")
        print(f"{label:36s} " + "; ".join(cells), flush=True)


if __name__ == "__main__":
    main()
