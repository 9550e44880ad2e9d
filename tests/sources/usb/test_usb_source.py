"""The USB source through pyusb's real code path, against the emulated camera."""

from __future__ import annotations

import json

import numpy as np
import pytest

import tectum
from tectum import Kind
from tectum.cli import main as cli
from tectum.sources.usb import _protocol as P
from tectum.sources.usb._device import DeviceDisconnected, list_devices
from tectum.sources.usb.emulated import EmulatedBackend, EmulatedCamera
from tectum.sources.usb.source import UsbSource
from tectum.testing import ListSink

from helpers import run_camera

SMALL = dict(duration_us=110_000, speed=400.0, noise_hz=1.0)


def run(cam: EmulatedCamera, **kw) -> tuple[UsbSource, ListSink, ListSink]:
    """(source, events sink, IMU sink: none is attached for a DVS128)."""
    src, sinks = run_camera(cam, sinks=1 if cam.model == "dvs128" else 2, **kw)
    return src, sinks[0], sinks[1] if len(sinks) > 1 else ListSink()


@pytest.mark.parametrize("model", ["davis346", "davis240", "dvs128"])
def test_stream_equals_what_the_camera_sent(model: str) -> None:
    cam = EmulatedCamera(model, reset_at_us=40_000, overrun_reads=(2, 5), max_transfer=1001, **SMALL)
    src, sink, _ = run(cam)
    ev = sink.events()
    tt, tx, ty, tp = cam.truth.events()
    assert len(ev) == len(tt) > 1000
    assert np.array_equal(ev.x, tx) and np.array_equal(ev.y, ty) and np.array_equal(ev.p, tp)
    pre = tt < 40_000
    assert np.array_equal(ev.t[pre], tt[pre])  # device time before the reset, wraps included
    after = ev.t[~pre]
    # after the reset time goes on just past the last event, spacing kept
    assert after[0] == ev.t[pre][-1] + 1 + (tt[~pre][0] - 40_000)
    assert np.array_equal(after - after[0], tt[~pre] - tt[~pre][0])
    assert src.counts["overruns"] == 2
    c = src.decoder.counts
    assert c["resets"] == 1 and c["wraps"] >= 2 and c["nonmonotonic"] == 0


def test_davis_configuration_and_imu() -> None:
    cam = EmulatedCamera("davis346", fx2=True, **SMALL)
    src, _, imu = run(cam)
    assert src.camera is None  # closed
    assert cam.config[(P.MOD_BIAS, 10)] == P.coarse_fine(4, 39, n_type=True)  # DiffBn sent
    for key in ((P.MOD_USB, P.USB_RUN), (P.MOD_MUX, P.MUX_RUN), (P.MOD_DVS, P.DVS_RUN)):
        assert key in cam.config
    assert cam.config[(P.MOD_DVS, P.DVS_RUN)] == 0  # stopped at close
    got = tectum.concat([q for q in imu.packets if q.kind == Kind.IMU])
    assert got.t.tolist() == cam.truth.imu_t
    np.testing.assert_allclose(got.accel, np.array(cam.truth.accel), rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(got.gyro, np.array(cam.truth.gyro), rtol=1e-9, atol=1e-9)


def test_dvs128_biases_sent() -> None:
    cam = EmulatedCamera("dvs128", **SMALL)
    run(cam)
    assert len(cam.biases) == 36 and cam.biases[:3] == (1992).to_bytes(3, "big")
    reqs = [r[1] for r in cam.control_log]
    assert reqs.index(P.DVS128_REQ_BIASES) < reqs.index(P.DVS128_REQ_START) < reqs.index(P.DVS128_REQ_STOP)


def test_unplug_raises_a_clear_error_after_delivering_what_was_read() -> None:
    cam = EmulatedCamera("davis346", disconnect_after=60_000, **SMALL)
    src = UsbSource("usb:", backend=EmulatedBackend(cam), idle_s=0.1)
    p = tectum.Pipeline()
    sink = ListSink()
    p.sink(sink, p.source(src, id="cam"))
    with pytest.raises(tectum.NodeError, match="disconnected") as ei:
        tectum.run(p)
    assert isinstance(ei.value.__cause__, DeviceDisconnected)
    n = len(sink.events())
    tt = cam.truth.events()[0]
    assert n > 0 and src.counts["disconnects"] == 1
    # every complete word read before the unplug was delivered, in order
    assert np.array_equal(sink.events().t, tt[:n])


def test_unplug_with_end_keeps_the_file(tmp_path) -> None:
    cam = EmulatedCamera("dvs128", disconnect_after=40_000, **SMALL)
    out = tmp_path / "cam.npz"
    p = tectum.Pipeline()
    p.sink(str(out), p.source(UsbSource("usb:", backend=EmulatedBackend(cam), on_disconnect="end", idle_s=0.1)))
    tectum.run(p)
    t = np.load(out)["t"]
    assert 0 < len(t) <= 10_000  # at most 40 000 bytes of 4-byte words (some are wraps)
    assert np.array_equal(t, cam.truth.events()[0][: len(t)])


def test_reconnect_goes_on_with_monotonic_time() -> None:
    cam = EmulatedCamera("davis346", disconnect_after=50_000, replug_after_polls=3, **SMALL)
    src, sink, _ = run(cam, on_disconnect="reconnect", reconnect_s=3.0)
    ev = sink.events()
    tt = cam.truth.events()[0]
    assert src.counts["reconnects"] == 1 and src.counts["disconnects"] == 1
    assert np.all(np.diff(ev.t) >= 0)
    # the pattern went on from the replug (what the camera held unsent when unplugged is gone)
    after = tt >= cam.replugged_at
    n_before = len(ev) - int(after.sum())
    assert n_before > 0 and np.array_equal(ev.t[:n_before], tt[:n_before])
    assert np.array_equal(np.diff(ev.t[n_before:]), np.diff(tt[after]))


def test_devices_lists_emulated_cameras_and_exits_0_without_any(capsys) -> None:
    be = EmulatedBackend(EmulatedCamera("davis346", serial="A1"), EmulatedCamera("dvs128", serial="B2", address=7))
    found = list_devices(be)
    assert [(d.model, d.serial, d.sensor) for d in found] == [("DAVIS FX3", "A1", (346, 260)),
                                                              ("DVS128", "B2", (128, 128))]
    assert list_devices(EmulatedBackend()) == []
    assert cli(["devices", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["devices"] == [] and out["reason"]
    assert cli(["devices", "--emulate", "dvs128"]) == 0
    assert "DVS128" in capsys.readouterr().out


def test_cli_runs_an_emulated_camera(tmp_path) -> None:
    out = tmp_path / "e.npz"
    assert cli(["run", "usb:?emulate=dvs128&duration_us=50000", "--sink", str(out)]) == 0
    t = np.load(out)["t"]
    assert len(t) > 0 and t[-1] - t[0] < 60_000
