"""The built-in suites of ``tectum bench``, one module each, every one with
``run(out: Path, quick: bool) -> dict``: ``engine`` (scheduler overhead and
latency), ``io`` (file decode/encode), ``filters`` (speed and denoising
accuracy), ``flow`` (speed and accuracy of flow and lifetime), ``simulate``
(generation speed) and ``net`` (TCP/UDP streaming). They are imported only
when run (see :mod:`tectum.evaluation.plugin`)."""
