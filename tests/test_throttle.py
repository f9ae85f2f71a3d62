"""The one limiter of logged lines (``hil.link.throttle.Throttle``), shared by the board session's drop,
reset and board-log lines, the phone receiver's drop and new-sender lines and the run's recorded board
logs: never more than its lines in any of its windows, and every call either a line or counted for the
next one."""

from __future__ import annotations

from hypothesis import example, given, settings
from hypothesis import strategies as st

from hil.link.throttle import Throttle


@given(
    every_s=st.floats(0.01, 5.0),
    lines=st.integers(1, 5),
    calls=st.lists(st.tuples(st.floats(0.0, 3.0), st.integers(1, 4)), min_size=1, max_size=300),
)
@example(every_s=1.4694874560107705, lines=1, calls=[(1.4938711943521672, 1), (0.12, 1), (2.0, 1)])  # CI's
@settings(max_examples=2000)
def test_no_window_holds_more_lines_than_allowed_and_nothing_goes_uncounted(every_s, lines, calls):
    """Windows open at a line (not sliding): any span of ``every_s`` meets at most two windows' lines; and
    every call's count is said once — by its own line, or by the next line's count of those held."""
    throttle = Throttle(every_s, lines)
    now, written, said_total, total = 0.0, [], 0, 0
    for step, count in calls:
        now += step
        total += count
        said = throttle.due(now, count)
        if said is not None:
            written.append(now)
            said_total += said + count
    assert written[0] == calls[0][0]  # the first call is always a line
    for i, t in enumerate(written):
        assert sum(1 for u in written[i:] if u - t < every_s * (1 - 1e-9)) <= 2 * lines  # as due() judges
    # two windows later (one later may round to a hair short of it: (t + w) - t < w): a line, saying
    # what is still held
    last = throttle.due(now + 2 * every_s, 0)
    assert last is not None and said_total + last == total


def test_a_flood_is_a_line_per_window_saying_how_many_came_between():
    throttle = Throttle(1.0)
    said = [throttle.due(k * 0.01) for k in range(350)]  # 3.5 s at 100 a second
    lines = [s for s in said if s is not None]
    assert lines == [0, 99, 99, 99]
