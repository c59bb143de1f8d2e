"""The benchmark timing helpers (``jaxplan.eval.timing``)."""
import time

from jaxplan.eval.timing import best_time, best_times_interleaved


def test_interleaved_best_calls_every_side_once_per_round_and_keeps_the_best():
    order = []
    waits = {"a": [0.03, 0.005, 0.02], "b": [0.02, 0.04, 0.02]}

    def side(name):
        def call():
            time.sleep(waits[name][sum(o == name for o in order)])
            order.append(name)
        return call

    best = best_times_interleaved({"a": side("a"), "b": side("b")}, 3)
    assert order == ["a", "b"] * 3  # one call of each per round, in turn
    assert set(best) == {"a", "b"}
    assert 0.005 <= best["a"] < 0.02 and 0.02 <= best["b"] < 0.04  # the shortest call of each
    order.clear()
    waits = {"a": [0.01] * 4, "b": [0.01] * 4}
    best_times_interleaved({"a": side("a"), "b": side("b")}, 2, inner=2)
    assert order == ["a", "a", "b", "b"] * 2
    calls = []
    assert best_time(lambda: calls.append(1), 4) >= 0 and len(calls) == 4
