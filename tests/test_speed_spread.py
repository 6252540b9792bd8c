"""Speeds are medians of repeated timings, with min and max, timed until one noisy call
cannot move the median by more than 10 %; the reports state the real settings."""

from __future__ import annotations

import numpy as np
import pytest

from sparse_brdf.benchmark.charts import speed_accuracy_figure
from sparse_brdf.benchmark.report import speed_settings, summary_table
from sparse_brdf.benchmark.speed import SETTLE, Rate, settled, timed_rate


class NoisyClock:
    """A fake clock: each timed call takes ``base`` seconds times a random factor in
    [1 - jitter, 1 + jitter]; the calls listed in ``spikes`` take ``spike`` times longer
    (the machine was busy), others listed in ``dips`` ``dip`` times shorter."""

    def __init__(self, base=0.01, jitter=0.03, spikes=(), spike=50.0, dips=(), dip=0.02,
                 seed=0):
        self.now, self.base, self.jitter = 0.0, base, jitter
        self.spikes, self.spike, self.dips, self.dip = set(spikes), spike, set(dips), dip
        self.rng, self.reads, self.calls = np.random.default_rng(seed), 0, 0

    def __call__(self) -> float:
        self.reads += 1
        if self.reads % 2 == 0:  # the stop of a timed call: its duration passes
            factor = 1 + self.rng.uniform(-self.jitter, self.jitter)
            factor *= self.spike if self.calls in self.spikes else 1.0
            factor *= self.dip if self.calls in self.dips else 1.0
            self.now += self.base * factor
            self.calls += 1
        return self.now


def _work():
    return lambda: None


def _true_rate(n=1000, base=0.01):
    return n / base


@pytest.mark.parametrize("spike_at", [0, 2, 4])
def test_one_noisy_call_moves_the_median_by_under_10_percent(spike_at):
    """A call 50 times too slow (or 50 times too fast) anywhere among the timed calls
    moves the median rate by less than 10 %, while min or max show it."""
    slow = timed_rate(_work, 1000, repeats=5, clock=NoisyClock(spikes=[spike_at]))
    fast = timed_rate(_work, 1000, repeats=5, clock=NoisyClock(dips=[spike_at]))
    assert slow.min < _true_rate() / 10 and fast.max > _true_rate() * 10  # in the spread
    for rate in (slow, fast):
        assert abs(rate.median / _true_rate() - 1) < 0.10, rate
        assert rate.min <= rate.median <= rate.max and rate.repeats >= 5 and rate.settled


def test_noisy_timings_are_repeated_until_the_median_settles():
    """With +-40 % noise on every call, five timings do not settle the median: more are
    timed, until no single value could move it by more than SETTLE."""
    clock = NoisyClock(jitter=0.4, seed=3)
    rate = timed_rate(_work, 1000, repeats=5, clock=clock)
    assert rate.repeats > 5 and rate.repeats % 2 == 1 and rate.settled
    assert clock.calls == rate.repeats  # the warm-up call is not timed
    # the guarantee itself: replace any one timing by anything, the median moves < 10 %
    rates = np.array(_rates(rate.repeats, jitter=0.4, seed=3))
    assert settled(rates)
    for i in range(len(rates)):
        for extreme in (1e-9, 1e12):
            moved = np.median(np.r_[rates[:i], extreme, rates[i + 1:]])
            assert abs(moved / np.median(rates) - 1) <= SETTLE + 1e-12


def _rates(count, jitter, seed, n=1000):
    clock = NoisyClock(jitter=jitter, seed=seed)
    out = []
    for _ in range(count):
        t0 = clock()
        out.append(n / (clock() - t0))
    return out


def test_a_timer_that_never_settles_stops_and_says_so():
    rate = timed_rate(_work, 1000, repeats=5, clock=NoisyClock(jitter=0.95, seed=1),
                      max_repeats=7)
    assert rate.repeats == 7 and not rate.settled


def test_settled_needs_an_odd_count_of_close_neighbours():
    assert settled([1.0, 1.05, 0.97])
    assert not settled([1.0, 1.05])  # even: the median is no single timing
    assert not settled([1.0, 1.2, 0.97])


def _results(speed_evals, spread):
    cell = {"material": "m/a", "model": "naive", "status": "finished", "bytes": 8,
            "rae": 0.1, "cos_snr": 30.0, "gamma_mse": 0.0, "fit_s": 0.1}
    return {"config": {"speed": True, "speed_evals": speed_evals}, "cells": {"m/a|naive": cell},
            "speed": {"naive": 2e7}, "speed_spread": {"naive": spread}}


def test_reports_state_the_real_speed_settings():
    spread = Rate(2e7, 1.5e7, 2.2e7, 9, 4096, True).spread()
    text = speed_settings(_results(4096, spread))
    assert "2^12 random direction pairs" in text and "9 timed calls" in text
    assert "2^20" not in text
    assert "100,000 random" in speed_settings(_results(100_000, spread))
    assert speed_settings({"config": {"speed": False}}) .startswith("evals/s: not measured")
    (row,) = summary_table(_results(4096, spread))
    assert (row["evals_per_s"], row["evals_min"], row["evals_max"]) == (2e7, 1.5e7, 2.2e7)


@pytest.mark.parametrize("speeds", [(2.1e7, 2.6e7, 3.3e7), (1.5e6, 9.9e6), (3e5, 4e7, 2e9)])
def test_every_chart_axis_is_labelled_with_ticks(speeds):
    """Speeds within one power of ten (the usual case) still get labelled ticks, as do
    speeds over several."""
    import matplotlib.pyplot as plt

    rows = [{"model": f"m{i}", "evals_per_s": s, "bytes": 100.0 * (i + 1),
             "snr_object_mean": 30.0 + i, "snr_whole_mean": 35.0 + i}
            for i, s in enumerate(speeds)]
    fig = speed_accuracy_figure(rows)
    fig.canvas.draw()
    try:
        for ax in fig.axes:
            assert ax.get_xlabel() and ax.get_ylabel()
            lo, hi = ax.get_xlim()
            shown = [t.get_text() for t in ax.get_xticklabels()
                     if t.get_text() and lo <= t.get_position()[0] <= hi]
            assert len(shown) >= 2, (ax.get_xlabel(), shown)
            assert [t for t in ax.get_yticklabels() if t.get_text()]
    finally:
        plt.close(fig)


def test_flip_is_charted_beside_snr_with_its_own_front():
    """HDR-FLIP (lower is better) gets its own row of charts; its Pareto front against
    bytes keeps the models no other beats on both, here the smallest and the closest."""
    import matplotlib.pyplot as plt

    rows = [{"model": m, "evals_per_s": 1e7, "bytes": b, "snr_object_mean": 30.0,
             "snr_whole_mean": 40.0, "flip_mean": f}
            for m, b, f in (("small", 100.0, 0.2), ("close", 200.0, 0.05), ("worse", 300.0, 0.1))]
    fig = speed_accuracy_figure(rows)
    try:
        flip_axes = [ax for ax in fig.axes if "HDR-FLIP" in ax.get_ylabel()]
        assert len(fig.axes) == 6 and len(flip_axes) == 2
        by_bytes = next(ax for ax in flip_axes if ax.get_xlabel() == "bytes per material")
        front = next(line for line in by_bytes.get_lines()
                     if line.get_label() == "Pareto front")
        assert list(zip(front.get_xdata(), front.get_ydata(), strict=True)) == [
            (100.0, 0.2), (200.0, 0.05)]
    finally:
        plt.close(fig)
