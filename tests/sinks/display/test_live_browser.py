"""The live view as a user sees it: one page load in a real headless
Chromium (driven by Selenium), within which the picture must change and the
stats table fill in; any JavaScript console error fails the test.

Needs Debian's ``chromium`` and ``chromium-driver`` (.ci/apt-packages.txt)
and the ``selenium`` package (the ``test`` extra); skips, saying which is
missing, where they are absent. ``TECTUM_LIVE_SCREENSHOTS=DIR`` keeps a
screenshot of each page for a person to look at.
"""

from __future__ import annotations

import os
import shutil
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pytest

from tectum.sinks.display.maps import UNKNOWN_COLOUR
from tectum.sinks.display.render import OFF_COLOUR, ON_COLOUR

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")
DRIVER = shutil.which("chromedriver")
ARGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
        "--disable-background-networking", "--disable-component-update", "--disable-sync",
        "--disable-dev-shm-usage", "--window-size=1000,620")


@pytest.fixture
def browser(tmp_path: Path) -> Iterator[Any]:
    if not (CHROMIUM and DRIVER):
        pytest.skip("chromium or chromedriver is not installed (Debian packages 'chromium' and "
                    "'chromium-driver', see .ci/apt-packages.txt)")
    webdriver = pytest.importorskip("selenium.webdriver", reason="selenium is not installed (pip install '.[test]')")
    from selenium.webdriver.chrome.service import Service

    opts = webdriver.ChromeOptions()
    opts.binary_location = CHROMIUM
    for a in (*ARGS, f"--user-data-dir={tmp_path / 'profile'}"):
        opts.add_argument(a)
    opts.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    driver = webdriver.Chrome(options=opts, service=Service(executable_path=DRIVER))
    driver.set_page_load_timeout(30)
    try:
        yield driver
    finally:
        driver.quit()


def _picture(driver: Any) -> np.ndarray:
    """The image element as the browser draws it (BGR)."""
    from selenium.webdriver.common.by import By

    png = driver.find_element(By.ID, "f").screenshot_as_png
    return cv2.imdecode(np.frombuffer(png, np.uint8), cv2.IMREAD_COLOR)


def _share(img: np.ndarray, colour: tuple[int, int, int]) -> float:
    return float((np.abs(img.astype(int) - colour).sum(axis=2) < 40).mean())


def _console_errors(driver: Any) -> list[dict[str, Any]]:
    return [e for e in driver.get_log("browser") if e["level"] == "SEVERE"]


