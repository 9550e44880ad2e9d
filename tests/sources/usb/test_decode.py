"""The USB word decoders against slow, obvious reference decoders."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from tectum.sources.usb._decode import DavisDecoder, Dvs128Decoder


def ref_dvs128(buf: bytes) -> list[tuple[int, int, int, int]]:
    out, wrap, base, last = [], 0, 0, -1
    for i in range(0, len(buf) - 3, 4):
        addr = buf[i] | buf[i + 1] << 8
        ts = buf[i + 2] | buf[i + 3] << 8
        if buf[i + 3] & 0x80:
            wrap += 1 << 14
        elif buf[i + 3] & 0x40:
            wrap, base = 0, (last + 1 if last >= 0 else 0)
        else:
            t = max(base + wrap + ts, last)
            last = t
            if not addr & 0x8000:
                out.append((t, 127 - (addr >> 1 & 127), 127 - (addr >> 8 & 127), 1 if addr & 1 == 0 else -1))
    return out


def ref_davis(words: list[int], w: int, h: int) -> list[tuple[int, int, int, int]]:
    out, wrap, cur, base, last, ly = [], 0, 0, 0, -1, 0
    for v in words:
        if v & 0x8000:
            cur = wrap + (v & 0x7FFF)
            continue
        code, data = v >> 12 & 7, v & 0xFFF
        if code == 0 and data == 1:
            wrap, cur, base = 0, 0, (last + 1 if last >= 0 else 0)
        elif code == 1 and data < h:
            ly = data
        elif code in (2, 3) and data < w:
            t = max(base + cur, last)
            last = t
            out.append((t, data, ly, 1 if code == 3 else -1))
        elif code == 7:
            wrap += data << 15
            cur = wrap
    return out


def as_tuples(d) -> list[tuple[int, int, int, int]]:
    return list(zip(d.t.tolist(), d.x.tolist(), d.y.tolist(), d.p.tolist()))


@settings(max_examples=25, deadline=None)
@given(st.binary(min_size=0, max_size=400), st.lists(st.integers(1, 50), max_size=6))
def test_dvs128_matches_reference_in_any_chunking(buf: bytes, cuts: list[int]) -> None:
    dec = Dvs128Decoder()
    got, pos = [], 0
    for c in cuts + [len(buf)]:
        got += as_tuples(dec.feed(buf[pos:pos + c]))
        pos += c
    got += as_tuples(dec.feed(buf[pos:]))
    assert got == ref_dvs128(buf[: len(buf) - len(buf) % 4])


@settings(max_examples=25, deadline=None)
@given(st.lists(st.one_of(st.integers(0, 0xFFFF), st.sampled_from([0x0001, 0x7001, 0x7003, 0x8000, 0xFFFF])),
                max_size=300), st.integers(1, 37))
def test_davis_matches_reference_in_any_chunking(words: list[int], step: int) -> None:
    raw = np.array(words, "<u2").tobytes()
    dec = DavisDecoder((240, 180))
    got = []
    for i in range(0, len(raw), step):
        got += as_tuples(dec.feed(raw[i:i + step]))
    assert got == ref_davis(words, 240, 180)
    assert np.all(np.diff([g[0] for g in got]) >= 0) if got else True


def test_davis_wrap_reset_and_counts() -> None:
    dec = DavisDecoder((346, 260))
    words = [0x8000 | 100, 0x1000 | 5, 0x3000 | 7,  # t=100 (x=7, y=5, ON)
             0x7002, 0x8000 | 3, 0x2000 | 9,        # two wraps: t = 65536 + 3, OFF
             0x0001, 0x8000 | 10, 0x3000 | 1,       # reset: t = 65539 + 1 + 10
             0x1000 | 300]                           # a bad row (>= 260)
    d = dec.feed(np.array(words, "<u2").tobytes())
    assert d.t.tolist() == [100, 65539, 65550]
    assert d.x.tolist() == [7, 9, 1] and d.y.tolist() == [5, 5, 5] and d.p.tolist() == [1, -1, 1]
    c = dec.counts
    assert c["wraps"] == 1 and c["resets"] == 1 and c["bad_address"] == 1


def test_davis_imu_sample_scaled_to_si_units() -> None:
    dec = DavisDecoder((346, 260))
    vals = [16384, 0, -16384, 340, 0, 3277, -3277]  # scale 0: 16384 LSB/g (±2 g), 131.072 LSB per °/s
    words = [0x8000 | 50, 0x0005, 0x5300 | (0b111 << 5)]
    for v in vals:
        v &= 0xFFFF
        words += [0x5000 | v >> 8, 0x5000 | v & 0xFF]
    words.append(0x0007)
    d = dec.feed(np.array(words, "<u2").tobytes())
    assert d.imu_t.tolist() == [50]
    np.testing.assert_allclose(d.imu[0, :3], [9.80665, 0, -9.80665], rtol=1e-6)
    np.testing.assert_allclose(d.imu[0, 3], 36.0)
    np.testing.assert_allclose(d.imu[0, 4:], [0, 25 * np.pi / 180, -25 * np.pi / 180], rtol=1e-3)
