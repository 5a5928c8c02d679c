"""dask.distributed batch: a LocalCluster with 2 workers gives the serial results."""

import numpy as np
import pytest

pytest.importorskip("dask.distributed")

from experiments.inverse.batch import coverage_task, run_batch  # noqa: E402


def test_local_cluster_results_equal_serial_results():
    seeds = [0, 1, 2]
    serial = run_batch(coverage_task, seeds, workers=0)
    parallel = run_batch(coverage_task, seeds, workers=2, log=lambda *_: None)
    for a, b in zip(serial, parallel):
        assert a["seed"] == b["seed"]
        assert np.allclose(a["x"], b["x"], rtol=1e-12)
        assert np.allclose(a["std"], b["std"], rtol=1e-12)
