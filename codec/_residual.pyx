"""Kernel of the residual layer (ATM.md §4.8): an adaptive binary range coder and the
per-pixel loop that predicts each level from its decoded causal neighbours, forms the
contexts and codes the residual. Encoder and decoder share every step of the model, so
they stay in lock step. Each plane's adaptive state (probabilities, the row above) is
a `Plane` object its owner keeps from band to band; each chunk has its own coder. The
loops release the GIL; the decoder checks every level it makes against the plane's
range and never reads past the chunk (status codes; codec.residual turns them into
CorruptError)."""

from libc.stdint cimport int64_t, uint8_t, uint16_t, uint32_t, uint64_t
from libc.stdlib cimport free, malloc
from libc.string cimport memcpy

from codec.rangecoder cimport RangeEncoder, rc_begin, rc_flush, rc_shift_low

import numpy as np

#: Contexts: activity bucket (0..BUCKETS-1) x local shape (0..SHAPES-1): the signs of
#: three neighbour differences (27) x the bucket of their magnitudes' sum.
DEF BUCKETS = 12
#: Unary nodes of a token (tokens 0..TOKENS-1; the last has no terminating node):
#: 16-bit planes have magnitudes below 2^16, wide planes (binary32 keys, ATM.md
#: §4.10) below 2^32.
DEF TOKENS = 40
DEF NODES = TOKENS - 1
DEF WIDE_TOKENS = 72
DEF WIDE_NODES = WIDE_TOKENS - 1
DEF SHAPES = 27 * BUCKETS
DEF CONTEXTS = BUCKETS * SHAPES
DEF SIGN_CONTEXTS = 9
#: Interpolation (predictor 1): contexts are the pyramid's levels, 0..LEVELS-1.
DEF LEVELS = 32
DEF MODELS = CONTEXTS * NODES + SIGN_CONTEXTS + LEVELS * NODES + LEVELS
DEF WIDE_MODELS = CONTEXTS * WIDE_NODES + SIGN_CONTEXTS + LEVELS * WIDE_NODES + LEVELS
#: Adaptation: the steady estimate moves by at most 1/2^MAX_SHIFT of the way to the
#: coded bit, the fast one by at least 1/2^FAST_SHIFT.
DEF MAX_SHIFT = 8
DEF FAST_SHIFT = 4
DEF TOP = 1 << 24

cpdef enum Status:
    RESIDUAL_OK = 0
    RESIDUAL_RANGE = 1     # a decoded level lies outside 0..max_level
    RESIDUAL_OVERRUN = 2   # the coder read past the end of the chunk
    RESIDUAL_TRAILING = 3  # the coder left bytes of the chunk unread
    RESIDUAL_MEMORY = 4

MODEL_COUNT = MODELS
TOKEN_COUNT = TOKENS
WIDE_MODEL_COUNT = WIDE_MODELS
WIDE_TOKEN_COUNT = WIDE_TOKENS
BUCKET_COUNT = BUCKETS
SHIFT_LIMIT = MAX_SHIFT


cdef inline int _shift(uint8_t n) noexcept nogil:
    # floor(log2(n + 2)), at most MAX_SHIFT: fast at first, then steadier
    cdef int s = 0
    cdef uint32_t v = n + 2
    while v > 1:
        v >>= 1
        s += 1
    return s if s < MAX_SHIFT else MAX_SHIFT


cdef inline void _update(uint16_t* p, uint8_t* n, int bit, int64_t stride) noexcept nogil:
    # two estimates of one model, `stride` (the plane's model count) apart: a fast
    # one and a steady one
    cdef int s = _shift(n[0])
    cdef int f = s if s < FAST_SHIFT else FAST_SHIFT
    if bit:
        p[0] = p[0] - (p[0] >> f)
        p[stride] = p[stride] - (p[stride] >> s)
    else:
        p[0] = p[0] + ((65536 - p[0]) >> f)
        p[stride] = p[stride] + ((65536 - p[stride]) >> s)
    if n[0] < 255:
        n[0] += 1


cdef struct Encoder:
    # LZMA's range encoder (codec/rangecoder.pxd, shared with the HOLE chunk's coder)
    # and the plane's model count: the two estimates of a model lie that far apart
    RangeEncoder rc
    int64_t stride


cdef inline void _encode_bit(Encoder* e, uint16_t* p, uint8_t* n, int bit) noexcept nogil:
    # p NULL: a raw bit, probability one half and no model
    cdef uint32_t bound = (e.rc.rng >> 16) * (((p[0] + p[e.stride]) >> 1) if p != NULL else 32768)
    if bit:
        e.rc.low += bound
        e.rc.rng -= bound
    else:
        e.rc.rng = bound
    while e.rc.rng < TOP:
        e.rc.rng <<= 8
        rc_shift_low(&e.rc)
    if n != NULL:
        _update(p, n, bit, e.stride)