def _wait(driver: Any, what: str, until: Any, timeout: float = 20.0) -> Any:
    """``until()``'s first true value; fails at once on a console error."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        errors = _console_errors(driver)
        assert not errors, f"JavaScript console error(s): {errors}"
        got = until()
        if got:
            return got
        time.sleep(0.1)
    raise AssertionError(f"within {timeout} s of one page load: {what}")


@pytest.mark.parametrize("live_view", [{"mode": "polarity"}, {"mode": "flow_wheel", "flow_max_px_s": 60.0}],
                         indirect=True, ids=["polarity", "flow_wheel"])
def test_one_page_load_updates_picture_and_stats(live_view: str, browser: Any, request: pytest.FixtureRequest) -> None:
    from selenium.webdriver.common.by import By

    mode = request.node.callspec.params["live_view"]["mode"]
    browser.get(live_view + "/")
    browser.execute_script("window.sameLoad = 'yes'")  # gone if anything reloads the page
    img = browser.find_element(By.ID, "f")
    shown = "return arguments[0].naturalWidth"
    _wait(browser, "the first frame is shown", lambda: browser.execute_script(shown, img) > 0)
    first = _picture(browser)
    _wait(browser, "the picture changes", lambda: np.abs(_picture(browser).astype(int) - first).sum(axis=2).max() > 60)
    table = "return [...document.querySelectorAll('#nodes tbody tr')].map(tr => [...tr.cells].map(c => c.textContent))"
    rows = _wait(browser, "the stats table fills in", lambda: browser.execute_script(table))  # at once: rows change
    assert any(r[0] == "pattern" and int(r[2].replace(",", "")) > 0 for r in rows), rows  # the source's events out
    status = browser.find_element(By.ID, "status").text
    assert " events, " in status and "Mev/s" in status, status
    assert browser.execute_script("return window.sameLoad") == "yes"

    pic = _picture(browser)
    w, h = img.size["width"], img.size["height"]
    assert w > 400 and h > 300, (w, h)  # 96x64 px scaled to the window, not drawn at its own size
    if mode == "polarity":
        assert _share(pic, ON_COLOUR) > 0.01 and _share(pic, OFF_COLOUR) > 0.01  # both edges of the bars
        legend = browser.find_element(By.ID, "legend").text
        assert "ON event" in legend and "OFF event" in legend, legend
    else:
        sat = cv2.cvtColor(pic, cv2.COLOR_BGR2HSV)[:, :, 1]
        assert (sat > 100).mean() > 0.01  # flow colours, not grey
        wheel = browser.find_element(By.CSS_SELECTOR, "#legend img")
        assert browser.execute_script("return arguments[0].naturalWidth", wheel) == 96
    caption = browser.find_element(By.CSS_SELECTOR, "#view p.what").text
    assert "Sensor 96x64 px" in caption, caption

    keep = os.environ.get("TECTUM_LIVE_SCREENSHOTS")
    if keep:
        Path(keep).mkdir(parents=True, exist_ok=True)
        browser.save_screenshot(str(Path(keep) / f"live-{mode}.png"))
    errors = _console_errors(browser)
    assert not errors, errors


def _open_view(browser: Any, url: str, title: str) -> str:
    """One page load of a map or frame stream's view: wait for its first
    picture and its title; its caption."""
    from selenium.webdriver.common.by import By

    browser.get(url + "/")
    img = browser.find_element(By.ID, "f")
    _wait(browser, "the first picture is shown", lambda: browser.execute_script("return arguments[0].naturalWidth", img))
    _wait(browser, f"the title says {title}", lambda: browser.find_element(By.ID, "title").text == title)
    return str(browser.find_element(By.ID, "caption").text)


@pytest.mark.parametrize("live_view", [{"maps": True}], indirect=True, ids=["maps"])
def test_a_map_stream_shows_maps_with_their_caption_and_legend(live_view: str, browser: Any) -> None:
    from selenium.webdriver.common.by import By

    caption = _open_view(browser, live_view, "Map")
    assert "Log-intensity map (80x40 px)" in caption, caption
    assert browser.find_element(By.ID, "maplegend").is_displayed()
    assert not browser.find_element(By.ID, "evlegend").is_displayed()  # no events in this stream
    pic = _picture(browser)
    assert _share(pic, UNKNOWN_COLOUR) > 0.1  # the never-observed quarter
    grey = np.abs(pic.astype(int) - pic[:, :, :1]).max(axis=2) < 8
    assert grey.mean() > 0.3
    errors = _console_errors(browser)
    assert not errors, errors


@pytest.mark.parametrize("live_view", [{"op": "repr.time_surface", "op_params": {"window_us": 50_000}}],
                         indirect=True, ids=["time_surface"])
def test_a_representation_shows_its_frames_with_their_caption(live_view: str, browser: Any) -> None:
    from selenium.webdriver.common.by import By

    caption = _open_view(browser, live_view, "Frames")
    assert "Frame (96x64 px)" in caption and "from 0 to 1" in caption, caption
    assert not browser.find_element(By.ID, "maplegend").is_displayed()  # a depth legend would mislead here
    assert browser.find_element(By.ID, "evlegend").is_displayed()  # ON and OFF colours
    first = browser.find_element(By.ID, "status").text
    _wait(browser, "the frames keep coming", lambda: browser.find_element(By.ID, "status").text != first)
    errors = _console_errors(browser)
    assert not errors, errors
