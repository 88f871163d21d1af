"""Failures counted in a row by their cause: what stops a run, or a compare, against a dead server."""

from __future__ import annotations

from pipeline.core.outcomes import FailureStreak

REFUSED = "HttpError: unit seg_{n}: connection refused (the host refused {n} s ago)"


def test_alike_failures_stop_at_the_limit_whatever_their_names_and_details():
    streak = FailureStreak(3, "units")
    assert [streak.failed(REFUSED.format(n=n)) for n in range(1, 4)][:2] == ["", ""]
    assert streak.gave_up == (
        f"the last 3 units failed alike ({REFUSED.format(n=3)}; max_failures_in_a_row=3)"
    )


def test_another_cause_or_a_success_starts_the_count_again():
    streak = FailureStreak(2, "clips")
    streak.failed(REFUSED.format(n=1))
    streak.failed("OSError: disk full")
    streak.succeeded()
    streak.failed(REFUSED.format(n=2))
    assert streak.gave_up == "" and streak.count == 1
    assert streak.failed(REFUSED.format(n=3)).startswith("the last 2 clips failed alike")


def test_a_limit_of_zero_never_gives_up():
    streak = FailureStreak(0, "units")
    for n in range(50):
        streak.failed(REFUSED.format(n=n))
    assert streak.gave_up == "" and streak.count == 50