cdef struct Decoder:
    uint32_t code
    uint32_t rng
    const uint8_t* buf
    size_t size
    size_t at
    int overrun
    int64_t stride


cdef inline uint8_t _next(Decoder* d) noexcept nogil:
    if d.at < d.size:
        d.at += 1
        return d.buf[d.at - 1]
    d.overrun = 1
    d.at += 1
    return 0


cdef inline int _decode_bit(Decoder* d, uint16_t* p, uint8_t* n) noexcept nogil:
    cdef uint32_t bound = (d.rng >> 16) * (((p[0] + p[d.stride]) >> 1) if p != NULL else 32768)
    cdef int bit
    if d.code < bound:
        d.rng = bound
        bit = 0
    else:
        d.code -= bound
        d.rng -= bound
        bit = 1
    while d.rng < TOP:
        d.rng <<= 8
        d.code = (d.code << 8) | _next(d)
    if n != NULL:
        _update(p, n, bit, d.stride)
    return bit


cdef inline int _bucket(int64_t v) noexcept nogil:
    # 0 for 0, then 1, 2, 3-4, 5-8, 9-16, ... : 1 + bit length of v - 1, capped
    cdef int b = 1
    if v <= 0:
        return 0
    v -= 1
    while v:
        v >>= 1
        b += 1
    return b if b < BUCKETS else BUCKETS - 1


cdef inline int64_t _abs(int64_t v) noexcept nogil:
    return -v if v < 0 else v


cdef inline int _sign(int64_t v) noexcept nogil:
    return (v > 0) - (v < 0)


cdef class Plane:
    """The adaptive state of one plane (channel) of a residual layer across its bands:
    every model's probability and count, and the last coded row's hole-filled levels
    and residuals (the next band's causal neighbours)."""

    cdef uint16_t[::1] prob
    cdef uint8_t[::1] count
    cdef int64_t[::1] above
    cdef int64_t[::1] above_residual
    cdef readonly int width
    cdef readonly bint started
    #: wide: the plane codes 32-bit samples (binary32 keys), with WIDE_NODES nodes a
    #: token; else 16-bit ones with NODES
    cdef readonly bint wide
    cdef readonly int nodes
    cdef readonly int64_t models

    def __init__(self, int width, bint wide=False):
        if width < 1:
            raise ValueError("a plane is at least one pixel wide")
        self.width = width
        self.wide = wide
        self.nodes = WIDE_NODES if wide else NODES
        self.models = WIDE_MODELS if wide else MODELS
        self.prob = np.full(2 * self.models, 32768, np.uint16)  # fast estimates, then steady ones
        self.count = np.zeros(self.models, np.uint8)
        self.above = np.zeros(width, np.int64)
        self.above_residual = np.zeros(width, np.int64)
        self.started = False

    def copy(self):
        """An independent copy (the encoder tries each predictor on one)."""
        other = Plane(self.width, self.wide)
        other.prob[:] = self.prob
        other.count[:] = self.count
        other.above[:] = self.above
        other.above_residual[:] = self.above_residual
        other.started = self.started
        return other


cdef inline int64_t _predict(int64_t* cur, int64_t* up, int64_t x, int64_t w, bint has_up,
                             int64_t* shape) noexcept nogil:
    """MED on the causal neighbours with ATM.md §4.8.3's stand-ins at the edges; sets
    the local shape from the differences NE - N, N - NW, NW - W."""
    cdef int64_t W, N, NW, NE, lo, hi
    if has_up:
        N = up[x]
        NE = up[x + 1] if x + 1 < w else N
        if x > 0:
            W = cur[x - 1]
            NW = up[x - 1]
        else:
            W = N
            NW = N
    elif x > 0:
        W = cur[x - 1]
        N = W
        NW = W
        NE = W
    else:
        W = N = NW = NE = 0
    shape[0] = (((_sign(NE - N) + 1) * 9 + (_sign(N - NW) + 1) * 3 + _sign(NW - W) + 1) * BUCKETS
                + _bucket(_abs(NE - N) + _abs(N - NW) + _abs(NW - W)))
    lo = W if W < N else N
    hi = N if W < N else W
    if NW >= hi:
        return lo
    if NW <= lo:
        return hi
    return W + N - NW


