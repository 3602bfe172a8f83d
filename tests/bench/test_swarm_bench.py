"""``jaxapf bench swarm``: the scaling table's structure on a tiny run (speed is measured, never asserted)."""

import pytest

from jaxapf.bench.swarm import format_swarm_benchmark, run_swarm_benchmark


@pytest.mark.slow
def test_the_swarm_benchmark_reports_every_size():
    result = run_swarm_benchmark(agents=(1, 3), uavs=6, steps=5, horizon=4, iters=3, repeats=1)
    sizes = result["sizes"]
    assert list(sizes) == ["1", "3"] and sizes["1"]["fields"] == 6 and sizes["3"]["fields"] == 2
    for v in sizes.values():
        assert v["run_s"] > 0 and v["us_per_uav_step"] > 0 and v["compile_s"] > 0 and v["alone_us_per_uav_step"] > 0
        assert abs(v["us_per_swarm_step"] - v["us_per_uav_step"] * int(next(k for k in sizes if sizes[k] is v))) < 1e-6
    assert "UAVs" in format_swarm_benchmark(result)
