"""DAVIS APS frames: the decoder against a slow reference, and frames from
the emulated camera through pyusb."""

from __future__ import annotations

import numpy as np
import pytest

import tectum
from tectum import Kind
from tectum.sources.usb import _protocol as P
from tectum.sources.usb._decode import DavisDecoder
from tectum.sources.usb.emulated import EmulatedCamera

from helpers import run_camera


def ref_frame(reset: np.ndarray, signal: np.ndarray) -> np.ndarray:
    """libcaer's CDS, pixel by pixel, as 8 bits."""
    out = np.zeros(reset.shape, np.uint8)
    for (r, c), rv in np.ndenumerate(reset):
        sv = signal[r, c]
        v = 1023 if rv < 384 or sv == 0 else min(max(int(rv) - int(sv), 0), 1023)
        out[r, c] = v >> 2
    return out


def frame_words(reset: np.ndarray, signal: np.ndarray, t0: int, t1: int, drop_column: bool = False) -> list[int]:
    h, w = reset.shape
    words = [0x8000 | t0, 0x0008, 0x000E]
    for c in range(w):  # rolling order: reset and signal read per column
        if drop_column and c == 2:
            continue
        words += [0x000B] + [0x4000 | int(v) for v in reset[:, c]] + [0x000D]
        words += [0x000C] + [0x4000 | int(v) for v in signal[:, c]] + [0x000D]
    return words + [0x8000 | t1, 0x000F, 0x1000 | 1, 0x3000 | 2, 0x000A]


@pytest.mark.parametrize("step", [1, 3, 101, 10_000])
def test_decoder_cds_matches_reference_in_any_chunking(step: int) -> None:
    rng = np.random.default_rng(step)
    reset = rng.integers(0, 1024, (5, 7))
    signal = rng.integers(0, 1024, (5, 7))
    signal[0, 0] = 0
    words = frame_words(reset, signal, 100, 900) + frame_words(reset, signal, 1000, 1500, drop_column=True)
    raw = np.array(words, "<u2").tobytes()
    dec = DavisDecoder((7, 5))
    frames, events = [], 0
    for i in range(0, len(raw), step):
        d = dec.feed(raw[i:i + step])
        frames += d.frames
        events += len(d.t)
    assert len(frames) == 1 and events == 2  # the frame missing a column is dropped, counted
    f = frames[0]
    assert np.array_equal(f.image, ref_frame(reset, signal))
    assert (f.start, f.exposure_start, f.exposure_end, f.end, f.t) == (100, 100, 900, 900, 500)
    assert dec.counts["aps_frames"] == 1 and dec.counts["aps_bad_frames"] == 1


def test_roi_info_gives_a_smaller_frame_at_its_position() -> None:
    reset = np.full((2, 3), 900)
    signal = np.arange(6).reshape(2, 3) * 100 + 100
    roi = []
    for v in (4, 1, 6, 2):  # start column 4, start row 1, end column 6, end row 2
        roi += [0x5100 | (v >> 8), 0x5200 | (v & 0xFF)]
    words = frame_words(reset, signal, 10, 20)
    words[2:2] = roi  # right after the frame start, as the camera sends it
    f = DavisDecoder((8, 4)).feed(np.array(words, "<u2").tobytes()).frames[0]
    assert f.position == (4, 1) and np.array_equal(f.image, ref_frame(reset, signal))


@pytest.mark.parametrize("model,orientation", [("davis346", 0), ("davis240", 4 | 2), ("davis346", 1)])
def test_emulated_camera_frames_equal_what_it_saw(model: str, orientation: int) -> None:
    cam = EmulatedCamera(model, duration_us=85_000, speed=400.0, noise_hz=1.0, aps_orientation=orientation,
                         max_transfer=65_537)
    src, (sink,) = run_camera(cam, frame_interval_us=30_000, exposure_us=3000)
    fr = tectum.concat([q for q in sink.packets if q.kind == Kind.FRAMES])
    assert len(fr) == len(cam.truth.frames) == 3
    assert fr.images.shape[1:] == cam.sensor[::-1] and fr.images.dtype == np.uint8
    for k, (_sof, sexp, eexp, _eof) in enumerate(cam.truth.frame_times):
        assert np.array_equal(fr.images[k], cam.truth.frames[k])
        assert (fr.exposure_start[k], fr.exposure_end[k], fr.t[k]) == (sexp, eexp, (sexp + eexp) // 2)
    assert src.decoder.counts["aps_bad_frames"] == 0
    tt = cam.truth.events()[0]
    assert np.array_equal(sink.events().t, tt)  # frames do not disturb the events
    # libcaer's APS defaults were sent, then the requested timing (in ADC clock cycles)
    assert cam.config[(P.MOD_APS, P.APS_EXPOSURE)] == 3000 * cam.adc_clock_mhz
    assert cam.config[(P.MOD_APS, P.APS_GLOBAL_SHUTTER)] == 1
    assert cam.config[(P.MOD_APS, P.APS_RUN)] == 0  # stopped at close


def test_frames_off_and_default_timing() -> None:
    cam = EmulatedCamera("davis346", duration_us=50_000, speed=400.0, noise_hz=1.0)
    src, (sink,) = run_camera(cam, frames=False)
    assert not [q for q in sink.packets if q.kind == Kind.FRAMES and len(q)]
    assert cam.config[(P.MOD_APS, P.APS_FRAME_INTERVAL)] == P.APS_DEFAULT_INTERVAL_US * cam.adc_clock_mhz
    assert src.decoder.counts["aps_words_skipped"] > 0  # stray APS words without a frame start
