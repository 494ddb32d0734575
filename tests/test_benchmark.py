import json

import numpy as np
import pytest

from topomatch.evaluation.benchmark import BenchmarkConfig, run_benchmark
from topomatch.evaluation.rundir import RunDir
from topomatch.matching import MATCHERS, Correspondence, Matcher


class FailsOnSomePairs(Matcher):
    name = "flaky"

    def __init__(self, *, fail_source: str = "syn08") -> None:
        self.fail_source = fail_source

    def match(self, source, target):
        if source.name == self.fail_source:
            raise RuntimeError("deliberate failure")
        return Correspondence(np.zeros(target.n_vertices, dtype=np.int64))


@pytest.fixture()
def flaky_registered(monkeypatch):
    monkeypatch.setitem(MATCHERS, "flaky", FailsOnSomePairs)


def test_run_is_complete_and_resumable(tmp_path):
    # four pairs per protocol: enough to lose some maps and resume
    cfg = BenchmarkConfig(methods=["oracle", "descriptor-nn"], protocols=["shrec16", "topkids25"], max_pairs=4,
                          params={"descriptor-nn": {"k": 40, "n_descriptors": 20}})
    out = tmp_path / "run"
    s1 = run_benchmark(cfg, out, progress=False)
    ora = s1["methods"]["oracle"]
    assert ora["shrec16"]["auc_mean"] == 1.0 and ora["topkids25"]["mean_error"]["dijkstra"] == 0.0
    assert ora["shrec16"]["n_pairs"] == ora["topkids25"]["n_pairs"] == 4
    for key in ("n_pairs", "mean_error", "auc_mean", "auc_best", "auc_worst", "area_matched", "excluded_fraction", "seconds_per_pair_median", "seconds_per_pair_mean", "seconds_total", "peak_rss_mb"):
        assert key in s1["methods"]["descriptor-nn"]["shrec16"]
    man = json.loads((out / "manifest.json").read_text())
    assert man["versions"]["numpy"] and man["protocols"]["shrec16"]["symmetric"] is True
    assert man["versions"]["cpu"] and int(man["versions"]["cpu_count"]) >= 1
    # kill half way: remove some maps and scores, run again, same numbers
    run = RunDir(out)
    removed = sorted((out / "maps" / "descriptor-nn").glob("*.npz"))[:3]
    for p in removed:
        p.unlink()
    for p in (out / "scores").rglob("descriptor-nn/*.npz"):
        p.unlink()
    s2 = run_benchmark(cfg, out, progress=False)
    a = s1["methods"]["descriptor-nn"]["shrec16"]
    b = s2["methods"]["descriptor-nn"]["shrec16"]
    assert a["auc_mean"] == b["auc_mean"] and a["mean_error"] == b["mean_error"]
    assert all(run.load_map("descriptor-nn", p.stem) is not None for p in removed)
    with pytest.raises(ValueError, match="different configuration"):
        run_benchmark(BenchmarkConfig(methods=["oracle"]), out, progress=False)


def test_failing_pair_is_recorded_not_fatal(tmp_path, flaky_registered):
    cfg = BenchmarkConfig(methods=["flaky"], protocols=["shrec16"])
    s = run_benchmark(cfg, tmp_path / "r", progress=False)
    b = s["methods"]["flaky"]["shrec16"]
    assert b["n_failed"] == 3 and b["n_pairs"] == 9  # 4 test shapes: 12 pairs, 3 with source syn08
    fail = RunDir(tmp_path / "r").load_failure("flaky", "syn07-syn08")
    assert "deliberate failure" in fail["error"] and "Traceback" in fail["traceback"]
    csv_text = (tmp_path / "r" / "pairs.csv").read_text()
    assert "deliberate failure" in csv_text


def test_reproducible_bit_for_bit_and_across_jobs(tmp_path):
    """Same command, same numbers, whatever --jobs is (eigenbases use one BLAS thread)."""
    params = {"descriptor-nn": {"k": 40, "n_descriptors": 20}}
    cfg1 = BenchmarkConfig(methods=["descriptor-nn"], protocols=["topkids25"], split="test", jobs=1, max_pairs=2, params=params)
    cfg2 = BenchmarkConfig(methods=["descriptor-nn"], protocols=["topkids25"], split="test", jobs=2, max_pairs=2, params=params)
    s1 = run_benchmark(cfg1, tmp_path / "a", progress=False)["methods"]["descriptor-nn"]["topkids25"]
    s1b = run_benchmark(cfg1, tmp_path / "a2", progress=False)["methods"]["descriptor-nn"]["topkids25"]
    s2 = run_benchmark(cfg2, tmp_path / "b", progress=False)["methods"]["descriptor-nn"]["topkids25"]
    assert s1["auc_mean"] == s1b["auc_mean"] and s1["mean_error"] == s1b["mean_error"]
    assert s1["auc_mean"] == s2["auc_mean"] and s1["mean_error"] == s2["mean_error"]


