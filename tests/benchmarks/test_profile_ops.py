"""benchmarks/diagnostics/profile_ops.py: exclusive time per operation from nested trace events."""

from __future__ import annotations

import pytest

from . import load_benchmark

profile_ops = load_benchmark("diagnostics/profile_ops")


def test_nested_events_count_once():
    """A while loop (0-100 us) holding two kernels (10-30, 40-90) on one thread, a
    kernel on another thread at the same time, and a second call of the first kernel:
    the loop keeps 100 - 20 - 50 = 30 us; events are named by their HLO op."""
    events = [
        {"ph": "X", "pid": 1, "tid": 1, "ts": 0.0, "dur": 100.0, "name": "x", "args": {"hlo_op": "while.1"}},
        {"ph": "X", "pid": 1, "tid": 1, "ts": 10.0, "dur": 20.0, "name": "y", "args": {"hlo_op": "fusion.2"}},
        {"ph": "X", "pid": 1, "tid": 1, "ts": 40.0, "dur": 50.0, "name": "z", "args": {"hlo_op": "fusion.3"}},
        {"ph": "X", "pid": 1, "tid": 2, "ts": 20.0, "dur": 60.0, "name": "fusion.2"},
        {"ph": "X", "pid": 1, "tid": 1, "ts": 200.0, "dur": 5.0, "name": "y", "args": {"hlo_op": "fusion.2"}},
        {"ph": "i", "pid": 1, "tid": 1, "ts": 50.0, "name": "instant"},
    ]
    exclusive, inclusive, count = profile_ops.exclusive_times(events)
    assert exclusive["while.1"] == pytest.approx(30.0) and inclusive["while.1"] == pytest.approx(100.0)
    assert exclusive["fusion.2"] == pytest.approx(20.0 + 60.0 + 5.0) and count["fusion.2"] == 3
    assert exclusive["fusion.3"] == pytest.approx(50.0)
    assert "instant" not in count


def test_an_event_that_starts_where_another_ends_is_not_its_child():
    events = [
        {"ph": "X", "pid": 1, "tid": 1, "ts": 0.0, "dur": 10.0, "name": "a"},
        {"ph": "X", "pid": 1, "tid": 1, "ts": 10.0, "dur": 5.0, "name": "b"},
    ]
    exclusive, _, _ = profile_ops.exclusive_times(events)
    assert exclusive == {"a": 10.0, "b": 5.0}
