"""Display sinks: a live view in the browser (``http://HOST:PORT``), video
files (``.mp4``, ``.avi``), PNG snapshots (``.png``) and a frame callback."""

from __future__ import annotations

from tectum.hookspecs import hookimpl


@hookimpl
def tectum_register_sinks(registry) -> None:  # type: ignore[no-untyped-def]
    from .files import FrameCallbackSink, PngSink, VideoSink
    from .live import LiveViewSink

    for cls in (LiveViewSink, VideoSink, PngSink, FrameCallbackSink):
        registry.add_sink(cls)
