"""The CPU decoder's kernel: exact integer scanline rasterisation of a mesh, with the
GIL released (see codec.decoder_cpu for the rule it implements, ATM.md §5).

The pixel centres and vertices are integer points, so a span's ends and a pixel's
value are exact fractions, read here in fixed point. Division by multiplication
(Granlund and Montgomery): for integers 0 <= n < V*d and M = ceil(2**s / d),
floor(n / d) = (n * M) >> s whenever V*d*d <= 2**s. Writing n = q*d + r and
e = M*d - 2**s < d, n*M / 2**s = q + r/d + n*e / (d * 2**s), where r/d <= 1 - 1/d
and n*e / (d * 2**s) < V*d*d / (d * 2**s) <= 1/d. And n*M < V*2**s + V*d.

* A channel's value at (x, y) is floor(N / d2), N = ga*x + gb*y + gc an exact integer
  plane over d2 = 2|D| (D the doubled area). At every pixel a triangle writes, N/d2 is
  a mean of its corners' samples plus 1/2, so 0 < N < V*d2 with V = 2**8 or 2**16 (the
  samples' range); s = 62 - log2 V keeps N*M below 2**63. N*M is linear in x and y:
  a row adds gb*M, a pixel ga*M, in uint64 arithmetic modulo 2**64, exact wherever the
  true value lies in [0, 2**64) (at every pixel written) whatever the walk passes
  through on the way. A pixel costs an add and a shift.
* An edge from column x0 that moves dx columns over dy rows is at
  x = x0 + dx*k/dy on its k-th row, and ceil(x) = floor(n / dy) with
  n = x0*dy + dx*k + dy - 1, 0 <= n < W*dy: walked the same way, with V = W below
  2**22 and s = 40 (a constant: a variable shift costs more), so edges over up to
  2**((40 - bits(W)) / 2) rows (2**15 for W = 512). The multipliers of every edge
  height are made once per call, and the planes' of |D| up to 2048 once at import,
  so most triangles cost no division.
* Short spans (a decoder's are ~3 pixels): a loop over a span's pixels ends where the
  branch predictor cannot guess, which cost more than the pixels. A one-channel span
  of up to 8 samples is computed 8 samples at once (the same fixed-point values,
  packed into a word with SSE2 where there is SSE2) and merged into the row under a
  mask: the samples beyond the span are written back as they were, so this needs
  only the word's room in the image (the last bytes take the loop) and no other
  writer of the image during the call (each call owns its output). A sample beyond
  the span may exceed the sample type; the packs saturate it, or it carries only
  into later samples, which the mask drops with it.
* Where the processor has AVX-512 (BW and VL; found at import, so that a build for
  any x86-64 runs everywhere), a one-channel triangle's rows take a walk in C
  instead (atm_walk_avx512): the same span ends and fixed-point samples, eight
  computed in two 256-bit registers, narrowed and stored under a byte or word mask,
  with no load of the row and no room needed past the span; a walk for each
  orientation, so no select a row. The set-up of those triangles is in C too
  (atm_run_avx512: _triangles' arithmetic, line for line), a loop that hands back
  the rare triangle it does not take. rasterise(portable=True) takes the portable
  code (the tests compare the two).

Triangles beyond those bounds (d2 over 2**23 for 8-bit samples, 2**15 for 16-bit: 2
million and 8,192 pixels; taller edges, or over 2**16 rows; images 2**22 wide), with a
corner in the last column (where the rule needs to know whether the right edge is
exactly on a column) take the general walk (colour triangles too: their fixed-point
walk is _triangle_colour's, with the same bounds): edges as
quotient and remainder over their rows (one float64 division per edge, corrected to
the exact floor), planes in fixed point or, when too large, as quotient and remainder
(one division per span and a carry per pixel). Bounds: with W*H <= 2**32 and samples
below 2**16, every plane coefficient and N is below 2**53 in magnitude.

Coverage (every pixel written exactly once). A mesh that mesh.validate has checked
tiles the image (total area, positive orientation, and edges shared as a tiling
shares them: ATM.md §4.2.3), and the ownership rule then gives every pixel to exactly
one triangle, so the caller may ask for the cheap check alone (CHECK_TOTAL): the
written pixels counted, which must be W*H. The total area with every triangle
positively oriented would not be proof enough by itself: two overlapping triangles
can leave a gap of their overlap's area (tests/test_decoders.py's sheared meshes),
which is why validate also checks the edges, or knows them (the decoder's own
triangulation of vertices whose hull is the image). Any other mesh (CHECK_SPANS) is
checked per span, not per pixel: row y's spans [lo, hi) tile 0..W exactly when the
multiset of their starts plus W equals that of their ends plus 0 (then the number of
spans over each column, starts up to it less ends up to it, is one), so each span
adds one at lo and takes one at hi of a row of W + 1 counters, and every row must end
as (1, 0, ..., 0, -1). The counters are 16 bits, wrapping: exact for a row of fewer
than 2**15 spans (a tiling's row has at most W), which is counted when there are
2**15 triangles or more (each gives a row one span at most). When either check
fails the image is rasterised again counting each pixel's writes, to name the first
pixel uncovered or covered twice."""

from libc.stdint cimport int32_t, int64_t, uint8_t, uint16_t, uint64_t
from libc.stdlib cimport calloc, free, malloc
from libc.string cimport memcpy, memset

ctypedef fused sample_t:
    uint8_t
    uint16_t

# the triangles' corner indices: int64, or int32 (half the memory to read)
ctypedef fused index_t:
    int32_t
    int64_t

# rasterise()'s status codes; the caller turns them into CorruptError
cpdef enum Status:
    OK = 0
    BAD_VERTEX = 1      # a vertex outside the image (detail: its index)
    BAD_INDEX = 2       # a triangle corner beyond the vertices (detail: the triangle)
    UNCOVERED = 3       # detail: the first pixel (raster order) no triangle writes
    TWICE = 4           # detail: the first pixel written twice or more
    NO_MEMORY = 5       # the coverage counters could not be allocated


# rasterise()'s coverage checks (see the module's docstring)
cpdef enum Check:
    CHECK_SPANS = 0     # any mesh: every row's spans counted
    CHECK_TOTAL = 1     # a mesh known to tile the image: the written pixels counted


# how _triangles accounts for the pixels it writes
cdef enum Mode:
    MODE_TOTAL = 0      # count them
    MODE_COUNTS = 1     # per-row span counters
    MODE_COVER = 2      # each pixel's writes


cdef inline int64_t _floor_div_fast(int64_t a, int64_t b) noexcept nogil:
    """floor(a / b) for b > 0 and |a| < 2**53: the float64 quotient truncated (no
    integer division, which costs several times more), then corrected without a
    branch. Division in binary64 is correctly rounded and both integers around the
    true quotient are representable, so the rounded quotient lies between them and
    truncating it gives the floor or one more: one correction suffices."""
    cdef int64_t q = <int64_t>(<double>a / <double>b)
    q -= (a - q * b) < 0
    return q


