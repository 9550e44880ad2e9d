"""``filter.background_activity``: Delbruck's background-activity filter."""

from __future__ import annotations

from typing import Literal

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.core import cgutils, config
from numba.extending import intrinsic, overload

from tectum import EventPacket, Operator, concat, same_sensor

from ._ba_window import adaptive_kernel, adaptive_state
from ._state import NEVER, padded_timestamps, select

__all__ = ["BackgroundActivity", "background_activity_kernel", "background_activity_select"]

#: Relative times (µs) in the operator's int32 state stay below this; a
#: stream running longer moves the state's origin on (:meth:`BackgroundActivity._rebase`).
_SPAN_US = 1 << 30
#: A pixel of the int32 state that has never fired (relative time).
_NEVER32 = np.iinfo(np.int32).min
#: Events the vector compaction copies at once (one compress per column).
_LANES = 16


@njit(cache=True, nogil=True)
def background_activity_kernel(t, x, y, support, dt_us, keep):  # type: ignore[no-untyped-def]
    """Keep event ``i`` when one of its 8 neighbours fired at or after
    ``t[i] - dt_us``. ``support`` is a ``(1, H + 2, W + 2)`` int64 padded
    map holding, per pixel, the latest time (µs) one of its 8 neighbours
    fired: every event, kept or not, writes its time into its neighbours'
    cells (one read and 8 writes per event, no branches, and since times
    never decrease the latest write is the maximum). Writes ``keep`` (bool);
    returns the number kept."""
    m = support[0]
    n = 0
    for i in range(t.shape[0]):
        ti = t[i]
        xx = np.intp(x[i]) + 1
        yy = np.intp(y[i]) + 1
        ok = m[yy, xx] >= ti - dt_us
        keep[i] = ok
        n += ok
        m[yy - 1, xx - 1] = ti
        m[yy - 1, xx] = ti
        m[yy - 1, xx + 1] = ti
        m[yy, xx - 1] = ti
        m[yy, xx + 1] = ti
        m[yy + 1, xx - 1] = ti
        m[yy + 1, xx] = ti
        m[yy + 1, xx + 1] = ti
    return n


def _recent(m, a, c, b, lim):  # type: ignore[no-untyped-def]
    """Whether one of an event's 8 neighbours fired at or after ``lim``
    (µs, as the map holds them) in the flat padded map ``m``: cells
    ``a .. a + 2`` (the row above), ``c`` and ``c + 2`` (its own row, left
    and right) and ``b .. b + 2`` (the row below). Compiled, three 4-lane
    vector loads (from ``a``, ``c`` and ``b``) compared with ``lim`` at
    once, the event's own cell and each fourth lane masked out: ``m`` must
    hold one cell after ``b + 2``, and ``lim`` fit its dtype. This is the
    plain form (``NUMBA_DISABLE_JIT``)."""
    return max(m[a], m[a + 1], m[a + 2], m[c], m[c + 2], m[b], m[b + 1], m[b + 2]) >= lim


