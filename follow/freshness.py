"""Whether a stamped piece of data is fresh enough to move the robot on.

Age is `now - stamp`, and a negative age is no proof of freshness: a stamp ahead of the
reading clock comes from a clock that disagrees with it (a camera or base driver on
another host, a clock stepped back by NTP, a simulator's /clock restarted). Taking such
data as fresh would switch off every stale-data stop for as long as the offset, so it
counts as stale: the robot stops, and waits for data whose time it can trust.
"""

from __future__ import annotations

# How far ahead of the reading clock a stamp may be and still count: clocks synchronised
# over a network (chrony, PTP) agree far better than this.
MAX_STAMP_AHEAD_S = 0.1


def is_fresh(now_s: float, stamp_s: float, max_age_s: float) -> bool:
    """`stamp_s` is at most `max_age_s` old at `now_s` and not ahead of it by more than
    `MAX_STAMP_AHEAD_S`."""
    return -MAX_STAMP_AHEAD_S <= now_s - stamp_s <= max_age_s


def is_ahead(now_s: float, stamp_s: float) -> bool:
    """`stamp_s` lies in the reading clock's future by more than `MAX_STAMP_AHEAD_S`."""
    return stamp_s - now_s > MAX_STAMP_AHEAD_S