cdef struct Edge:
    # the edge's x on the current row, q + r/den with 0 <= r < den (den: its rows), and
    # its step per row the same way
    int64_t q, r, den, dq, dr


cdef inline void _edge_start(Edge* e, int64_t x0, int64_t dx, int64_t dy) noexcept nogil:
    """An edge from column x0 that moves dx columns over dy > 0 rows."""
    e.q = x0
    e.r = 0
    e.den = dy
    e.dq = _floor_div_fast(dx, dy)
    e.dr = dx - e.dq * dy


cdef inline void _edge_next(Edge* e) noexcept nogil:
    """One row down: the whole step, and a carry from the remainder."""
    cdef int64_t carry
    e.q += e.dq
    e.r += e.dr
    carry = e.r >= e.den
    e.r -= carry * e.den
    e.q += carry


cdef inline void _sort3(int64_t* i, const int64_t* v, int64_t w, bint ordered) noexcept nogil:
    """Order three vertex indices by raster position (row, then column): a sorting
    network of conditional moves on their pixel keys, as the order is different from
    triangle to triangle; on the indices themselves where the keys increase with them
    (`ordered`)."""
    cdef int64_t a = i[0], b = i[1], c = i[2], t, kt, ka, kb, kc
    cdef bint s
    if ordered:
        ka = a; kb = b; kc = c
    else:
        ka = v[2 * a + 1] * w + v[2 * a]; kb = v[2 * b + 1] * w + v[2 * b]; kc = v[2 * c + 1] * w + v[2 * c]
    s = kb < ka
    t = b if s else a; b = a if s else b; a = t
    kt = kb if s else ka; kb = ka if s else kb; ka = kt
    s = kc < kb
    t = c if s else b; c = b if s else c; b = t
    kt = kc if s else kb; kc = kb if s else kc; kb = kt
    s = kb < ka
    t = b if s else a; b = a if s else b; a = t
    i[0] = a; i[1] = b; i[2] = c


cdef struct Planes:
    # per channel (at most 4): the plane's value numerator N at column 0 of the current
    # row, its step per row and per column; fixed point (each times M, modulo 2**64)
    # when `fast`, else N itself (int64 bits)
    uint64_t row[4]
    uint64_t dy[4]
    uint64_t dx[4]
    int64_t d2          # the denominator, 2 |D|
    int shift           # s
    bint fast


cdef inline void _write1(sample_t* p, uint64_t a, uint64_t step, int64_t lo, int64_t hi) noexcept nogil:
    """Pixels lo .. hi - 1 of one channel from the fixed-point value `a` at lo, `step`
    per pixel; the shift is a constant of the sample type (a variable one costs more)."""
    cdef int64_t x
    for x in range(lo, hi):
        if sample_t is uint8_t:
            p[x] = <sample_t>(a >> 54)
        else:
            p[x] = <sample_t>(a >> 46)
        a += step


cdef extern from *:
    """
    /* Eight 8-bit samples (v + k*s) >> 54, k = 0..7, in one little-endian word: with
       SSE2 on x86-64 (_mm_cvtsi128_si64 is 64-bit only: a 32-bit x86 build takes the scalar form) four 2-lane adds and shifts and three packs instead of some
       thirty scalar operations; elsewhere the scalar form. A sample beyond a span may
       reach 10 bits: the packs saturate it, the scalar form carries it into the later
       bytes, which the caller masks out with it. */
    #if defined(__x86_64__) || defined(_M_X64) || defined(_M_AMD64)
    #include <emmintrin.h>
    static inline uint64_t atm_pack8_u8(uint64_t v, uint64_t s) {
        __m128i st = _mm_set1_epi64x((long long)s);
        __m128i st2 = _mm_add_epi64(st, st), st4;
        __m128i x0 = _mm_set_epi64x((long long)(v + s), (long long)v), x1, x2, x3;
        st4 = _mm_add_epi64(st2, st2);
        x1 = _mm_add_epi64(x0, st2);
        x2 = _mm_add_epi64(x0, st4);
        x3 = _mm_add_epi64(x1, st4);
        /* each 64-bit lane now below 2**10, so its high half is 0 and the signed
           32 -> 16-bit packs keep the values */
        x0 = _mm_packs_epi32(_mm_srli_epi64(x0, 54), _mm_srli_epi64(x1, 54));
        x2 = _mm_packs_epi32(_mm_srli_epi64(x2, 54), _mm_srli_epi64(x3, 54));
        x0 = _mm_packs_epi32(x0, x2);
        return (uint64_t)_mm_cvtsi128_si64(_mm_packus_epi16(x0, x0));
    }
    /* Samples 0 .. n - 1 (n <= 8) of a 16-bit span at p, (v + k*s) >> 46, merged into
       the 16 bytes there under a mask. A sample is below 2**18 after the shift (below
       2**16 in the span): the low 32 bits of each lane, less 2**15, fit the signed
       32 -> 16-bit pack exactly in the span, and the bias comes off as a flipped top
       bit. */
    static inline void atm_put8_u16(uint16_t* p, uint64_t v, uint64_t s, int64_t n) {
        __m128i st = _mm_set1_epi64x((long long)s);
        __m128i st2 = _mm_add_epi64(st, st), st4;
        __m128i x0 = _mm_set_epi64x((long long)(v + s), (long long)v), x1, x2, x3, a, b, bias, m, old;
        st4 = _mm_add_epi64(st2, st2);
        x1 = _mm_add_epi64(x0, st2);
        x2 = _mm_add_epi64(x0, st4);
        x3 = _mm_add_epi64(x1, st4);
        a = _mm_unpacklo_epi64(_mm_shuffle_epi32(_mm_srli_epi64(x0, 46), 0x88),
                               _mm_shuffle_epi32(_mm_srli_epi64(x1, 46), 0x88));
        b = _mm_unpacklo_epi64(_mm_shuffle_epi32(_mm_srli_epi64(x2, 46), 0x88),
                               _mm_shuffle_epi32(_mm_srli_epi64(x3, 46), 0x88));
        bias = _mm_set1_epi32(32768);
        a = _mm_packs_epi32(_mm_sub_epi32(a, bias), _mm_sub_epi32(b, bias));
        a = _mm_xor_si128(a, _mm_set1_epi16((short)0x8000));
        m = _mm_cmpgt_epi16(_mm_set1_epi16((short)n), _mm_setr_epi16(0, 1, 2, 3, 4, 5, 6, 7));
        old = _mm_loadu_si128((const __m128i*)p);
        _mm_storeu_si128((__m128i*)p, _mm_or_si128(_mm_and_si128(m, a), _mm_andnot_si128(m, old)));
    }
    #else
    static inline uint64_t atm_pack8_u8(uint64_t v, uint64_t s) {
        uint64_t w = 0;
        int k;
        for (k = 0; k < 8; k++, v += s)
            w |= (v >> 54) << (8 * k);
        return w;
    }
    static inline void atm_put8_u16(uint16_t* p, uint64_t v, uint64_t s, int64_t n) {
        int64_t k;
        for (k = 0; k < n; k++, v += s)
            p[k] = (uint16_t)(v >> 46);
    }
    #endif
    """
    uint64_t atm_pack8_u8(uint64_t v, uint64_t s) noexcept nogil
    void atm_put8_u16(uint16_t* p, uint64_t v, uint64_t s, int64_t n) noexcept nogil


