"""The stage clock (sfb_video/timing.py): a stage's seconds exclude the stages nested in it,
and a timed iterator counts the work of producing items, not the consumer's."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from sfb_video import timing


class FakeClock:
    """perf_counter that moves only when told to."""

    def __init__(self) -> None:
        self.now = 0.0

    def __call__(self) -> float:
        return self.now


@pytest.fixture
def clock(monkeypatch: pytest.MonkeyPatch) -> FakeClock:
    fake = FakeClock()
    monkeypatch.setattr(timing.time, "perf_counter", fake)
    timing.reset()
    return fake


def test_nested_stages_count_only_their_own_time(clock: FakeClock) -> None:
    with timing.stage("export"):
        clock.now += 1.0
        with timing.stage("recording"):
            clock.now += 2.0
        clock.now += 0.5
        with timing.stage("recording"):
            clock.now += 0.25
    assert timing.stage_seconds() == {"export": 1.5, "recording": 2.25}


def test_a_timed_iterator_counts_producing_not_consuming(clock: FakeClock) -> None:
    def frames() -> Iterator[int]:
        for k in range(3):
            clock.now += 1.0  # decoding
            yield k

    @timing.timed("fit")
    def fit(k: int) -> int:
        clock.now += 10.0
        return k

    seen = [fit(k) for k in timing.timed_iter("read", frames())]
    assert seen == [0, 1, 2]
    assert timing.stage_seconds() == {"read": 3.0, "fit": 30.0}


def test_a_stage_that_raises_is_still_counted(clock: FakeClock) -> None:
    with pytest.raises(ValueError), timing.stage("detect"):
        clock.now += 4.0
        raise ValueError
    with timing.stage("fit"):
        clock.now += 1.0
    assert timing.stage_seconds() == {"detect": 4.0, "fit": 1.0}