cdef inline void _contexts(int64_t* res, int64_t* up_res, int64_t x, int64_t w, bint has_up,
                           int64_t shape, int* ctx, int* sctx) noexcept nogil:
    cdef int64_t rW = res[x - 1] if x > 0 else 0
    cdef int64_t rN = 0, rNW = 0, rNE = 0
    if has_up:
        rN = up_res[x]
        rNW = up_res[x - 1] if x > 0 else 0
        rNE = up_res[x + 1] if x + 1 < w else 0
    ctx[0] = _bucket(_abs(rW) + _abs(rN) + ((_abs(rNW) + _abs(rNE)) >> 1)) * SHAPES + shape
    sctx[0] = 3 * (_sign(rW) + 1) + _sign(rN) + 1


cdef inline void _put_residual(Encoder* e, uint16_t* node, uint8_t* ncount, uint16_t* sp, uint8_t* sn,
                               int64_t r, int nodes) noexcept nogil:
    """A residual as a unary token (nodes), a sign and raw low bits (ATM.md §4.8.4)."""
    cdef int64_t a = _abs(r), k
    cdef int nb = 0, tok
    if a < 16:
        tok = <int>a
    else:
        k = a
        while k:
            k >>= 1
            nb += 1
        tok = <int>(16 + 2 * (nb - 5) + ((a >> (nb - 2)) & 1))
    for k in range(tok):
        _encode_bit(e, node + k, ncount + k, 1)
    if tok < nodes:
        _encode_bit(e, node + tok, ncount + tok, 0)
    if a:
        _encode_bit(e, sp, sn, r < 0)
    if tok >= 16:
        k = nb - 3
        while k >= 0:
            _encode_bit(e, NULL, NULL, (a >> k) & 1)
            k -= 1


cdef inline int64_t _get_residual(Decoder* d, uint16_t* node, uint8_t* ncount, uint16_t* sp,
                                  uint8_t* sn, int nodes) noexcept nogil:
    cdef int tok = 0, negative, nb
    cdef int64_t a, k
    while tok < nodes and _decode_bit(d, node + tok, ncount + tok):
        tok += 1
    negative = tok and _decode_bit(d, sp, sn)
    if tok < 16:
        a = tok
    else:
        nb = 5 + (tok - 16) // 2
        a = (<int64_t>1 << (nb - 1)) | (<int64_t>((tok - 16) & 1) << (nb - 2))
        k = nb - 3
        while k >= 0:
            a |= <int64_t>_decode_bit(d, NULL, NULL) << k
            k -= 1
    return -a if negative else a


cdef int _code_med(Encoder* e, Decoder* d, uint16_t* prob, uint8_t* count, int64_t* above,
                   int64_t* above_res, bint started, int64_t* levels, const uint8_t* holes,
                   int64_t rows, int64_t w, int64_t max_level, int nodes) noexcept nogil:
    """Code (e) or decode (d) rows x w levels in raster order, skipping holes; levels
    is written when decoding. above/above_res: the row before (updated to the last
    row). A hole's level is its left neighbour's (the row above's at the row start,
    0 in the first row of a plane), its residual 0."""
    cdef int64_t y, x, pred, shape, r, level
    cdef int ctx, sctx
    cdef int64_t* cur
    cdef int64_t* res = <int64_t*>malloc(w * sizeof(int64_t))
    cdef int64_t* up
    cdef bint has_up
    if res == NULL:
        return RESIDUAL_MEMORY
    for y in range(rows):
        cur = levels + y * w
        if y == 0:
            up, has_up = above, started
        else:
            up, has_up = levels + (y - 1) * w, True
        for x in range(w):
            if holes[y * w + x]:
                res[x] = 0
                if x > 0:
                    cur[x] = cur[x - 1]
                elif has_up:
                    cur[x] = up[x]
                else:
                    cur[x] = 0
                continue
            pred = _predict(cur, up, x, w, has_up, &shape)
            _contexts(res, above_res, x, w, has_up, shape, &ctx, &sctx)
            if e != NULL:
                _put_residual(e, prob + ctx * nodes, count + ctx * nodes, prob + CONTEXTS * nodes + sctx,
                              count + CONTEXTS * nodes + sctx, cur[x] - pred, nodes)
            else:
                r = _get_residual(d, prob + ctx * nodes, count + ctx * nodes, prob + CONTEXTS * nodes + sctx,
                                  count + CONTEXTS * nodes + sctx, nodes)
                level = pred + r
                if level < 0 or level > max_level:
                    free(res)
                    return RESIDUAL_RANGE
                cur[x] = level
            res[x] = cur[x] - pred
        # this row's residuals become the row above's (levels are read in place)
        memcpy(above_res, res, w * sizeof(int64_t))
    if rows:
        memcpy(above, levels + (rows - 1) * w, w * sizeof(int64_t))
    free(res)
    return RESIDUAL_OK