cdef extern from *:
    """
    /* _walk1's rows with AVX-512 (BW and VL, on 256-bit registers: no 512-bit
       instruction, which would lower some processors' clock for every thread of the
       core), chosen at run time where the processor has it, so that a build for any
       x86-64 keeps the portable walk for the others. A span's samples are computed
       eight at a time, narrowed by truncation (a sample beyond the span may exceed
       the type; it is masked out with them) and stored under a byte (or word) mask:
       no load of the row, and no room needed beyond the span (masked-out elements
       are neither written nor can they fault). The same fixed-point values and span
       ends as the portable walk, so the same pixels. */
    #if (defined(__GNUC__) || defined(__clang__)) && defined(__x86_64__)
    #include <immintrin.h>
    #define ATM_AVX512 1
    #define ATM_TARGET __attribute__((target("avx512f,avx512bw,avx512vl")))
    static int atm_has_avx512(void) {
        __builtin_cpu_init();
        return __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512bw")
               && __builtin_cpu_supports("avx512vl");
    }
    /* the 8 samples (a + k*adx) >> shift, k = 0..7, as bytes (u8) or words (u16) */
    static inline ATM_TARGET __m128i atm_eight_avx512(uint64_t a, __m256i k0, __m256i k4, int wide) {
        __m256i v = _mm256_set1_epi64x((long long)a);
        __m256i x0 = _mm256_add_epi64(v, k0), x1 = _mm256_add_epi64(v, k4);
        if (wide) {
            x0 = _mm256_srli_epi64(x0, 46);
            x1 = _mm256_srli_epi64(x1, 46);
            return _mm_unpacklo_epi64(_mm256_cvtepi64_epi16(x0), _mm256_cvtepi64_epi16(x1));
        }
        x0 = _mm256_srli_epi64(x0, 54);
        x1 = _mm256_srli_epi64(x1, 54);
        return _mm_unpacklo_epi32(_mm256_cvtepi64_epi8(x0), _mm256_cvtepi64_epi8(x1));
    }
    /* the masks of the first n = 0 .. 8 elements */
    static const uint16_t atm_first[9] = {0, 1, 3, 7, 15, 31, 63, 127, 255};
    /* samples 0 .. n - 1 (n <= 8) of a span at p (bytes or words) */
    static inline ATM_TARGET void atm_store8_avx512(void* p, __m128i s, int64_t n, int wide, const char* end) {
        (void)end;  /* a masked store needs no room */
        if (wide)
            _mm_mask_storeu_epi16(p, (__mmask8)atm_first[n], s);
        else
            _mm_mask_storeu_epi8(p, (__mmask16)atm_first[n], s);
    }
    static inline ATM_TARGET void atm_steps_avx512(uint64_t adx, __m256i* k0, __m256i* k4) {
        *k0 = _mm256_set_epi64x((long long)(3 * adx), (long long)(2 * adx), (long long)adx, 0);
        *k4 = _mm256_add_epi64(*k0, _mm256_set1_epi64x((long long)(4 * adx)));
    }
    #define ATM_NAME(x) x##_avx512
    #include "raster_walk.hpp"
    #undef ATM_NAME
    #undef ATM_TARGET
    /* The same walk with AVX2 (most x86-64 processors without AVX-512 have it), chosen
       at run time where there is no AVX-512. The 8 samples are computed as above, the
       even ones in one register and the odd ones in the other, so that one shift and
       an or put them in order as 32-bit lanes (each below 2**18), packed with
       saturation (a sample beyond the span may exceed the type; it is not stored).
       AVX2 has no store under a byte mask: the span's 8 (or 16) bytes are loaded,
       merged under a mask and stored back, the bytes beyond the span as they were
       (no other writer of the image during the call, as for the portable walk); where
       that word would reach past the image's end, the samples are copied one by one. */
    #define ATM_TARGET __attribute__((target("avx2")))
    static int atm_has_avx2(void) {
        __builtin_cpu_init();
        return __builtin_cpu_supports("avx2");
    }
    static inline ATM_TARGET void atm_steps_avx2(uint64_t adx, __m256i* k0, __m256i* k4) {
        *k0 = _mm256_set_epi64x((long long)(6 * adx), (long long)(4 * adx), (long long)(2 * adx), 0);
        *k4 = _mm256_add_epi64(*k0, _mm256_set1_epi64x((long long)adx));
    }
    static inline ATM_TARGET __m128i atm_eight_avx2(uint64_t a, __m256i k0, __m256i k4, int wide) {
        __m256i v = _mm256_set1_epi64x((long long)a);
        __m256i x0 = _mm256_add_epi64(v, k0), x1 = _mm256_add_epi64(v, k4);
        __m128i s;
        if (wide) {
            x0 = _mm256_srli_epi64(x0, 46);
            x1 = _mm256_srli_epi64(x1, 46);
        } else {
            x0 = _mm256_srli_epi64(x0, 54);
            x1 = _mm256_srli_epi64(x1, 54);
        }
        /* 32-bit lanes s0 .. s7; packed to words per 128-bit half (s0-s3 twice, s4-s7
           twice), whose first quarters are joined */
        x0 = _mm256_or_si256(x0, _mm256_slli_epi64(x1, 32));
        x0 = _mm256_permute4x64_epi64(_mm256_packus_epi32(x0, x0), 0x08);
        s = _mm256_castsi256_si128(x0);
        return wide ? s : _mm_packus_epi16(s, s);
    }
    /* the low n bytes of a word, n = 0 .. 8 */
    static const uint64_t atm_bytes[9] = {0, 0xFF, 0xFFFF, 0xFFFFFF, 0xFFFFFFFFull, 0xFFFFFFFFFFull,
                                          0xFFFFFFFFFFFFull, 0xFFFFFFFFFFFFFFull, 0xFFFFFFFFFFFFFFFFull};
    static inline ATM_TARGET void atm_store8_avx2(void* p, __m128i s, int64_t n, int wide, const char* end) {
        uint64_t old, word;
        __m128i m;
        if (wide) {
            if ((const char*)p + 16 <= end) {
                m = _mm_cmpgt_epi16(_mm_set1_epi16((short)n), _mm_setr_epi16(0, 1, 2, 3, 4, 5, 6, 7));
                _mm_storeu_si128((__m128i*)p, _mm_blendv_epi8(_mm_loadu_si128((const __m128i*)p), s, m));
            } else {
                uint16_t t[8];
                _mm_storeu_si128((__m128i*)t, s);
                memcpy(p, t, (size_t)n * 2);
            }
        } else if ((const char*)p + 8 <= end) {
            memcpy(&old, p, 8);
            word = (uint64_t)_mm_cvtsi128_si64(s);
            old = (old & ~atm_bytes[n]) | (word & atm_bytes[n]);
            memcpy(p, &old, 8);
        } else {
            uint8_t t[16];
            _mm_storeu_si128((__m128i*)t, s);
            memcpy(p, t, (size_t)n);
        }
    }
    #define ATM_NAME(x) x##_avx2
    #include "raster_walk.hpp"
    #undef ATM_NAME
    #else
    #define ATM_AVX512 0
    static int atm_has_avx512(void) { return 0; }
    static int atm_has_avx2(void) { return 0; }
    #define ATM_STUBS(isa) \
    static int64_t atm_walk_##isa(void* pixels, int wide, int narrow, int64_t y, int64_t last, \
                                  int64_t turn, uint64_t arow, uint64_t adx, uint64_t ady, \
                                  uint64_t ea, uint64_t sa, uint64_t eb, uint64_t sb, \
                                  uint64_t ec, uint64_t sc, int long_left, int64_t w, int64_t h, \
                                  uint16_t* counts, int64_t* spans) { return -1; } \
    static int64_t atm_run_##isa(const int64_t* v, const void* values, const void* tris, int idx32, int64_t k, \
                                 int64_t m, void* pixels, int wide, const uint64_t* recip, int64_t edge_lim, \
                                 const uint64_t* table, int64_t w, int64_t h, uint16_t* counts, \
                                 int64_t* spans, int64_t* written, int ordered) { return k; }
    ATM_STUBS(avx512)
    ATM_STUBS(avx2)
    #undef ATM_STUBS
    #endif
    """
    int atm_has_avx512() noexcept nogil
    int atm_has_avx2() noexcept nogil
    int64_t atm_run_avx512(const int64_t* v, const void* values, const void* tris, int idx32, int64_t k, int64_t m,
                           void* pixels, int wide, const uint64_t* recip, int64_t edge_lim, const uint64_t* table,
                           int64_t w, int64_t h, uint16_t* counts, int64_t* spans, int64_t* written,
                           int ordered) noexcept nogil
    int64_t atm_walk_avx512(void* pixels, int wide, int narrow, int64_t y, int64_t last, int64_t turn,
                            uint64_t arow, uint64_t adx, uint64_t ady, uint64_t ea, uint64_t sa, uint64_t eb,
                            uint64_t sb, uint64_t ec, uint64_t sc, int long_left, int64_t w, int64_t h,
                            uint16_t* counts, int64_t* spans) noexcept nogil
    int64_t atm_run_avx2(const int64_t* v, const void* values, const void* tris, int idx32, int64_t k, int64_t m,
                         void* pixels, int wide, const uint64_t* recip, int64_t edge_lim, const uint64_t* table,
                         int64_t w, int64_t h, uint16_t* counts, int64_t* spans, int64_t* written,
                         int ordered) noexcept nogil
    int64_t atm_walk_avx2(void* pixels, int wide, int narrow, int64_t y, int64_t last, int64_t turn,
                          uint64_t arow, uint64_t adx, uint64_t ady, uint64_t ea, uint64_t sa, uint64_t eb,
                          uint64_t sb, uint64_t ec, uint64_t sc, int long_left, int64_t w, int64_t h,
                          uint16_t* counts, int64_t* spans) noexcept nogil


