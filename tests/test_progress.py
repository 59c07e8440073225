"""A long loop's Progress says what is done, what remains and about how long that takes."""

import time

from rbfn.progress import Progress


def test_progress_says_done_total_and_time_left_from_the_stage_rate(monkeypatch):
    clock = iter([0.0, 0.0, 10.0, 10.0, 10.0])
    monkeypatch.setattr(time, "perf_counter", lambda: next(clock))
    p = Progress()
    assert p.line() is None  # nothing started
    p.at("refinement", 0, 100)  # stage starts at t = 0
    assert p.line() == "refinement: 0 / 100 steps"  # no rate yet
    p.at("refinement", 25, 100)
    assert p.line() == "refinement: 25 / 100 steps, about 30 s left"  # 25 steps in 10 s: 75 more in 30 s


def test_a_new_stage_restarts_the_rate_and_a_resumed_one_counts_from_where_it_was(monkeypatch):
    clock = iter([0.0, 0.0, 100.0, 110.0])
    monkeypatch.setattr(time, "perf_counter", lambda: next(clock))
    p = Progress()
    p.at("M = 10: colony", 40, 50, "iterations")  # resumed at iteration 40: the rate counts from there
    p.at("M = 10: colony", 45, 50, "iterations")
    assert p.line() == "M = 10: colony: 45 / 50 iterations, about 100 s left"  # 5 in 100 s
    p.at("refinement", 0, 10)
    assert p.what == "refinement" and p.line() == "refinement: 0 / 10 steps"


def test_a_stage_of_no_counted_steps_is_named_alone():
    p = Progress()
    p.at("the pilot run", 0, 0)
    assert p.line() == "the pilot run"
