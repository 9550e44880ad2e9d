"""Maps in the display sinks: ``out.png`` of a map stream is the picture of
its last map (log intensity in grey, NaN in the neutral colour; depth in a
colour map with a legend), and the live view serves maps with their caption."""

from __future__ import annotations

import json
import urllib.request

import cv2
import numpy as np
import pytest

import tectum
from tectum import MapPacket
from tectum.sinks.display.maps import (
    LEGEND_W,
    UNKNOWN_COLOUR,
    UNKNOWN_DEPTH_COLOUR,
    depth_picture,
    intensity_picture,
    map_picture,
)
from tectum.testing import ListSource


def test_intensity_picture_is_grey_with_nan_in_the_neutral_colour(log_maps):
    img = log_maps(1)[0].image[0]
    pic = intensity_picture(img)
    ok = np.isfinite(img)
    assert (pic[~ok] == UNKNOWN_COLOUR).all()
    assert (pic[ok][:, 0] == pic[ok][:, 1]).all() and (pic[ok][:, 1] == pic[ok][:, 2]).all()  # grey
    assert pic[ok].min() == 0 and pic[ok].max() == 255  # stretched
    brighter = img[ok] > np.median(img[ok])
    assert pic[ok][brighter, 0].mean() > pic[ok][~brighter, 0].mean() + 100


def test_depth_picture_has_a_colour_map_and_a_legend():
    d = np.tile(np.linspace(0.5, 4.0, 60), (30, 1))
    d[:5] = np.nan
    pic = depth_picture(d)
    assert pic.shape == (30, 60 + LEGEND_W, 3)
    body = pic[:, :60]
    assert (body[:5] == UNKNOWN_DEPTH_COLOUR).all()
    hsv = cv2.cvtColor(body[5:], cv2.COLOR_BGR2HSV)
    assert (hsv[..., 1] > 100).mean() > 0.9  # colours, not grey
    assert body[10, 0, 2] > body[10, 0, 0] and body[10, -1, 0] > body[10, -1, 2]  # near red, far blue
    assert body[10, 20].tolist() != body[10, 40].tolist()


def test_png_sink_keeps_the_last_map(tmp_path, log_maps):
    maps = log_maps(3)
    p = tectum.Pipeline()
    p.sink(str(tmp_path / "last.png"), p.source(ListSource(maps)))
    tectum.run(p)
    got = cv2.imread(str(tmp_path / "last.png"))
    np.testing.assert_array_equal(got, map_picture(maps[-1]))
    assert not np.array_equal(got, map_picture(maps[0]))


def test_a_depth_map_is_drawn_as_depth():
    d = np.full((1, 20, 30), 2.0, np.float32)
    d[0, :, 15:] = 1.0
    pkt = MapPacket([0], depth=d, image=np.zeros((1, 20, 30), np.float32))
    assert map_picture(pkt).shape == (20, 30 + LEGEND_W, 3)
    with pytest.raises(ValueError, match="neither an image nor a depth"):
        map_picture(MapPacket([0], confidence=np.zeros((1, 2, 2), np.float32)))


@pytest.mark.parametrize("live_view", [{"maps": True}], indirect=True)
def test_live_view_serves_maps_with_their_caption(live_view):
    stats = json.loads(urllib.request.urlopen(live_view + "/stats.json", timeout=2).read())
    assert stats["maps"] >= 1 and stats["events"] == 0, stats
    assert stats["view"]["title"] == "Map" and "Log-intensity map (80x40 px)" in stats["view"]["caption"]
    png = urllib.request.urlopen(live_view + "/frame.png", timeout=2).read()
    pic = cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)
    assert pic.shape == (80, 160, 3)  # scale=2
    assert (pic[:, :40] == UNKNOWN_COLOUR).all()
    page = urllib.request.urlopen(live_view + "/", timeout=2).read().decode()
    assert 'id="maplegend"' in page and "never observed" in page
