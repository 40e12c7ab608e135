"""bench/method_timer.py: the seconds that bench_dataset.py and bench_dataset_hair.py
split a sample's time into (the render call, the labels, the groom, ...)."""

from __future__ import annotations

import importlib.util
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def timer_module():
    spec = importlib.util.spec_from_file_location("method_timer",
                                                  ROOT / "bench" / "method_timer.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_wrapped_methods_are_timed_per_name_and_reset_by_take(timer_module):
    class Owner:
        def slow(self, x):
            time.sleep(0.05)
            return 2 * x

        def fails(self):
            time.sleep(0.02)
            raise ValueError("kept")

    timer = timer_module.MethodTimer()
    orig = timer.wrap(Owner, "slow")
    timer.wrap(Owner, "fails", "failing")
    assert orig is not Owner.slow and orig(Owner(), 1) == 2   # the original, returned
    o = Owner()
    assert o.slow(3) == 6 and o.slow(4) == 8                  # results pass through
    with pytest.raises(ValueError, match="kept"):             # and exceptions, timed too
        o.fails()
    got = timer.take()
    assert set(got) == {"slow", "failing"}
    assert 0.1 <= got["slow"] < 1.0 and 0.02 <= got["failing"] < 0.5
    assert timer.take() == {}                                 # take resets the totals
    o.slow(0)
    assert set(timer.take()) == {"slow"}


def test_a_cpu_clock_counts_work_not_waits(timer_module):
    """MethodTimer(clock=time.process_time): CPU seconds, so a sleep counts ~0 and a busy
    loop about its wall time."""
    class Owner:
        def sleeps(self):
            time.sleep(0.1)

        def spins(self):  # 0.1 s of arithmetic on this thread
            t0, n = time.perf_counter(), 0
            while time.perf_counter() - t0 < 0.1:
                n += 1
            return n

    timer = timer_module.MethodTimer(clock=time.process_time)
    timer.wrap(Owner, "sleeps")
    timer.wrap(Owner, "spins")
    o = Owner()
    o.sleeps()
    assert o.spins() > 0
    got = timer.take()
    assert got["sleeps"] < 0.03 and 0.05 < got["spins"] < 0.5