@intrinsic
def _recent_ir(typingctx, m, a, c, b, lim):  # type: ignore[no-untyped-def]
    sig = types.boolean(m, types.uintp, types.uintp, types.uintp, types.int64)

    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
        arr = context.make_array(signature.args[0])(context, builder, args[0])
        elt = context.get_data_type(signature.args[0].dtype)
        vec, lanes = ir.VectorType(elt, 4), ir.VectorType(ir.IntType(1), 4)

        def recent(k):  # type: ignore[no-untyped-def]
            ptr = builder.bitcast(builder.gep(arr.data, [k]), vec.as_pointer())
            return builder.icmp_signed(">=", builder.load(ptr, align=elt.width // 8), limits)

        lim = builder.trunc(args[4], elt) if elt.width < 64 else args[4]
        one = builder.insert_element(ir.Constant(vec, None), lim, ir.Constant(ir.IntType(32), 0))
        splat = ir.Constant(ir.VectorType(ir.IntType(32), 4), [0] * 4)
        limits = builder.shuffle_vector(one, ir.Constant(vec, None), splat)
        rows = builder.and_(builder.or_(recent(args[1]), recent(args[3])), ir.Constant(lanes, [1, 1, 1, 0]))
        own_row = builder.and_(recent(args[2]), ir.Constant(lanes, [1, 0, 1, 0]))
        bits = builder.bitcast(builder.or_(rows, own_row), ir.IntType(4))
        return builder.icmp_unsigned("!=", bits, ir.Constant(ir.IntType(4), 0))

    return sig, codegen


@overload(_recent)
def _recent_compiled(m, a, c, b, lim):  # type: ignore[no-untyped-def]
    return lambda m, a, c, b, lim: _recent_ir(m, a, c, b, lim)


def _compress(dst, n, src, i, keep):  # type: ignore[no-untyped-def]
    """Copy ``src[i + k]`` for each ``k < 16`` where ``keep[i + k]`` to
    ``dst[n:]`` in order; returns how many. Compiled, one masked compress
    store (see :func:`_vector_compress`); this is the plain form."""
    kept = 0
    for k in range(_LANES):
        if keep[i + k]:
            dst[n + kept] = src[i + k]
            kept += 1
    return kept


@intrinsic
def _compress_ir(typingctx, dst, n, src, i, keep):  # type: ignore[no-untyped-def]
    sig = types.intp(dst, types.intp, src, types.intp, keep)

    def codegen(context, builder, signature, args):  # type: ignore[no-untyped-def]
        d_ty, _, s_ty, _, k_ty = signature.args
        d, s, k = (context.make_array(ty)(context, builder, v) for ty, v in zip((d_ty, s_ty, k_ty), args[::2]))
        elt = context.get_data_type(s_ty.dtype)
        vec, bytes_ = ir.VectorType(elt, _LANES), ir.VectorType(ir.IntType(8), _LANES)
        flags = builder.load(builder.bitcast(builder.gep(k.data, [args[3]]), bytes_.as_pointer()), align=1)
        mask = builder.icmp_unsigned("!=", flags, ir.Constant(bytes_, None))
        values = builder.load(builder.bitcast(builder.gep(s.data, [args[3]]), vec.as_pointer()), align=1)
        out = builder.gep(d.data, [args[1]])
        if REGISTER_COMPRESS:
            _register_compress(builder, values, mask, out, elt)
        else:
            store = cgutils.get_or_insert_function(
                builder.module, ir.FunctionType(ir.VoidType(), [vec, out.type, mask.type]),
                f"llvm.masked.compressstore.v{_LANES}i{elt.width}")
            builder.call(store, [values, out, mask])
        return builder.zext(_popcount(builder, mask), ir.IntType(64))

    return sig, codegen


def _popcount(builder, mask):  # type: ignore[no-untyped-def]
    """The number of set lanes of an ``<N x i1>`` mask, as an ``iN``."""
    word = ir.IntType(mask.type.count)
    popcount = cgutils.get_or_insert_function(builder.module, ir.FunctionType(word, [word]),
                                              f"llvm.ctpop.i{mask.type.count}")
    return builder.call(popcount, [builder.bitcast(mask, word)])


def _register_compress(builder, values, mask, out, elt):  # type: ignore[no-untyped-def]
    """Store the lanes of ``values`` selected by ``mask`` to ``out`` in
    order as AVX-512 register compresses (at most 512 bits each) followed
    by plain full-width stores: each store writes a whole vector from its
    first kept lane on, so up to ``_LANES`` elements from ``out`` (the
    caller's output index never passes its input index, so these stay
    inside the output). The single-instruction compress to memory that
    ``llvm.masked.compressstore`` becomes with AVX-512 is microcoded on AMD
    Zen 4: the whole kernel took 8.4 ns an event there, against 5.4 with
    every event written and 2.7 with these (64 ki events, half kept)."""
    per = min(_LANES, 512 // elt.width)
    i32 = ir.IntType(32)
    for start in range(0, _LANES, per):
        lanes = ir.Constant(ir.VectorType(i32, per), list(range(start, start + per)))
        part = builder.shuffle_vector(values, ir.Constant(values.type, None), lanes)
        keep = builder.shuffle_vector(mask, ir.Constant(mask.type, None), lanes)
        vec = part.type
        fn = cgutils.get_or_insert_function(builder.module, ir.FunctionType(vec, [vec, vec, keep.type]),
                                            f"llvm.x86.avx512.mask.compress.v{per}i{elt.width}")
        packed = builder.call(fn, [part, ir.Constant(vec, None), keep])
        builder.store(packed, builder.bitcast(out, vec.as_pointer()), align=1)
        if start + per < _LANES:
            out = builder.gep(out, [builder.zext(_popcount(builder, keep), ir.IntType(64))])


@overload(_compress)
def _compress_compiled(dst, n, src, i, keep):  # type: ignore[no-untyped-def]
    if (dst.layout, src.layout, keep.layout) != ("C", "C", "C"):  # the vector loads and store need them
        return _compress
    return lambda dst, n, src, i, keep: _compress_ir(dst, n, src, i, keep)


def _vector_compress() -> bool:
    """Whether numba compiles for this CPU and it has AVX2: there LLVM's
    masked compress store (one instruction with AVX-512 F and VBMI2, a
    short sequence with AVX2) makes the whole kernel 1.65-1.83x faster
    than writing every event (compiled for this CPU or for Haswell,
    interleaved, loaded); compiled for plain SSE, 1.1-1.9x slower; and a
    target chosen with ``NUMBA_CPU_NAME`` (a portable cache) may not be
    this CPU."""
    if config.CPU_NAME or config.CPU_FEATURES:
        return False
    try:
        import llvmlite.binding as llvm

        features = llvm.get_host_cpu_features()
    except RuntimeError:
        return False
    return bool(features.get("avx2"))


def _register_compress_ok() -> bool:
    """Whether the compresses can go through AVX-512 registers (F and VL
    for 32- and 64-bit lanes, VBMI2 for 8- and 16-bit ones): see
    :func:`_register_compress`."""
    if not _vector_compress():
        return False
    import llvmlite.binding as llvm

    features = llvm.get_host_cpu_features()
    return all(features.get(f) for f in ("avx512f", "avx512vl", "avx512bw", "avx512vbmi2"))


#: :func:`background_activity_select` compacts with vector compresses here.
VECTOR_COMPRESS = _vector_compress()
#: The compresses go through AVX-512 registers (:func:`_register_compress`).
REGISTER_COMPRESS = _register_compress_ok()
#: Events per kernel call: a packet the engine joined (up to 2^18 events)
#: is filtered in calls of this many, so the events the copy reads back
#: are still in the L2 cache (8 % faster at 2^18, interleaved, loaded).
_CALL_EVENTS = 1 << 16


@njit(cache=True, nogil=True)
def background_activity_select(t, x, y, p, last, base, dt_us, keep, ot, ox, oy, op, vector):  # type: ignore[no-untyped-def]
    """The filter of :func:`background_activity_kernel` and the selection
    of its output: event ``i`` is kept when the latest time one of its 8
    neighbours fired is at or after ``t[i] - dt_us``. ``last`` is a
    ``(1, H + 3, W + 2)`` padded map (int32 or int64) of each pixel's own
    latest time, relative to ``base`` µs (pixel ``(x, y)`` at
    ``[0, y + 1, x + 1]``; the second border row below is read, never
    written: see :func:`_recent`). Writes ``keep`` (bool, per
    event) and returns how many were kept; unless all were, copies them to
    the front of ``ot, ox, oy, op`` (one spare slot each).

    Two passes, both without branches on the data: the filter (three
    vector compares and one write per event), then the copy: with
    ``vector`` (see :data:`VECTOR_COMPRESS`) 16 events per column at once,
    else every event written and the output index advanced by its keep
    bit."""
    w2 = np.uintp(last.shape[2])
    m = last.reshape(-1)
    one = np.uintp(1)
    n = 0
    for i in range(t.shape[0]):
        rel = t[i] - base
        c = (np.uintp(y[i]) + one) * w2 + np.uintp(x[i])  # the left neighbour's cell; the pixel's is c + 1
        ok = _recent(m, c - w2, c, c + w2, rel - dt_us)
        keep[i] = ok
        n += int(ok)
        m[c + one] = rel
    if n == t.shape[0]:
        return n
    n = 0
    i = 0
    if vector:
        while i + _LANES <= t.shape[0]:
            _compress(ot, n, t, i, keep)
            _compress(ox, n, x, i, keep)
            _compress(oy, n, y, i, keep)
            n += _compress(op, n, p, i, keep)
            i += _LANES
    for j in range(i, t.shape[0]):
        ot[n] = t[j]
        ox[n] = x[j]
        oy[n] = y[j]
        op[n] = p[j]
        n += int(keep[j])
    return n


class BackgroundActivity(Operator):
    """Background-activity filter (Delbruck 2008): keep an event when at
    least one of its 8 neighbours fired within the last ``dt_us`` µs
    (inclusive); every event, kept or dropped, refreshes its pixel's time.

    Default ``dt_us = 6000``: an edge moving at 170 px/s or faster reaches
    the next pixel within 6 ms, so (measured on the ``pattern:`` bars at
    200 px/s) over 90 % of signal passes, while Poisson noise of rate ``r``
    Hz/px passes with probability ``1 - exp(-8 r dt)``: 9 % at 2 Hz/px.
    Slower scenes need a longer ``dt_us``.

    ``dt_us="auto"`` chooses the window online from the stream (see
    :mod:`tectum.plugins.filter._ba_window`): about 1.5 times the 90th
    percentile of the signal's neighbour intervals (µs since a neighbour
    fired), the noise's exponential share of them fitted on the intervals
    of 50 ms or more and taken out first; 6 ms (the fixed default) until
    the first estimate and whenever under 5 % of the intervals are left
    (no motion, or a signal too sparse to tell from the noise); 0.3-50 ms,
    recomputed every 256 events; ``dt_us`` then reads the window in use.
    On the bench's 28 labelled conditions (``tectum bench filters``: 5
    simulator scenes and the ``pattern:`` bars at 2 speeds, 0.1-10 Hz/px
    noise) it keeps 90 % of the signal in 25 where 6 ms does in 16, and
    in the other 3 more than 6 ms does; it passes a little more noise on
    average (0.405 against 0.385): more where the scene is slow (which
    needs a longer window), less where it is fast. Not the default: about
    25 ns an event (loaded) against 3-4 for a fixed window, and it learns
    from the whole stream, so it does not shard (:meth:`memory_us` is
    None). Its state: an int64 map (8 x (W + 2) x (H + 2) bytes), 168
    histogram bins and six numbers.

    State: one int32 per pixel (the latest time it fired, relative to an
    origin that moves on every 2^30 µs) plus a border of one pixel and a
    second row below, 4 x (W + 2) x (H + 3) bytes (about 366 kB for
    346x260; int64 and twice that for a ``dt_us`` of 2^29 µs or more), and
    one byte per event of the largest packet (the keep flags). The kernel
    (:func:`background_activity_select`) filters, then copies the kept
    events, neither pass with a branch on the data: its speed does not
    depend on how many pass.
    """

    name = "filter.background_activity"

    def __init__(self, dt_us: int | Literal["auto"] = 6000) -> None:
        self.auto = dt_us == "auto"
        if self.auto:
            hist, weight, state = adaptive_state()
            self._hist, self._weight, self._state = hist, weight, state
            dt_us = int(state[1])
        elif isinstance(dt_us, str) or dt_us < 0:
            raise ValueError(f"dt_us must be an integer >= 0 or 'auto', got {dt_us!r}")
        self.dt_us = int(dt_us)
        self.last: np.ndarray | None = None
        self.base = 0  # µs: the origin of the times in ``last``
        self._keep = np.empty(0, np.bool_)  # the kernel's keep flags, reused from packet to packet
        self._sensor = (0, 0)  # (width, height) px that ``last`` was made for

    def memory_us(self) -> int | None:
        """Only neighbours' times within ``dt_us`` count (time sharding);
        with ``dt_us="auto"`` the window is learned from the whole stream
        (None: no sharding)."""
        return None if self.auto else self.dt_us

    def process(self, packet: EventPacket) -> list[EventPacket]:
        m = len(packet)
        if m == 0:
            return [packet]
        if self.auto:
            return [self._adaptive(packet)]
        if self.last is None:
            self._start(packet)
        elif packet.sensor is not self._sensor:
            self._sensor = same_sensor(self.name, self._sensor, packet)
        if packet.t_end - self.base > _SPAN_US and self.last.dtype == np.int32:  # type: ignore[union-attr]
            if packet.t_end - packet.t_start > _SPAN_US // 2:  # one packet spans minutes: in parts
                step = _SPAN_US // 4
                parts = [packet.slice_time(a, a + step) for a in range(packet.t_start, packet.t_end, step)]
                return [concat([q for part in parts for q in self.process(part)])]
            self._rebase(packet.t_start)
        if len(self._keep) < m:
            self._keep = np.empty(m, np.bool_)
        keep = self._keep[:m]
        cols = (packet.t, packet.x, packet.y, packet.p)
        out = (np.empty(m + 1, np.int64), np.empty(m + 1, np.uint16), np.empty(m + 1, np.uint16),
               np.empty(m + 1, np.int8))
        if m <= _CALL_EVENTS:
            n = background_activity_select(*cols, self.last, self.base, self.dt_us, keep, *out, VECTOR_COMPRESS)
            whole = n == m
        else:
            n, whole = self._in_calls(cols, keep, out)
        if whole:
            return [packet]
        ot, ox, oy, op = (o[:n] for o in out)
        return [EventPacket._trusted(ot, ox, oy, op, packet.sensor, packet.t_start, packet.t_end,
                                     {k: v[keep] for k, v in packet.columns.items()}, packet.checked)]

    def _adaptive(self, packet: EventPacket) -> EventPacket:
        """``dt_us="auto"``: the kernel of :mod:`._ba_window` on ``packet``
        (int64 times: no origin to move)."""
        if self.last is None:
            self._sensor = packet.sensor
            self.last = padded_timestamps(packet.sensor)
        elif packet.sensor is not self._sensor:
            self._sensor = same_sensor(self.name, self._sensor, packet)
        keep = np.empty(len(packet), np.bool_)
        adaptive_kernel(packet.t, packet.x, packet.y, self.last, self._hist, self._weight, self._state, keep)
        self.dt_us = int(self._state[1])
        return select(packet, keep)

    def _in_calls(self, cols: tuple[np.ndarray, ...], keep: np.ndarray,
                  out: tuple[np.ndarray, ...]) -> tuple[int, bool]:
        """The kernel over the columns ``cols`` in calls of
        :data:`_CALL_EVENTS` events: how many were kept (in ``out``, unless
        all were) and whether all were. The kernel copies nothing from a
        call that keeps all its events: copied here once one did not."""
        m = len(keep)
        n, whole = 0, True
        for a in range(0, m, _CALL_EVENTS):
            b = min(a + _CALL_EVENTS, m)
            got = background_activity_select(*(c[a:b] for c in cols), self.last, self.base, self.dt_us, keep[a:b],
                                             *(o[n:] for o in out), VECTOR_COMPRESS)
            if got == b - a and not whole:
                for o, c in zip(out, cols):
                    o[n:n + got] = c[a:b]
            elif got < b - a and whole:  # the first drop: the events before it (n == a) go first
                for o, c in zip(out, cols):
                    o[:a] = c[:a]
                whole = False
            n += got
        return n, whole

    def _start(self, packet: EventPacket) -> None:
        """The state, at the first packet: int32 times relative to its start
        (int64 from 0 when ``dt_us`` reaches 2^29 µs)."""
        w, h = self._sensor = packet.sensor
        if self.dt_us < _SPAN_US // 2:
            self.last, self.base = np.full((1, h + 3, w + 2), _NEVER32, np.int32), packet.t_start
        else:
            self.last, self.base = np.full((1, h + 3, w + 2), NEVER, np.int64), 0

    def _rebase(self, base: int) -> None:
        """Move the int32 state's origin on to ``base`` µs: times more than
        2^31 µs before it become "never" (far beyond ``dt_us``)."""
        shifted = self.last.astype(np.int64) - (base - self.base)  # type: ignore[union-attr]
        self.last = np.maximum(shifted, _NEVER32).astype(np.int32)
        self.base = base
