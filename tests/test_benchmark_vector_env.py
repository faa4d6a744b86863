"""benchmarks.speed.vector_env without MJX: its timing loop and its argument checks."""

import pytest

import benchmarks.speed.vector_env


def test_timed_runs_keep_the_warm_up_call_apart():
    calls = []
    first, runs = benchmarks.speed.vector_env.timed_runs(lambda i: calls.append(i), steps=3, repeats=2)
    assert calls == [0, 0, 1, 2, 0, 1, 2] and len(runs) == 2 and first >= 0  # one warm-up call, then 2 runs


@pytest.mark.parametrize("argv", [["--modes", "jit_step,warp"], ["--batches", "0"], ["--steps", "0"]])
def test_bad_arguments_stop_before_anything_is_built(argv):
    with pytest.raises(SystemExit):  # argparse's error
        benchmarks.speed.vector_env.main(argv)