cdef inline void _interp_one(Encoder* e, Decoder* d, uint16_t* prob, uint8_t* count, const int64_t* orig,
                             int64_t* rec, const uint8_t* holes, int64_t i, int64_t pred, int64_t level,
                             int64_t error, int64_t top, int nodes) noexcept nogil:
    """One sample of the interpolation pyramid: its residual from `pred` quantised
    with step 2E + 1 around zero, the reconstruction clipped to 0..top."""
    cdef int64_t ctx = level if level < LEVELS else LEVELS - 1
    cdef int64_t step = 2 * error + 1, dd, q, v
    cdef int64_t interp = CONTEXTS * nodes + SIGN_CONTEXTS
    cdef uint16_t* node = prob + interp + ctx * nodes
    cdef uint8_t* ncount = count + interp + ctx * nodes
    cdef uint16_t* sp = prob + interp + LEVELS * nodes + ctx
    cdef uint8_t* sn = count + interp + LEVELS * nodes + ctx
    if holes[i]:
        rec[i] = pred
        return
    if e != NULL:
        dd = orig[i] - pred
        q = (_abs(dd) + error) // step
        q = -q if dd < 0 else q
        _put_residual(e, node, ncount, sp, sn, q, nodes)
    else:
        q = _get_residual(d, node, ncount, sp, sn, nodes)
    v = pred + q * step
    rec[i] = 0 if v < 0 else top if v > top else v


cdef void _code_interp(Encoder* e, Decoder* d, uint16_t* prob, uint8_t* count, const int64_t* orig,
                       int64_t* rec, const uint8_t* holes, int64_t rows, int64_t w, int64_t error,
                       int64_t top, int nodes) noexcept nogil:
    """Predictor 1 (ATM.md §4.8.5): a hierarchical interpolation over the band, anchors
    every S pixels, then each halving of the stride's row midpoints and column
    midpoints from the mean of their two coded neighbours."""
    cdef int64_t stride = 1, half, y, x, level = 1, prev = (top + 1) // 2, pred, i
    while stride * 2 < (rows if rows > w else w):
        stride *= 2
    y = 0
    while y < rows:
        x = 0
        while x < w:
            _interp_one(e, d, prob, count, orig, rec, holes, y * w + x, prev, 0, error, top, nodes)
            prev = rec[y * w + x]
            x += stride
        y += stride
    while stride > 1:
        half = stride // 2
        y = 0
        while y < rows:
            x = half
            while x < w:
                i = y * w + x
                pred = (rec[i - half] + rec[i + half]) >> 1 if x + half < w else rec[i - half]
                _interp_one(e, d, prob, count, orig, rec, holes, i, pred, level, error, top, nodes)
                x += stride
            y += stride
        y = half
        while y < rows:
            x = 0
            while x < w:
                i = y * w + x
                pred = (rec[i - half * w] + rec[i + half * w]) >> 1 if y + half < rows else rec[i - half * w]
                _interp_one(e, d, prob, count, orig, rec, holes, i, pred, level + 1, error, top, nodes)
                x += half
            y += stride
        stride = half
        level += 2


cdef void _after_interp(int64_t* above, int64_t* above_res, bint started, const int64_t* last,
                        const uint8_t* holes, int64_t w, int64_t error) noexcept nogil:
    """The MED state after an interpolated band: its last row's levels (holes filled
    as in MED), residuals 0."""
    cdef int64_t x
    for x in range(w):
        above_res[x] = 0
        if not holes[x]:
            above[x] = (last[x] + error) // (2 * error + 1)
        elif x > 0:
            above[x] = above[x - 1]
        elif not started:
            above[x] = 0


cdef object _begin_encoder(Encoder* e):
    if rc_begin(&e.rc) != 0:
        raise MemoryError()


def _check_top(planes, int64_t top):
    # a token holds magnitudes below 2^16 (2^32 in a wide plane): larger samples
    # could not be coded, and a decoder's levels must stay within them
    cdef Plane plane
    for plane in planes:
        if top > (0xFFFFFFFF if plane.wide else 0xFFFF):
            raise ValueError(f"samples up to {top} do not fit a {'wide' if plane.wide else '16-bit'} plane")


