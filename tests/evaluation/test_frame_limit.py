"""When a frame row may be judged against the memory limit instead of 2x the
peer: only where the limit binds (tectum is not already faster than it)."""

from __future__ import annotations

from tectum.evaluation.suites.filters import frame_limit, limit_binds


def test_the_limit_is_the_bandwidth_over_the_bytes_an_event_moves() -> None:
    slow = frame_limit(1000, 1, 8, 24e9)  # one 8 B/px frame for 1,000 events
    fast = frame_limit(100_000, 1, 8, 24e9)
    assert fast > 10 * slow


def test_the_limit_binds_only_where_tectum_does_not_beat_it() -> None:
    assert limit_binds(ours=150.0, peer_mev_s=200.0, limit=300.0)  # 2x peer = 400 > 200: past it, and binding
    assert not limit_binds(ours=325.0, peer_mev_s=179.0, limit=256.0)  # faster than the "limit": cache, not memory
    assert not limit_binds(ours=150.0, peer_mev_s=50.0, limit=300.0)  # 2x the peer is within reach: judged by 2x


def test_the_frames_bytes_count_at_the_speed_they_are_written_in_cache() -> None:
    """The pooled frames are written in cache (frame_write_bandwidth), the
    events' columns read from main memory: each share of an event's bytes
    at its own bandwidth."""
    import pytest

    from tectum.evaluation.suites.filters import EVENT_BYTES, SENSOR, frame_write_bandwidth

    frame_bytes = 8 * SENSOR[0] * SENSOR[1] / 20_000  # one 8 B/px frame for 20,000 events
    both = frame_limit(20_000, 1, 8, 24e9, 88e9)
    assert both == pytest.approx(1e-6 / (frame_bytes / 88e9 + EVENT_BYTES / 24e9))
    assert frame_limit(20_000, 1, 8, 24e9) == pytest.approx(24e9 / (frame_bytes + EVENT_BYTES) / 1e6)
    assert 0 < frame_write_bandwidth(px_bytes=1, frames=2, repeat=3) < float("inf")