def test_config_validation():
    with pytest.raises(ValueError, match="unknown method"):
        BenchmarkConfig(methods=["nope"]).validate()
    with pytest.raises(ValueError, match="dataset"):
        BenchmarkConfig(dataset="faust").validate()


def test_dask_backend(tmp_path):
    distributed = pytest.importorskip("dask.distributed", reason="dask is an optional extra: pip install 'topomatch[dask]'")
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        cfg = BenchmarkConfig(methods=["oracle"], protocols=["shrec16"])
        s = run_benchmark(cfg, tmp_path / "d", progress=False, dask_scheduler=cluster.scheduler_address)
    assert s["methods"]["oracle"]["shrec16"]["auc_mean"] == 1.0
    assert s["methods"]["oracle"]["shrec16"]["n_pairs"] == 12


def test_max_pairs_takes_an_evenly_spaced_subset(tmp_path):
    from topomatch.evaluation.benchmark import subset_pairs
    from topomatch.evaluation.protocols import PairSpec

    pairs = [PairSpec(f"kid{i:02d}", "kid00") for i in range(1, 26)]
    sub = subset_pairs(pairs, 5)
    assert [p.target for p in sub] == ["kid01", "kid07", "kid13", "kid19", "kid25"]
    assert subset_pairs(pairs, 40) == pairs
    with pytest.raises(ValueError, match="max_pairs"):
        BenchmarkConfig(max_pairs=0).validate()
    s = run_benchmark(BenchmarkConfig(methods=["oracle"], protocols=["topkids25"], max_pairs=2), tmp_path / "m", progress=False)
    assert s["methods"]["oracle"]["topkids25"]["n_pairs"] == 2


def test_pair_selection_runs_exactly_the_named_pairs(tmp_path):
    from topomatch.evaluation.benchmark import load_collection
    from topomatch.evaluation.protocols import get_protocol

    cfg = BenchmarkConfig(methods=["oracle"], protocols=["topkids25"])
    all_pairs = get_protocol("topkids25").pairs(load_collection(cfg))
    wanted = [all_pairs[-1].id, all_pairs[0].id]
    s = run_benchmark(BenchmarkConfig(methods=["oracle"], protocols=["topkids25"], pairs=wanted), tmp_path / "p", progress=False)
    assert s["methods"]["oracle"]["topkids25"]["n_pairs"] == 2
    with pytest.raises(ValueError, match="not in the"):
        run_benchmark(BenchmarkConfig(methods=["oracle"], protocols=["topkids25"], pairs=["nosuch-kid00"]), tmp_path / "q", progress=False)
    with pytest.raises(ValueError, match="target"):
        BenchmarkConfig(pairs=["justonename"]).validate()


class CountsPairs(Matcher):
    """Reports how many pairs this object has matched (work shared across pairs)."""

    name = "counter"
    shares_work = True

    def __init__(self) -> None:
        self.seen_: list[str] = []

    def match(self, source, target):
        self.seen_.append(f"{target.name}-{source.name}")
        return Correspondence(np.zeros(target.n_vertices, dtype=np.int64), info={"seen": len(self.seen_)})


def test_matchers_that_share_work_run_in_one_process(tmp_path, monkeypatch):
    monkeypatch.setitem(MATCHERS, "counter", CountsPairs)
    cfg = BenchmarkConfig(methods=["counter"], protocols=["shrec16"], jobs=2, max_pairs=4)
    run_benchmark(cfg, tmp_path / "run", progress=False)
    run = RunDir(tmp_path / "run")
    seen = sorted(json.loads(str(np.load(p)["info"]))["seen"] for p in (tmp_path / "run" / "maps" / "counter").glob("*.npz"))
    assert seen == [1, 2, 3, 4]  # one object saw every pair (worker processes would each see one)
    assert run.path.exists()