# whether this processor runs the AVX-512 walk (found once, at import; read only)
cdef bint _AVX512 = atm_has_avx512()
#: Whether rasterise() takes the AVX-512 walk on this processor.
AVX512 = bool(_AVX512)
# and the AVX2 walk, where there is no AVX-512 (found once, at import; read only)
cdef bint _AVX2 = atm_has_avx2()
#: Whether this processor can take the AVX2 walk (rasterise() takes it without AVX-512).
AVX2 = bool(_AVX2)

# the walks, by the `isa` that _render and _triangles take
cdef enum Isa:
    ISA_PORTABLE = 0
    ISA_AVX2 = 1
    ISA_AVX512 = 2

#: The walks rasterise(walk=) can take on this processor, the one it takes by default first.
WALKS = (("avx512",) if _AVX512 else ()) + (("avx2",) if _AVX2 else ()) + ("portable",)
# the walks' names by their Isa (a tuple: no module state a call could change)
_ISA_NAMES = ("portable", "avx2", "avx512")


# _MASK[n]: the low n bytes of a word
cdef uint64_t _MASK[9]
_MASK[:] = [0, 0xFF, 0xFFFF, 0xFFFFFF, 0xFFFFFFFF, 0xFFFFFFFFFF, 0xFFFFFFFFFFFF, 0xFFFFFFFFFFFFFF,
            0xFFFFFFFFFFFFFFFF]


cdef inline void _put8(sample_t* p, uint64_t a, uint64_t s, int64_t n) noexcept nogil:
    """Samples 0 .. n - 1 (n <= 8) of a one-channel span at p, from the fixed-point value
    `a`, `s` per sample: 8 samples computed at once and merged into the row under a
    mask, one load and one store, with no exit that depends on n (a span is ~3 pixels,
    and a loop's exit mispredicted costs more than the span); p + 8 samples must lie in
    the image. The samples beyond the span are written back as they were."""
    cdef uint64_t old, m, w
    if sample_t is uint8_t:
        memcpy(&old, p, 8)
        m = _MASK[n]
        w = atm_pack8_u8(a, s)
        old = (old & ~m) | (w & m)
        memcpy(p, &old, 8)
    else:
        atm_put8_u16(p, a, s, n)


cdef inline void _put_long(sample_t* p, uint64_t a, uint64_t s, int64_t n, const sample_t* short_end) noexcept nogil:
    """Samples 0 .. n - 1 of a one-channel span at p, of any length: 8 at a time by
    _put8 (inside the span), the rest by _put8 where its word has room before
    short_end, else one by one."""
    while n > 8:
        _put8(p, a, s, 8)
        p += 8
        a += 8 * s
        n -= 8
    if p <= short_end:
        _put8(p, a, s, n)
    else:
        _write1(p, a, s, 0, n)


cdef inline void _span(sample_t* p, const Planes* pl, int64_t c, int64_t lo, int64_t hi) noexcept nogil:
    """Write pixels lo .. hi - 1 of the row starting at p (C channels each)."""
    cdef int64_t ch, x, q, r, d2 = pl.d2, qa, ra
    cdef uint64_t a, step
    if pl.fast:
        if c == 1:
            _write1(p, pl.row[0] + pl.dx[0] * <uint64_t>lo, pl.dx[0], lo, hi)
        else:
            for ch in range(c):
                a = pl.row[ch] + pl.dx[ch] * <uint64_t>lo
                step = pl.dx[ch]
                for x in range(lo, hi):
                    if sample_t is uint8_t:
                        p[x * c + ch] = <sample_t>(a >> 54)
                    else:
                        p[x * c + ch] = <sample_t>(a >> 46)
                    a += step
        return
    # a large triangle: N / d2 as quotient and remainder, stepped with a carry
    for ch in range(c):
        q = <int64_t>(pl.row[ch] + pl.dx[ch] * <uint64_t>lo)  # N, exact (below 2**53)
        r = q
        q = _floor_div_fast(r, d2)
        r -= q * d2
        qa = _floor_div_fast(<int64_t>pl.dx[ch], d2)
        ra = <int64_t>pl.dx[ch] - qa * d2
        for x in range(lo, hi):
            p[x * c + ch] = <sample_t>q
            q += qa
            r += ra - d2
            q += r >= 0
            r = r if r >= 0 else r + d2


