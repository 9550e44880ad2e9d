"""The live view's web page: the newest frame scaled to the window, a legend
for the mode, a caption saying what each panel shows, and the pipeline's
per-node stats, all refreshed by a script within one page load.

The script is a raw string (no Python escapes, no format braces): what is
written here is what the browser parses. ``tests/sinks/display`` loads the
page in a headless Chromium and fails on any console error.
"""

from __future__ import annotations

import html

from .maps import UNKNOWN_COLOUR, UNKNOWN_DEPTH_COLOUR
from .render import BACKGROUND, OFF_COLOUR, ON_COLOUR, TRACK_COLOUR, Renderer

__all__ = ["page"]

_HTML = r"""<!doctype html>
<html lang="en"><head><meta charset="utf-8"><title>tectum live view</title>
<meta name="viewport" content="width=device-width, initial-scale=1"><link rel="icon" href="data:,">
<style>
html, body {margin: 0; height: 100%; background: #202020; color: #ddd; font: 13px/1.4 system-ui, sans-serif}
body {display: flex; flex-wrap: wrap; gap: 12px; padding: 8px; box-sizing: border-box}
section {display: flex; flex-direction: column; min-width: 0}
#view {flex: 3 1 420px; height: calc(100vh - 16px)}
#side {flex: 1 1 320px; max-height: calc(100vh - 16px); overflow: auto}
#f {flex: 1; min-height: 0; width: 100%; object-fit: contain; object-position: left top;
    image-rendering: pixelated; background: #000}
h2 {font-size: 14px; margin: 0 0 2px; color: #fff}
p.what {margin: 0 0 6px; color: #aaa}
#legend div {margin: 2px 0}
.sw {display: inline-block; width: 12px; height: 12px; vertical-align: middle; margin-right: 6px;
     border: 1px solid #888}
table {border-collapse: collapse; font: 12px monospace; margin-top: 4px}
th, td {padding: 1px 6px; text-align: right; border-bottom: 1px solid #333}
th:first-child, td:first-child {text-align: left}
</style></head><body>
<section id="view">
<h2 id="title">Events</h2><p class="what" id="caption">__CAPTION__</p>
<img id="f" alt="the newest frame of events">
<div id="status">waiting for the first frame</div>
</section>
<section id="side">
<h2>Legend</h2><div id="legend"><div id="evlegend">__LEGEND__</div>
<div id="maplegend" hidden>__MAPLEGEND__</div>
<div id="tracks" hidden>__TRACKS__</div></div>
<h2 style="margin-top: 12px">Pipeline</h2>
<p class="what">Per node of the running pipeline: events in and out, events dropped at full queues,
milliseconds spent in the node's own code, and the latency from the source to each sink
(median / 99th percentile).</p>
<table id="nodes"><thead><tr><th>node</th><th>events in</th><th>events out</th><th>drops</th><th>busy ms</th>
<th>latency ms</th></tr></thead><tbody></tbody></table>
</section>
<script>
"use strict";
const $ = (id) => document.getElementById(id);
const fmt = (n) => n.toLocaleString("en-US");
let shown = 0, busy = false;

async function get(url, how) {  // null when the server is gone (the run ended)
  try {
    const r = await fetch(url, {cache: "no-store"});
    return r.ok ? await r[how]() : null;
  } catch (e) {
    return null;
  }
}

function cells(values) {
  const tr = document.createElement("tr");
  for (const v of values) {
    const td = document.createElement("td");
    td.textContent = v;
    tr.appendChild(td);
  }
  return tr;
}

function showNodes(p) {
  const rows = Object.entries(p.nodes).map(([id, n]) => {
    const l = p.latency_us[id];
    const lat = l && l.p50 !== undefined ? (l.p50 / 1e3).toFixed(2) + " / " + (l.p99 / 1e3).toFixed(2) : "";
    return cells([id, fmt(n.events_in), fmt(n.events_out), fmt(n.drops), (n.busy_ns / 1e6).toFixed(1), lat]);
  });
  $("nodes").tBodies[0].replaceChildren(...rows);
}

async function tick() {
  if (busy) return;
  busy = true;
  try {
    const s = await get("/stats.json", "json");
    if (s === null) {
      $("status").textContent = "the pipeline is not reachable (the run has ended?)";
      return;
    }
    if (s.frames > shown) {
      const blob = await get("/frame.png?" + s.frames, "blob");
      if (blob !== null) {
        const old = $("f").src;
        $("f").src = URL.createObjectURL(blob);
        if (old.startsWith("blob:")) URL.revokeObjectURL(old);
        shown = s.frames;
      }
    }
    $("status").textContent = fmt(s.events) + " events, " + (s.rate_ev_s / 1e6).toFixed(3) + " Mev/s, " +
      (s.maps ? fmt(s.maps) + " maps, " : "") + "frame " + fmt(s.frames) + ", event time " +
      (s.t_us / 1e6).toFixed(3) + " s";
    if (s.view) {  // a map or frame stream: its own title, caption and legend
      $("title").textContent = s.view.title;
      $("caption").textContent = s.view.caption;
      $("maplegend").hidden = s.view.title !== "Map";
      $("evlegend").hidden = !s.events && s.view.title === "Map";
    }
    $("tracks").hidden = !s.tracks;
    if (s.pipeline) showNodes(s.pipeline);
  } finally {
    busy = false;
  }
}

tick();
setInterval(tick, __INTERVAL__);
</script></body></html>
"""


