"""Scenes of moving objects last any duration: objects with a bounce box
reflect off its sides (position and true velocity), so a long live demo of
``shapes`` or ``translation_edges`` never goes blank."""

from __future__ import annotations

import numpy as np
import pytest

from tectum.sources.simulate import simulate
from tectum.sources.simulate.render import SPRITE_STATE, sprite_states


def _reference(u0: float, v: float, t: float, lo: float, hi: float, dt: float = 1e-4) -> tuple[float, float]:
    """Walk the point in small steps, reversing at each side."""
    u = u0
    for _ in range(int(round(t / dt))):
        u += v * dt
        if u > hi:
            u, v = 2 * hi - u, -v
        elif u < lo:
            u, v = 2 * lo - u, -v
    return u, v


def test_bounce_matches_a_stepped_reference() -> None:
    sprites = np.zeros((1, 22))
    sprites[0, 1:5] = (30.0, 20.0, 170.0, -55.0)  # x0, y0 px, vx, vy px/s
    sprites[0, 18:22] = (10.0, 5.0, 90.0, 60.0)  # the centre stays in [10, 90] x [5, 60]
    for t in (0.0, 0.3, 1.7, 4.05, 9.9):
        st = sprite_states(sprites, t, np.empty((1, SPRITE_STATE)))
        rx, rvx = _reference(30.0, 170.0, t, 10.0, 90.0)
        ry, rvy = _reference(20.0, -55.0, t, 5.0, 60.0)
        assert st[0, 0] == pytest.approx(rx, abs=0.05) and st[0, 1] == pytest.approx(ry, abs=0.05), t
        assert (st[0, 6], st[0, 7]) == (rvx, rvy), t


@pytest.mark.parametrize("scene", ["shapes", "translation_edges"])
def test_moving_objects_stay_on_the_sensor(scene: str) -> None:
    ev, _ = simulate(scene, 6_000_000, sensor="48x36")
    signal = ev.t[ev["noise"] == 0]
    per_second = np.histogram(signal, bins=6, range=(0, 6_000_000))[0]
    assert per_second.min() > 0.4 * per_second.max(), per_second
    vx = ev["vx"][ev["object_id"] == 1]  # the first object starts moving to the right (+x) ...
    assert (vx > 0).mean() > 0.2 and (vx < 0).mean() > 0.2  # ... and comes back: its true flow turns round