cdef inline int64_t _rows(sample_t* pixels, Planes* pl, Edge* left, Edge* right, int64_t y, int64_t stop,
                          int64_t c, int64_t w, bint border, int mode, uint16_t* counts, int64_t* spans,
                          uint8_t* cover) noexcept nogil:
    """Rows y .. stop - 1 of a triangle between two edges; the pixels written. The
    edges are walked in locals (through the pointers they would be stored and
    reloaded around every sample store, which may alias them)."""
    cdef int64_t lo, hi, ch, carry, written = 0
    cdef int64_t lq = left.q, lr = left.r, lden = left.den, ldq = left.dq, ldr = left.dr
    cdef int64_t rq = right.q, rr = right.r, rden = right.den, rdq = right.dq, rdr = right.dr
    cdef sample_t* row = pixels + y * w * c
    while y < stop:
        # [xl, xr]: the two edges' exact x on this row. Column x is the triangle's if
        # xl <= x < xr, or xl < x = xr = W - 1: from ceil(xl) to ceil(xr) - 1, and
        # W - 1 when the right edge is exactly there and the left one is not (only a
        # triangle with a corner in the last column can reach it)
        lo = lq + (lr != 0)
        hi = rq + (rr != 0)
        if border:
            hi += (rr == 0) & (hi == w - 1) & ((lr != 0) | (lo != w - 1))
        _span(row, pl, c, lo, hi)
        written += hi - lo  # lo <= hi: the left edge is left of the right one
        if mode != MODE_TOTAL:
            _account(mode, y, lo, hi, w, counts, spans, cover)
        # one row down: each edge's whole step, and a carry from its remainder
        # (without a branch: a carry's direction cannot be predicted)
        lq += ldq
        lr += ldr
        carry = lr >= lden
        lr -= carry * lden
        lq += carry
        rq += rdq
        rr += rdr
        carry = rr >= rden
        rr -= carry * rden
        rq += carry
        for ch in range(c):
            pl.row[ch] += pl.dy[ch]
        row += w * c
        y += 1
    left.q = lq
    left.r = lr
    right.q = rq
    right.r = rr
    return written


cdef inline void _account(int mode, int64_t y, int64_t lo, int64_t hi, int64_t w, uint16_t* counts, int64_t* spans,
                   uint8_t* cover) noexcept nogil:
    """A span's coverage bookkeeping under MODE_COUNTS or MODE_COVER."""
    cdef int64_t x
    cdef uint8_t seen
    if mode == MODE_COUNTS:
        if lo < hi:
            counts[y * (w + 1) + lo] += 1
            counts[y * (w + 1) + hi] -= 1
            if spans != NULL:
                spans[y] += 1
    else:
        for x in range(y * w + lo, y * w + hi):
            seen = cover[x]
            cover[x] = seen + 1 if seen < 2 else 2


cdef inline uint64_t _reciprocal(int64_t d, int shift) noexcept nogil:
    """ceil(2**shift / d) for 2 <= d and shift <= 54 (the quotient then below 2**53):
    the float64 quotient is correctly rounded and the integers around it are
    representable, so truncated it is the ceiling or one less."""
    cdef int64_t one = <int64_t>1 << shift
    cdef int64_t m = <int64_t>(<double>one / <double>d)
    m += m * d < one
    return <uint64_t>m


# _RECIPROCAL[h] = ceil(2**54 / 2h), the plane multiplier of an 8-bit triangle of
# doubled area h (d2 = 2h): a division per triangle costs more than the rest of its
# set-up, and nearly all of a decoder's triangles are this small (camera: 99.9 % of
# them have h <= 255). A 16-bit triangle's, ceil(2**46 / 2h), is (_RECIPROCAL[h] + 255)
# >> 8, as ceil(ceil(x) / n) = ceil(x / n) for a whole n. Made once, read only.
cdef enum:
    _RECIPROCALS = 2048
cdef uint64_t _RECIPROCAL[_RECIPROCALS + 1]
_RECIPROCAL[0] = 0
for _h in range(1, _RECIPROCALS + 1):
    _RECIPROCAL[_h] = _reciprocal(2 * _h, 54)


cdef inline void _fixed_edge(int64_t x0, int64_t dx, int64_t dy, const uint64_t* recip, uint64_t* e,
                             uint64_t* step) noexcept nogil:
    """An edge from column x0 moving dx columns over dy rows in _triangle1's fixed
    point: (n * E) at its first row, and E * dx per row."""
    cdef uint64_t m = recip[dy]
    e[0] = <uint64_t>(x0 * dy + dy - 1) * m
    step[0] = <uint64_t>dx * m


cdef inline int64_t _fixed_edges(int64_t tx, int64_t ty, int64_t mx, int64_t my, int64_t bx, int64_t by,
                                 int64_t last, const uint64_t* recip, uint64_t* ea, uint64_t* sa, uint64_t* eb,
                                 uint64_t* sb, uint64_t* ec, uint64_t* sc) noexcept nogil:
    """The long edge T -> B (ea, sa), the short one of the first rows (eb, sb: T -> M, or
    M -> B for a flat top) and the one it turns into at M's row (ec, sc: M -> B, stepped
    back to T's row, so that every edge steps on every row and a row picks its short
    edge by a select, not by a second loop whose exit the branch predictor misses: the
    walk is modulo 2**64 and exact wherever it is read); the row where the short edge
    turns (M's, or past the triangle's end)."""
    _fixed_edge(tx, bx - tx, by - ty, recip, ea, sa)
    if my > ty:
        _fixed_edge(tx, mx - tx, my - ty, recip, eb, sb)
        _fixed_edge(mx, bx - mx, by - my, recip, ec, sc)
        ec[0] -= <uint64_t>(my - ty) * sc[0]
        return my if by > my else last + 1
    _fixed_edge(mx, bx - mx, by - my, recip, eb, sb)
    ec[0] = eb[0]
    sc[0] = sb[0]
    return last + 1


cdef inline void _ends(uint64_t ea, uint64_t eb, bint long_left, int64_t* lo, int64_t* hi) noexcept nogil:
    """A row's span from the two edges' ceilings (the long edge's first), ordered by
    the triangle's orientation."""
    cdef int64_t ca = <int64_t>(ea >> 40), cb = <int64_t>(eb >> 40)
    lo[0] = ca if long_left else cb
    hi[0] = cb if long_left else ca