def _css(bgr: tuple[int, int, int]) -> str:
    b, g, r = bgr
    return f"rgb({r}, {g}, {b})"


def _swatch(bgr: tuple[int, int, int], text: str) -> str:
    return f'<div><span class="sw" style="background: {_css(bgr)}"></span>{text}</div>'


def _caption(r: Renderer, sensor: tuple[int, int] | None) -> str:
    ms = r.period_us / 1e3
    last = f"during the last {ms:g} ms (one frame per {ms:g} ms of event time)"
    size = f" Sensor {sensor[0]}x{sensor[1]} px, scaled to the window." if sensor else ""
    what = {
        "polarity": f"Each pixel that fired {last}, coloured by the polarity of its newest event.",
        "time_surface": f"Every pixel by how recently it fired: its colour fades as exp(-age / {r.tau_us / 1e3:g} ms) "
                        "since its newest event, tinted by that event's polarity.",
        "flow_wheel": f"Each pixel that fired {last}, coloured by the optical flow of its newest event "
                      "(the events' vx, vy columns): hue is the direction, saturation the speed.",
        "flow_arrows": f"Each pixel that fired {last} by polarity, with one arrow per {r.arrow_step} px cell: the "
                       f"mean optical flow of the cell's pixels, as far as it moves in {r.arrow_scale * 1e3:g} ms.",
    }[r.mode]
    return what + size


def _legend(r: Renderer) -> str:
    polarity = [_swatch(ON_COLOUR, "ON event: the pixel got brighter (+1)"),
                _swatch(OFF_COLOUR, "OFF event: the pixel got darker (-1)"), _swatch(BACKGROUND, "no event")]
    if r.mode == "time_surface":
        fade = (f'<div><span class="sw" style="width: 80px; background: linear-gradient(to right, '
                f'{_css(ON_COLOUR)}, {_css(BACKGROUND)})"></span>age 0 to {3 * r.tau_us / 1e3:g} ms (3 τ)</div>')
        return "\n".join(polarity + [fade])
    if r.mode == "flow_wheel":
        return ('<div style="display: flex; align-items: center; gap: 8px"><img src="/legend.png" width="96" '
                'height="96" alt="flow colour wheel"><span>colour: the direction of motion, read from the '
                "wheel's centre to its rim (moving right: red); paler: slower, white: still; full colour at "
                f"{r.flow_max:g} px/s or faster</span></div>\n" + _swatch(BACKGROUND, "no event, or no flow"))
    if r.mode == "flow_arrows":
        px = r.flow_max * r.arrow_scale
        arrow = (f"<div>&#x2192; white arrow: mean flow of a {r.arrow_step} px cell; {r.flow_max:g} px/s draws "
                 f"{px:g} px</div>")
        return "\n".join(polarity + [arrow])
    return "\n".join(polarity)


_MAP_LEGEND = "\n".join([
    '<div><span class="sw" style="width: 80px; background: linear-gradient(to right, #000, #fff)"></span>'
    "log intensity: dark to bright (1st to 99th percentile of the map)</div>",
    _swatch(UNKNOWN_COLOUR, "never observed (log-intensity map)"),
    "<div>depth map: colour bar in metres beside the map (warm: near, cool: far)</div>",
    _swatch(UNKNOWN_DEPTH_COLOUR, "no depth (depth map)"),
])


def page(r: Renderer, sensor: tuple[int, int] | None, interval_ms: int) -> bytes:
    """The HTML page for a renderer's settings (mode, period, flow scale)."""
    tracks = _swatch(TRACK_COLOUR, f"track (from result packets): its last {r.track_points} positions")
    return (_HTML.replace("__CAPTION__", html.escape(_caption(r, sensor)))
            .replace("__LEGEND__", _legend(r)).replace("__MAPLEGEND__", _MAP_LEGEND).replace("__TRACKS__", tracks)
            .replace("__INTERVAL__", str(int(interval_ms)))).encode()
