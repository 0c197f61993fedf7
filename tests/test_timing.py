"""The one timing harness: interleaved rounds with a rotated order, untimed warm-up calls, min
<= median, the repeat count, and ratios taken from its timings only (no timing thresholds)."""

import time

import pytest

from uavdyn.evaluation import Timing, interleaved_timing, ratio


def _recording(calls, name):
    def run():
        calls.append(name)

    return run


def test_every_round_calls_every_configuration_once_in_a_rotated_order():
    calls: list[str] = []
    names = ["a", "b", "c"]
    ticks = []
    out = interleaved_timing({n: _recording(calls, n) for n in names}, 4, warmup=1,
                             progress=lambda: ticks.append(1))
    assert len(calls) == (1 + 4) * 3
    rounds = [calls[i:i + 3] for i in range(0, len(calls), 3)]
    assert all(sorted(r) == names for r in rounds)
    firsts = [r[0] for r in rounds]
    assert firsts == ["a", "b", "c", "a", "b"]  # rotation: no configuration always first
    assert len({tuple(r) for r in rounds}) == 3
    assert list(out) == names
    assert all(t.repeats == 4 for t in out.values())
    assert len(ticks) == 4 * 3  # once per timed call, not for warm-up calls


def test_min_le_median_and_repeats_default_is_15():
    out = interleaved_timing({"x": lambda: sum(range(100)), "y": lambda: None})
    for name, t in out.items():
        assert isinstance(t, Timing) and t.name == name
        assert t.repeats == 15
        assert 0 < t.min_s <= t.median_s
        assert t.min_ms == pytest.approx(t.min_s * 1e3)
        assert t.median_ms == pytest.approx(t.median_s * 1e3)
        d = t.to_dict()
        assert d["repeats"] == 15 and d["median_ms"] == pytest.approx(t.median_ms)


def test_warmup_calls_are_not_timed():
    state = {"n": 0}

    def slow_first():
        state["n"] += 1
        if state["n"] == 1:
            time.sleep(0.2)

    out = interleaved_timing({"slow first": slow_first}, 3, warmup=1)
    assert state["n"] == 4
    assert out["slow first"].repeats == 3
    assert out["slow first"].min_s < 0.1 and out["slow first"].median_s < 0.1
    state["n"] = 0
    cold = interleaved_timing({"slow first": slow_first}, 3, warmup=0)
    assert state["n"] == 3 and cold["slow first"].repeats == 3


def test_ratio_is_the_quotient_of_the_reported_statistics():
    a, b = Timing("a", 2.0, 3.0, 15), Timing("b", 0.5, 2.0, 15)
    assert ratio(a, b) == 3.0 / 2.0
    assert ratio(a, b, "median") == 3.0 / 2.0
    assert ratio(a, b, "min") == 2.0 / 0.5
    with pytest.raises(ValueError):
        ratio(a, b, "mean")


@pytest.mark.parametrize("kwargs", [{"repeats": 0}, {"repeats": 2.5}, {"warmup": -1}])
def test_bad_arguments_are_refused(kwargs):
    with pytest.raises(ValueError):
        interleaved_timing({"a": lambda: None}, **kwargs)
    with pytest.raises(ValueError):
        interleaved_timing({})