cdef inline int64_t _walk1(sample_t* pixels, sample_t* row, uint64_t arow, uint64_t adx, uint64_t ady, int64_t y,
                           int64_t last, int64_t turn, uint64_t ea, uint64_t sa, uint64_t eb, uint64_t sb,
                           uint64_t ec, uint64_t sc, bint long_left, bint narrow, int64_t w, int64_t h, int mode,
                           uint16_t* counts, int64_t* spans, uint8_t* cover) noexcept nogil:
    """_triangle1's rows y .. last from `row`; `narrow` (a constant at each call, so
    that the compiler makes a walk without the test): every span has at most 8
    samples and room for _put8's word."""
    cdef int64_t lo, hi, written = 0
    cdef sample_t* short_end = pixels + w * h - 8
    while y <= last:
        _ends(ea, eb if y < turn else ec, long_left, &lo, &hi)
        if narrow or (<uint64_t>(hi - lo) <= 8 and row + lo <= short_end):
            _put8(row + lo, arow + adx * <uint64_t>lo, adx, hi - lo)
        else:
            _put_long(row + lo, arow + adx * <uint64_t>lo, adx, hi - lo, short_end)
        written += hi - lo
        if mode != MODE_TOTAL:
            _account(mode, y, lo, hi, w, counts, spans, cover)
        ea += sa
        eb += sb
        ec += sc
        arow += ady
        row += w
        y += 1
    return written


cdef inline int64_t _triangle1(sample_t* pixels, uint64_t arow, uint64_t adx, uint64_t ady, int64_t tx,
                               int64_t ty, int64_t mx, int64_t my, int64_t bx, int64_t by, int64_t last,
                               bint long_left, const uint64_t* recip, int64_t w, int64_t h, int mode,
                               uint16_t* counts, int64_t* spans, uint8_t* cover, int isa) noexcept nogil:
    """A triangle of one channel in fixed point, its edges too (most triangles of a
    gray image; none with a corner in the last column, nor a plane too large for the
    fixed point), its rows walked in locals: the long edge T -> B and the short one,
    T -> M above M's row and M -> B from there on, each edge's ceiling taken alike and
    the two ordered by the triangle's orientation (selects, not a loop per run of
    rows). An edge from column x0 moving dx columns over dy rows has ceil(x) =
    floor(n / dy) on its k-th row, n = x0*dy + dx*k + dy - 1, with 0 <= n < W*dy, read
    as (n * E) >> 40 with E = ceil(2**40 / dy) (exact when W*dy*dy <= 2**40, as for
    the planes: see the module's docstring). Short spans take _put8 (with AVX-512 or
    AVX2, `isa`, and no per-pixel count, atm_walk_avx512 or atm_walk_avx2 takes the
    rows). The pixels written."""
    cdef int64_t turn, xmin = min(tx, mx, bx), xmax = max(tx, mx, bx)
    cdef uint64_t ea, sa, eb, sb, ec, sc
    cdef sample_t* row = pixels + ty * w
    turn = _fixed_edges(tx, ty, mx, my, bx, by, last, recip, &ea, &sa, &eb, &sb, &ec, &sc)
    # a narrow triangle (most of them): every span is [lo, hi) within [xmin, xmax], so
    # at most 8 samples, and the last row's word from xmax lies in the image
    if isa == ISA_AVX512 and mode != MODE_COVER:
        return atm_walk_avx512(pixels, sample_t is uint16_t, xmax - xmin <= 8, ty, last, turn, arow, adx, ady,
                               ea, sa, eb, sb, ec, sc, long_left, w, h, counts if mode == MODE_COUNTS else NULL,
                               spans)
    if isa == ISA_AVX2 and mode != MODE_COVER:
        return atm_walk_avx2(pixels, sample_t is uint16_t, xmax - xmin <= 8, ty, last, turn, arow, adx, ady,
                             ea, sa, eb, sb, ec, sc, long_left, w, h, counts if mode == MODE_COUNTS else NULL, spans)
    if xmax - xmin <= 8 and last * w + xmax + 8 <= w * h:
        return _walk1(pixels, row, arow, adx, ady, ty, last, turn, ea, sa, eb, sb, ec, sc, long_left, True, w, h,
                      mode, counts, spans, cover)
    return _walk1(pixels, row, arow, adx, ady, ty, last, turn, ea, sa, eb, sb, ec, sc, long_left, False, w, h,
                  mode, counts, spans, cover)


cdef int64_t _triangle_colour(sample_t* pixels, Planes* pl, int64_t c, int64_t tx, int64_t ty, int64_t mx,
                              int64_t my, int64_t bx, int64_t by, int64_t last, bint long_left,
                              const uint64_t* recip, int64_t w, int mode, uint16_t* counts, int64_t* spans,
                              uint8_t* cover) noexcept nogil:
    """_triangle1 for C > 1 channels (kept apart: the gray walk keeps its plane in
    registers)."""
    cdef int64_t lo, hi, ch, x, y, turn, written = 0
    cdef uint64_t ea, sa, eb, sb, ec, sc
    cdef uint64_t a0, a1, a2, d0, d1, d2
    cdef sample_t* row = pixels + ty * w * c
    cdef sample_t* p
    turn = _fixed_edges(tx, ty, mx, my, bx, by, last, recip, &ea, &sa, &eb, &sb, &ec, &sc)
    for y in range(ty, last + 1):
        _ends(ea, eb if y < turn else ec, long_left, &lo, &hi)
        if c == 3:
            # RGB pixel by pixel, its channels within: one loop whose exit depends on
            # the span, not one a channel (1.2x on astronaut's RGB mesh)
            p = row + lo * 3
            a0 = pl.row[0] + pl.dx[0] * <uint64_t>lo; d0 = pl.dx[0]; pl.row[0] += pl.dy[0]
            a1 = pl.row[1] + pl.dx[1] * <uint64_t>lo; d1 = pl.dx[1]; pl.row[1] += pl.dy[1]
            a2 = pl.row[2] + pl.dx[2] * <uint64_t>lo; d2 = pl.dx[2]; pl.row[2] += pl.dy[2]
            for x in range(lo, hi):
                if sample_t is uint8_t:
                    p[0] = <sample_t>(a0 >> 54); p[1] = <sample_t>(a1 >> 54); p[2] = <sample_t>(a2 >> 54)
                else:
                    p[0] = <sample_t>(a0 >> 46); p[1] = <sample_t>(a1 >> 46); p[2] = <sample_t>(a2 >> 46)
                a0 += d0; a1 += d1; a2 += d2
                p += 3
        else:
            for ch in range(c):
                a0 = pl.row[ch] + pl.dx[ch] * <uint64_t>lo
                for x in range(lo, hi):
                    if sample_t is uint8_t:
                        row[x * c + ch] = <sample_t>(a0 >> 54)
                    else:
                        row[x * c + ch] = <sample_t>(a0 >> 46)
                    a0 += pl.dx[ch]
                pl.row[ch] += pl.dy[ch]
        written += hi - lo
        if mode != MODE_TOTAL:
            _account(mode, y, lo, hi, w, counts, spans, cover)
        ea += sa
        eb += sb
        ec += sc
        row += w * c
    return written


cdef inline int64_t _corner(const void* tris, int64_t i, bint idx32) noexcept nogil:
    """Triangle corner i (of the 3M) in either index width."""
    return (<const int32_t*>tris)[i] if idx32 else (<const int64_t*>tris)[i]


