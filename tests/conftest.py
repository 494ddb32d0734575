"""Shared fixtures: tiny meshes built in code, and the real data when present.

The real TOPKIDS / KIDS data are read from ``$TOPOMATCH_DATA`` or, by default, from
``../shared/data`` beside the project checkout. Tests that need them are marked
``data`` and skip with the reason when the files are absent.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from topomatch.datasets.toy import grid, icosphere, torus

ROOT = Path(__file__).resolve().parents[1]
DATA = Path(os.environ.get("TOPOMATCH_DATA") or ROOT.parent / "shared" / "data")


def data_path(*parts: str) -> Path:
    """A path under the data directory, skipping the test when it is absent."""
    p = DATA.joinpath(*parts)
    if not p.exists():
        pytest.skip(f"data not available: {p} (set TOPOMATCH_DATA to the folder holding topkids/ and kids/)")
    return p


@pytest.fixture(scope="session")
def sphere():
    return icosphere(3)


@pytest.fixture(scope="session")
def small_sphere():
    return icosphere(2)


@pytest.fixture(scope="session")
def donut():
    return torus(24, 12)


@pytest.fixture(scope="session")
def plane():
    return grid(21)


@pytest.fixture()
def rng():
    return np.random.default_rng(0)


@pytest.fixture(scope="session")
def topkids_low():
    from topomatch.datasets.topkids import load_topkids

    data_path("topkids", "low_res", "kid00.off")
    return load_topkids(DATA, "low")


@pytest.fixture(scope="session")
def topkids_high():
    from topomatch.datasets.topkids import load_topkids

    data_path("topkids", "high_res", "kid00.off")
    return load_topkids(DATA, "high")


@pytest.fixture(scope="session")
def builtin():
    from topomatch.datasets.builtin import builtin_benchmark

    return builtin_benchmark()


@pytest.fixture(scope="session")
def report_run(tmp_path_factory):
    """A tiny finished run (built-in data, descriptor-nn and the oracle, both protocols)."""
    from topomatch.evaluation.benchmark import BenchmarkConfig, run_benchmark

    run = tmp_path_factory.mktemp("report") / "run"
    config = BenchmarkConfig(
        dataset="builtin",
        methods=["descriptor-nn", "oracle"],
        protocols=["shrec16", "topkids25"],
        params={"descriptor-nn": {"k": 20, "n_descriptors": 16}},  # small: the fixture is about the run format
    )
    run_benchmark(config, run, progress=False)
    return run