def encode(planes, int predictor, samples_list, holes, int64_t error, int64_t top):
    """The coded bytes of a chunk: each plane's samples (rows x W int64, holes'
    entries ignored) in turn with `predictor` (0 MED on levels, 1 interpolation), with
    that plane's `Plane` state (updated)."""
    cdef Encoder e
    cdef Plane plane
    cdef const int64_t[:, ::1] sv
    cdef int64_t[:, ::1] lv
    cdef int64_t[:, ::1] rv
    cdef const uint8_t[:, ::1] hv = holes
    cdef int status = RESIDUAL_OK
    cdef int64_t rows = hv.shape[0], w = hv.shape[1], step = 2 * error + 1
    if predictor not in (0, 1) or error < 0 or top < 0:
        raise ValueError("predictor 0 or 1, error and top >= 0")
    _check_top(planes, top)
    _begin_encoder(&e)
    try:
        for plane, samples in zip(planes, samples_list):
            sv = samples
            if sv.shape[0] != rows or sv.shape[1] != w or plane.width != w:
                raise ValueError("samples, holes and plane disagree on the band's shape")
            if rows == 0:
                continue
            e.stride = plane.models
            if predictor == 0:
                lv = (np.asarray(samples) + error) // step
                with nogil:
                    status = _code_med(&e, NULL, &plane.prob[0], &plane.count[0], &plane.above[0],
                                       &plane.above_residual[0], plane.started, &lv[0, 0], &hv[0, 0], rows, w,
                                       (top + error) // step, plane.nodes)
            else:
                rv = np.empty((rows, w), np.int64)
                with nogil:
                    _code_interp(&e, NULL, &plane.prob[0], &plane.count[0], &sv[0, 0], &rv[0, 0], &hv[0, 0],
                                 rows, w, error, top, plane.nodes)
                    _after_interp(&plane.above[0], &plane.above_residual[0], plane.started, &rv[rows - 1, 0],
                                  &hv[rows - 1, 0], w, error)
            if status != RESIDUAL_OK:
                raise MemoryError()
            plane.started = True
        with nogil:
            rc_flush(&e.rc)
        if e.rc.failed:
            raise MemoryError()
        # LZMA's coder always starts with a zero byte: it is not stored
        return bytes(e.rc.buf[1 : e.rc.size])
    finally:
        free(e.rc.buf)


def decode(planes, int predictor, const uint8_t[::1] data, holes, int64_t error, int64_t top):
    """(status, [samples per plane, rows x W int64]) of a chunk's coded bytes; the
    planes' states are updated. The caller checked the fields; the kernel checks every
    level and byte."""
    cdef Decoder d
    cdef Plane plane
    cdef int64_t[:, ::1] lv
    cdef int64_t[:, ::1] rv
    cdef const uint8_t[:, ::1] hv = holes
    cdef int status = RESIDUAL_OK
    cdef int64_t rows = hv.shape[0], w = hv.shape[1], step = 2 * error + 1
    cdef int i
    if predictor not in (0, 1) or error < 0 or top < 0:
        raise ValueError("predictor 0 or 1, error and top >= 0")
    _check_top(planes, top)
    out = []
    d.buf = &data[0] if data.shape[0] else NULL
    d.size = data.shape[0]
    d.at = 0
    d.overrun = 0
    d.rng = 0xFFFFFFFF
    d.code = 0
    with nogil:
        for i in range(4):
            d.code = (d.code << 8) | _next(&d)
    for plane in planes:
        if plane.width != w:
            raise ValueError("holes and plane disagree on the band's width")
        samples = np.zeros((rows, w), np.int64)
        rv = samples
        d.stride = plane.models
        if rows and predictor == 0:
            levels = np.zeros((rows, w), np.int64)
            lv = levels
            with nogil:
                status = _code_med(NULL, &d, &plane.prob[0], &plane.count[0], &plane.above[0],
                                   &plane.above_residual[0], plane.started, &lv[0, 0], &hv[0, 0], rows, w,
                                   (top + error) // step, plane.nodes)
            samples = np.minimum(levels * step, top)
        elif rows:
            with nogil:
                _code_interp(NULL, &d, &plane.prob[0], &plane.count[0], NULL, &rv[0, 0], &hv[0, 0],
                             rows, w, error, top, plane.nodes)
                _after_interp(&plane.above[0], &plane.above_residual[0], plane.started, &rv[rows - 1, 0],
                              &hv[rows - 1, 0], w, error)
        if status == RESIDUAL_OK and d.overrun:
            status = RESIDUAL_OVERRUN
        if status != RESIDUAL_OK:
            return status, None
        plane.started = plane.started or rows > 0
        out.append(samples)
    if d.at < d.size:
        return RESIDUAL_TRAILING, None
    return RESIDUAL_OK, out