cdef int64_t _triangles(const int64_t* v, const sample_t* vals, const void* tris, bint idx32, int64_t m, int64_t c,
                        sample_t* pixels, int mode, uint16_t* counts, int64_t* spans, uint8_t* cover,
                        int64_t w, int64_t h, int isa, bint ordered) noexcept nogil:
    """Write every triangle's pixels into `pixels` and account for them as `mode`
    says: MODE_COUNTS in `counts` (a row of W + 1 counters per image row, see the
    module's docstring) and `spans` (non-empty spans per row, or NULL), MODE_COVER by
    counting each pixel's writes in `cover` (capped at 2). Returns the number of pixels
    written. Vertices and corners are checked by the caller; `ordered`: the vertices'
    raster keys increase with their index."""
    cdef int64_t j, k, ch, d, half, d2, last, y, stop, written = 0, ga, gb, lim
    cdef int64_t tx, ty, mx, my, bx, by, dxm, dym, dxb, dyb, dxl, dyl, vt, vm, vb, mult
    cdef int64_t corner[3]
    cdef Edge lng, top, bottom
    cdef Planes pl
    cdef bint long_left, border, run
    cdef int bits
    cdef int64_t edge_lim
    cdef uint64_t* recip
    # s = 62 - log2 V; the fixed point is exact for d2 up to 2**((s - log2 V) / 2)
    if sample_t is uint8_t:
        pl.shift = 54
        lim = 1 << 23
    else:
        pl.shift = 46
        lim = 1 << 15
    # the edges' fixed point (shift 40) is exact for edges over up to
    # 2**((40 - bits(W)) / 2) rows, in images below 2**22 wide (n * E < 2**64)
    bits = 0
    while (<int64_t>1 << bits) <= w:
        bits += 1
    edge_lim = <int64_t>1 << ((40 - bits) // 2) if bits <= 22 else 0
    # (a table of at most 2**16 entries, whatever the band's height)
    edge_lim = min(edge_lim, h - 1, 1 << 16)
    # E for every edge height the fixed point takes (an edge spans 1 .. H - 1 rows):
    # one division per height and call instead of three per triangle
    recip = <uint64_t*>malloc(<size_t>(edge_lim + 1) * sizeof(uint64_t))
    if recip != NULL:
        recip[0] = 0
        if edge_lim >= 1:
            recip[1] = <uint64_t>1 << 40
        for k in range(2, edge_lim + 1):
            recip[k] = _reciprocal(k, 40)
    # with AVX-512, atm_run_avx512 renders the one-channel triangles it can, up to
    # one it cannot, which the loop's body renders
    run = isa != ISA_PORTABLE and c == 1 and recip != NULL and mode != MODE_COVER
    k = 0
    while k < m:
        if run:
            if isa == ISA_AVX512:
                k = atm_run_avx512(v, vals, tris, idx32, k, m, pixels, sample_t is uint16_t, recip, edge_lim,
                                   _RECIPROCAL, w, h, counts if mode == MODE_COUNTS else NULL, spans, &written, ordered)
            else:
                k = atm_run_avx2(v, vals, tris, idx32, k, m, pixels, sample_t is uint16_t, recip, edge_lim,
                                 _RECIPROCAL, w, h, counts if mode == MODE_COUNTS else NULL, spans, &written, ordered)
            if k >= m:
                break
        j = k
        k += 1
        corner[0] = _corner(tris, 3 * j, idx32)
        corner[1] = _corner(tris, 3 * j + 1, idx32)
        corner[2] = _corner(tris, 3 * j + 2, idx32)
        _sort3(corner, v, w, ordered)  # T, M, B
        tx = v[2 * corner[0]]; ty = v[2 * corner[0] + 1]
        mx = v[2 * corner[1]]; my = v[2 * corner[1] + 1]
        bx = v[2 * corner[2]]; by = v[2 * corner[2] + 1]
        dxm = mx - tx; dym = my - ty; dxb = bx - tx; dyb = by - ty
        dxl = bx - mx; dyl = by - my
        d = dxm * dyb - dxb * dym
        if d == 0:
            continue  # degenerate: no area, so no pixel (a validated mesh has none)
        # The plane 2*sum(w_i v_i) + D = ga*x + gb*y + gc of each channel, with the
        # weights and D of the corners in the order T, M, B; |ga| <= 4 H vmax,
        # |gb| <= 4 W vmax, |gc| < 14 W H (vmax + 1): below 2**53. Either orientation:
        # negating the plane and D together leaves a pixel's value floor(plane / 2D)
        # as it is. At T the plane is (2 vt + 1) |D|.
        half = d if d > 0 else -d
        d2 = 2 * half
        pl.d2 = d2
        pl.fast = d2 <= lim
        mult = 1
        if half <= _RECIPROCALS:
            mult = <int64_t>(_RECIPROCAL[half] if sample_t is uint8_t else (_RECIPROCAL[half] + 255) >> 8)
        elif pl.fast:
            mult = <int64_t>_reciprocal(d2, pl.shift)
        for ch in range(c):
            vt = vals[corner[0] * c + ch]; vm = vals[corner[1] * c + ch]; vb = vals[corner[2] * c + ch]
            ga = 2 * (dyb * vm - dyl * vt - dym * vb)
            gb = 2 * (dxl * vt - dxb * vm + dxm * vb)
            if d < 0:
                ga = -ga; gb = -gb
            # N at column 0 of row ty (exact: |ga * tx| < 2**53)
            pl.row[ch] = <uint64_t>((2 * vt + 1) * half - ga * tx) * <uint64_t>mult
            pl.dx[ch] = <uint64_t>ga * <uint64_t>mult
            pl.dy[ch] = <uint64_t>gb * <uint64_t>mult
        # Rows ty .. by - 1, and by too on the image's last row. The long edge T -> B
        # (dyb > 0, as the triangle has area); the short one T -> M above M's row, M -> B
        # from there on (a flat top or bottom has one of them). M lies right of the long
        # edge when d > 0: the long edge is then the left one on every row, else the
        # short one.
        last = by if by == h - 1 else by - 1
        long_left = d > 0
        border = tx == w - 1 or mx == w - 1 or bx == w - 1
        if pl.fast and not border and dyb <= edge_lim and recip != NULL:
            if c == 1:
                written += _triangle1(pixels, pl.row[0], pl.dx[0], pl.dy[0], tx, ty, mx, my, bx, by, last,
                                      long_left, recip, w, h, mode, counts, spans, cover, isa)
            else:
                written += _triangle_colour(pixels, &pl, c, tx, ty, mx, my, bx, by, last, long_left, recip, w,
                                            mode, counts, spans, cover)
            continue
        _edge_start(&lng, tx, dxb, dyb)
        y = ty
        if dym > 0:
            _edge_start(&top, tx, dxm, dym)
            stop = my if dyl > 0 else last + 1
            if long_left:
                written += _rows(pixels, &pl, &lng, &top, y, stop, c, w, border, mode, counts, spans, cover)
            else:
                written += _rows(pixels, &pl, &top, &lng, y, stop, c, w, border, mode, counts, spans, cover)
            y = stop
        if dyl > 0:
            _edge_start(&bottom, mx, dxl, dyl)
            if long_left:
                written += _rows(pixels, &pl, &lng, &bottom, y, last + 1, c, w, border, mode, counts, spans, cover)
            else:
                written += _rows(pixels, &pl, &bottom, &lng, y, last + 1, c, w, border, mode, counts, spans, cover)
    free(recip)
    return written


cdef int _check_counts(const uint16_t* counts, const int64_t* spans, int64_t w, int64_t h) noexcept nogil:
    """Whether every row's counters are (1, 0, ..., 0, -1) and exact: its spans
    tile it."""
    cdef int64_t y, x, stride = w + 1
    cdef uint16_t acc
    cdef const uint16_t* row
    for y in range(h):
        if spans != NULL and spans[y] >= 1 << 15:
            return 0
        row = counts + y * stride
        acc = (row[0] ^ 1) | (row[w] ^ 0xFFFF)
        for x in range(1, w):
            acc |= row[x]
        if acc:
            return 0
    return 1


cdef int _render(const int64_t* v, int64_t nv, const sample_t* vals, int64_t c, const void* tris, bint idx32, int64_t m,
                 sample_t* pixels, int64_t w, int64_t h, int check, int isa, int64_t* detail) noexcept nogil:
    """Check the indices, rasterise, check the coverage; the status code, with
    `detail` set on an error."""
    cdef int64_t k, p, npix = w * h
    cdef uint16_t* counts = NULL
    cdef int64_t* spans = NULL
    cdef uint8_t* cover
    cdef int status = OK
    cdef int64_t key, previous = -1
    cdef bint ordered = True
    for k in range(nv):
        if not (0 <= v[2 * k] < w and 0 <= v[2 * k + 1] < h):
            detail[0] = k
            return BAD_VERTEX
        # whether raster order is index order (a decoder's vertices are in raster
        # order: the walk then orders a triangle's corners by index, no key to make)
        key = v[2 * k + 1] * w + v[2 * k]
        ordered &= key > previous
        previous = key
    for k in range(m):
        # unsigned: a negative index is beyond too
        if ((<uint64_t>_corner(tris, 3 * k, idx32) >= <uint64_t>nv) | (<uint64_t>_corner(tris, 3 * k + 1, idx32) >= <uint64_t>nv)
                | (<uint64_t>_corner(tris, 3 * k + 2, idx32) >= <uint64_t>nv)):
            detail[0] = k
            return BAD_INDEX
    if check == CHECK_TOTAL:
        if _triangles(v, vals, tris, idx32, m, c, pixels, MODE_TOTAL, NULL, NULL, NULL, w, h, isa, ordered) == npix:
            return OK
    else:
        counts = <uint16_t*>calloc(<size_t>((w + 1) * h), sizeof(uint16_t))
        # a triangle gives a row one span at most: with fewer than 2**15 triangles no
        # row can have more spans, and they need no count
        spans = <int64_t*>calloc(<size_t>h, sizeof(int64_t)) if m >= 1 << 15 else NULL
        if counts == NULL or (spans == NULL and m >= 1 << 15):
            free(counts)
            free(spans)
            return NO_MEMORY
        _triangles(v, vals, tris, idx32, m, c, pixels, MODE_COUNTS, counts, spans, NULL, w, h, isa, ordered)
        status = _check_counts(counts, spans, w, h)
        free(counts)
        free(spans)
        if status:
            return OK
    # not a tiling: again, counting every pixel's writes, to name the first bad one
    cover = <uint8_t*>calloc(<size_t>npix, 1)
    if cover == NULL:
        return NO_MEMORY
    _triangles(v, vals, tris, idx32, m, c, pixels, MODE_COVER, NULL, NULL, cover, w, h, isa, ordered)
    status = OK
    for p in range(npix):
        if cover[p] != 1:
            status = UNCOVERED if cover[p] == 0 else TWICE
            detail[0] = p
            break
    free(cover)
    return status


def rasterise(const int64_t[:, ::1] vertices, const sample_t[:, ::1] values,
              const index_t[:, ::1] triangles, sample_t[:, ::1] out,
              int64_t width, int64_t height, int check=CHECK_SPANS, bint portable=False, bint zero=False,
              walk=None):
    """Rasterise the triangles (corner indices int64 or int32) into `out` (H*W x C,
    C <= 4; the samples' type),
    checking that every pixel is written exactly once (`check`: CHECK_SPANS for any
    mesh, CHECK_TOTAL only for one known to tile the image). Checks every index it
    reads: returns (status, detail) with status OK or one of the codes above.
    Releases the GIL; nothing else may write `out` during the call (short spans are
    merged into it word by word, the samples around them written back as read).
    portable=True: the portable walk even where the processor has AVX-512 (which
    gives the same pixels; for tests); walk: one of WALKS to take instead of the
    fastest (ValueError for a walk this processor cannot take; for tests and
    benchmarks). zero=True: `out` is set to 0 first, in the same
    release of the GIL (a new image's zeroing and first-touch page faults are work
    that another thread's Python need not wait for)."""
    cdef int64_t detail = 0, nv = vertices.shape[0], m = triangles.shape[0], c = values.shape[1]
    cdef int status
    if c > 4 or c < 1 or values.shape[0] != nv or vertices.shape[1] != 2:
        raise ValueError("rasterise: 1 to 4 channels, one row of values per vertex")
    # W*H <= 2**32 (the exact arithmetic's bound), checked before the product could wrap
    if width < 1 or height < 1 or width > ((<int64_t>1) << 32) // height:
        raise ValueError("rasterise: an image of 1 to 2**32 pixels")
    if triangles.shape[1] != 3 or out.shape[0] != width * height or out.shape[1] != c:
        raise ValueError("rasterise: M x 3 triangles and an H*W x C output")
    if width < 1 or height < 1:
        raise ValueError("rasterise: an image of at least one pixel")
    if check != CHECK_SPANS and check != CHECK_TOTAL:
        raise ValueError(f"rasterise: unknown coverage check {check}")
    if walk is not None and walk not in WALKS:
        raise ValueError(f"rasterise: walk {walk!r} is not one of this processor's {WALKS}")
    cdef int isa = _ISA_NAMES.index("portable" if portable else walk if walk is not None else WALKS[0])
    # the first element's address, read only where there are elements
    cdef const int64_t* v = &vertices[0, 0] if nv else NULL
    cdef const sample_t* vals = &values[0, 0] if nv else NULL
    cdef const void* tris = &triangles[0, 0] if m else NULL
    with nogil:
        if zero:
            memset(&out[0, 0], 0, <size_t>(width * height * c) * sizeof(sample_t))
        status = _render(v, nv, vals, c, tris, index_t is int32_t, m, &out[0, 0], width, height, check,
                         isa, &detail)
    if status == NO_MEMORY:
        raise MemoryError(f"rasterise: no memory for the coverage counters of a {width}x{height} image")
    return status, detail
