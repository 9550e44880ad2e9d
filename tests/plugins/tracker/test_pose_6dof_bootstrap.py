"""``tracker.pose_6dof`` in a loop: a bootstrap (the poses port's rows handed
on for ``bootstrap_us``, tracking from its end against the latest map), each
later map taken from the first batch that ends after its time (the same
however the ports are split), and a later map's view not taken for the map's
own."""

from __future__ import annotations

from typing import Any

import numpy as np
import pytest

from tectum import MapPacket, PosePacket, concat
from tectum.plugins.tracker.pose_6dof import Pose6Dof
from tectum.testing import assert_batch_invariant, feed_ports

from helpers import SLIDE

SENSOR = "120x90"
BOOT_US = 60_000


def _map(t_us: int) -> MapPacket:
    from tectum.sources.simulate.photomap import scene_map

    m = scene_map(SLIDE, t_us, sensor=SENSOR)
    return MapPacket(np.array([t_us], np.int64), image=m["image"][None], depth=m["depth"][None], K=m["K"][None],
                     pose=m["pose"][None], t_start=t_us, t_end=t_us + 1)


@pytest.fixture(scope="module")
def slide() -> dict[str, Any]:
    from tectum.sources.simulate import simulate

    ev, truth = simulate(SLIDE, 140_000, sensor=SENSOR)
    poses = PosePacket(truth["pose_t"], position=truth["pose_position"], orientation=truth["pose_orientation"],
                       t_start=ev.t_start, t_end=ev.t_end)
    maps = concat([_map(40_000), _map(100_000)])
    assert isinstance(maps, MapPacket)
    maps = MapPacket(maps.t, **maps.data, t_start=ev.t_start, t_end=ev.t_end)
    return {"events": ev.without_columns(*ev.columns), "poses": poses, "maps": maps}


def _op() -> Pose6Dof:
    return Pose6Dof(bootstrap_us=BOOT_US, min_points=50, batch_events=600)


def test_the_bootstrap_is_handed_on_then_tracking_starts_at_its_end(slide: dict[str, Any]) -> None:
    op = _op()
    out = concat([q for q in feed_ports(op, {k: [v] for k, v in slide.items()}) if isinstance(q, PosePacket)])
    assert isinstance(out, PosePacket)
    poses, ev = slide["poses"], slide["events"]
    boot = out.t < BOOT_US
    assert np.array_equal(out.t[boot], poses.t[poses.t < BOOT_US])  # the poses port's rows, as they are
    assert np.allclose(out.position[boot], poses.position[poses.t < BOOT_US]) and not out.lost[boot].any()
    assert op.counts["skipped_before_map"] == int(np.searchsorted(ev.t, BOOT_US))  # events before its end
    tracked = ~boot & (out.t <= poses.t[-1])
    assert tracked.sum() > 20 and not out.lost[tracked].any()
    # the tracked rows (from 60 ms, against the 40 ms map, then the 100 ms one) follow the truth
    from tectum.camera import interpolate_poses

    p, _, _ = interpolate_poses(out.t[tracked], poses.t, poses.position, poses.orientation)
    err = np.linalg.norm(out.position[tracked] - p, axis=1)
    assert err.max() < 0.004, err.max()  # m, over 24 mm of travel
    assert op.map is not None and np.allclose(op.map.position, slide["maps"].data["pose"][1][:3])  # the later map


def test_maps_and_bootstrap_are_batch_invariant(slide: dict[str, Any]) -> None:
    assert_batch_invariant(_op, slide, max_examples=3, event_by_event_check=False)


def test_a_later_map_is_not_taken_for_the_map_view() -> None:
    """Started at the first map's own pose, the reference view is the map's
    (its larger step, ``map_view_px``); a later map at another pose makes
    that view the tracker's own."""
    from tectum.sources.simulate import simulate

    ev, _ = simulate(SLIDE, 40_000, sensor=SENSOR)
    ev = ev.without_columns(*ev.columns)
    op = Pose6Dof(min_points=50)
    op.process_ports({"events": ev.slice_time(0, 20_000), "maps": _map(0)})
    assert op._ref_is_map
    op.process_ports({"events": ev.slice_time(20_000, 40_000), "maps": _map(20_000)})
    assert op.map is not None and np.allclose(op.map.position, _map(20_000).data["pose"][0][:3])
    assert not op._ref_is_map


def test_a_bootstrap_without_poses_is_an_error(slide: dict[str, Any]) -> None:
    with pytest.raises(ValueError, match="no pose came on port 'poses'"):
        feed_ports(_op(), {"events": [slide["events"]], "maps": [slide["maps"]]})
