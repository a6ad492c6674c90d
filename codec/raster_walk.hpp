/* The rasteriser's SIMD walk, C included by codec/_rasterise.pyx once per instruction
   set (no include guard): ATM_NAME(x) names its functions for that set (x_avx512,
   x_avx2), ATM_TARGET is its target attribute, and these come before it:
   ATM_NAME(atm_steps)(adx, &k0, &k4): the two registers that atm_eight adds to a
   span's first value; ATM_NAME(atm_eight)(a, k0, k4, wide): the 8 samples
   (a + k*adx) >> shift, k = 0..7, as bytes (u8) or words (u16), in a 128-bit register;
   ATM_NAME(atm_store8)(p, s, n, wide, end): samples 0 .. n - 1 (n <= 8) of s stored at
   p, the image ending at end. One body for both sets, so that they take the same span
   ends and fixed-point samples: the same pixels. (C, despite the name: setup.py's
   depends and MANIFEST.in take the kernels' .hpp files.) */
static inline ATM_TARGET int64_t ATM_NAME(atm_rows)(void* pixels, int64_t y, int64_t last, int64_t turn,
                                          uint64_t arow, uint64_t adx, uint64_t ady,
                                          uint64_t ea, uint64_t sa, uint64_t eb, uint64_t sb,
                                          uint64_t ec, uint64_t sc, int long_left, int64_t w,
                                          uint16_t* counts, int64_t* spans, int wide, int narrow,
                                          int counting, const char* end) {
    /* the left edge's ceiling and the right one's: the long edge's is the left one
       when long_left (a walk for each: no select a row) */
    uint64_t el = long_left ? ea : eb, sl = long_left ? sa : sb, er = long_left ? eb : ea;
    uint64_t sr = long_left ? sb : sa;
    __m256i k0, k4;
    int64_t written = 0, lo, hi, n, size = wide ? 2 : 1;
    char* row = (char*)pixels + y * w * size;
    char* p;
    uint64_t a;
    ATM_NAME(atm_steps)(adx, &k0, &k4);
    for (; y <= last; y++) {
        if (long_left) {
            lo = (int64_t)(el >> 40);
            hi = (int64_t)((y < turn ? er : ec) >> 40);
        } else {
            lo = (int64_t)((y < turn ? el : ec) >> 40);
            hi = (int64_t)(er >> 40);
        }
        n = hi - lo;
        a = arow + adx * (uint64_t)lo;
        p = row + lo * size;
        if (!narrow) {
            for (; n > 8; n -= 8, p += 8 * size, a += 8 * adx)
                ATM_NAME(atm_store8)(p, ATM_NAME(atm_eight)(a, k0, k4, wide), 8, wide, end);
        }
        ATM_NAME(atm_store8)(p, ATM_NAME(atm_eight)(a, k0, k4, wide), n, wide, end);
        written += hi - lo;
        if (counting && lo < hi) {  /* MODE_COUNTS' bookkeeping (_account's) */
            counts[y * (w + 1) + lo] += 1;
            counts[y * (w + 1) + hi] -= 1;
            if (spans)
                spans[y] += 1;
        }
        el += sl;
        er += sr;
        ec += sc;
        arow += ady;
        row += w * size;
    }
    return written;
}
static ATM_TARGET int64_t ATM_NAME(atm_walk)(void* pixels, int wide, int narrow, int64_t y, int64_t last,
                                          int64_t turn, uint64_t arow, uint64_t adx, uint64_t ady,
                                          uint64_t ea, uint64_t sa, uint64_t eb, uint64_t sb,
                                          uint64_t ec, uint64_t sc, int long_left, int64_t w,
                                          int64_t h, uint16_t* counts, int64_t* spans) {
    /* eight walks, each with its sample size, span test and bookkeeping known to
       the compiler; end: the image's end, which a store that needs room checks */
    const char* end = (const char*)pixels + w * h * (wide ? 2 : 1);
#define ATM_WALK(ll, wide, narrow, counting) ATM_NAME(atm_rows)(pixels, y, last, turn, arow, adx, ady, ea, sa, eb, \
                                                      sb, ec, sc, ll, w, counts, spans, wide, narrow, counting, end)
#define ATM_WALKS(wide, narrow, counting) (long_left ? ATM_WALK(1, wide, narrow, counting) \
                                                     : ATM_WALK(0, wide, narrow, counting))
    if (counts)
        return wide ? (narrow ? ATM_WALKS(1, 1, 1) : ATM_WALKS(1, 0, 1))
                    : (narrow ? ATM_WALKS(0, 1, 1) : ATM_WALKS(0, 0, 1));
    return wide ? (narrow ? ATM_WALKS(1, 1, 0) : ATM_WALKS(1, 0, 0))
                : (narrow ? ATM_WALKS(0, 1, 0) : ATM_WALKS(0, 0, 0));
#undef ATM_WALKS
#undef ATM_WALK
}
/* _triangles' loop over one-channel triangles k, k + 1, ... with the walk above:
   the same set-up as its own (_sort3's order, the plane with the table's
   multiplier, _fixed_edges' edges), here so that the compiler sees the set-up
   and the walk together. Stops at the first triangle the fast walk does not take
   (|D| over the table's 2048, a corner in the last column, an edge over
   edge_lim rows), which the caller renders its own way: the index where it
   stopped (m at the end); the pixels written are added to *written. */
static inline ATM_TARGET int64_t ATM_NAME(atm_triangles)(const int64_t* v, const void* values, const void* tris,
                                         int64_t k, int64_t m, void* pixels, const uint64_t* recip,
                                         int64_t edge_lim, const uint64_t* table, int64_t w, int64_t h,
                                         uint16_t* counts, int64_t* spans, int64_t* written,
                                         int wide, int idx32, int ordered) {
    int64_t a, b, c, t, ka, kb, kc, kt, tx, ty, mx, my, bx, by, dxm, dym, dxb, dyb, dxl, dyl;
    int64_t d, half, vt, vm, vb, ga, gb, last, turn, xmin, xmax, total = 0;
    uint64_t mult, arow, adx, ady, ea, sa, eb, sb, ec, sc;
    int s, border;
    for (; k < m; k++) {
        if (idx32) {
            a = ((const int32_t*)tris)[3 * k]; b = ((const int32_t*)tris)[3 * k + 1]; c = ((const int32_t*)tris)[3 * k + 2];
        } else {
            a = ((const int64_t*)tris)[3 * k]; b = ((const int64_t*)tris)[3 * k + 1]; c = ((const int64_t*)tris)[3 * k + 2];
        }
        /* raster order: by the pixel keys, or by index where the keys increase
           with it (a decoder's vertices: no key to make) */
        if (ordered) {
            ka = a; kb = b; kc = c;
        } else {
            ka = v[2 * a + 1] * w + v[2 * a]; kb = v[2 * b + 1] * w + v[2 * b]; kc = v[2 * c + 1] * w + v[2 * c];
        }
        s = kb < ka;
        t = s ? b : a; b = s ? a : b; a = t;
        kt = s ? kb : ka; kb = s ? ka : kb; ka = kt;
        s = kc < kb;
        t = s ? c : b; c = s ? b : c; b = t;
        kt = s ? kc : kb; kc = s ? kb : kc; kb = kt;
        s = kb < ka;
        t = s ? b : a; b = s ? a : b; a = t;
        tx = v[2 * a]; ty = v[2 * a + 1];
        mx = v[2 * b]; my = v[2 * b + 1];
        bx = v[2 * c]; by = v[2 * c + 1];
        dxm = mx - tx; dym = my - ty; dxb = bx - tx; dyb = by - ty;
        dxl = bx - mx; dyl = by - my;
        d = dxm * dyb - dxb * dym;
        if (d == 0)
            continue;
        half = d > 0 ? d : -d;
        border = (tx == w - 1) | (mx == w - 1) | (bx == w - 1);
        if (half > 2048 || border || dyb > edge_lim)
            break;
        mult = wide ? (table[half] + 255) >> 8 : table[half];
        if (wide) {
            vt = ((const uint16_t*)values)[a]; vm = ((const uint16_t*)values)[b]; vb = ((const uint16_t*)values)[c];
        } else {
            vt = ((const uint8_t*)values)[a]; vm = ((const uint8_t*)values)[b]; vb = ((const uint8_t*)values)[c];
        }
        /* _triangles' ga and gb with dyl = dyb - dym and dxl = dxb - dxm put in
           (the same integers, two products fewer) */
        ga = 2 * (dyb * (vm - vt) - dym * (vb - vt));
        gb = 2 * (dxm * (vb - vt) - dxb * (vm - vt));
        if (d < 0) {
            ga = -ga;
            gb = -gb;
        }
        arow = (uint64_t)((2 * vt + 1) * half - ga * tx) * mult;
        adx = (uint64_t)ga * mult;
        ady = (uint64_t)gb * mult;
        last = by == h - 1 ? by : by - 1;
        ea = (uint64_t)(tx * dyb + dyb - 1) * recip[dyb];
        sa = (uint64_t)dxb * recip[dyb];
        if (dym > 0) {
            eb = (uint64_t)(tx * dym + dym - 1) * recip[dym];
            sb = (uint64_t)dxm * recip[dym];
            ec = (uint64_t)(mx * dyl + dyl - 1) * recip[dyl];
            sc = (uint64_t)dxl * recip[dyl];
            ec -= (uint64_t)dym * sc;
            turn = by > my ? my : last + 1;
        } else {
            eb = (uint64_t)(mx * dyl + dyl - 1) * recip[dyl];
            sb = (uint64_t)dxl * recip[dyl];
            ec = eb;
            sc = sb;
            turn = last + 1;
        }
        xmin = tx < mx ? tx : mx; xmin = xmin < bx ? xmin : bx;
        xmax = tx > mx ? tx : mx; xmax = xmax > bx ? xmax : bx;
        /* the walk a call of its own: inlined here, its eight forms made the loop
           slower than the call */
        total += ATM_NAME(atm_walk)(pixels, wide, xmax - xmin <= 8, ty, last, turn, arow, adx, ady, ea, sa,
                                 eb, sb, ec, sc, d > 0, w, h, counts, spans);
    }
    *written += total;
    return k;
}
static ATM_TARGET int64_t ATM_NAME(atm_run)(const int64_t* v, const void* values, const void* tris, int idx32,
                                         int64_t k, int64_t m, void* pixels, int wide,
                                         const uint64_t* recip, int64_t edge_lim, const uint64_t* table,
                                         int64_t w, int64_t h, uint16_t* counts, int64_t* spans,
                                         int64_t* written, int ordered) {
    /* a loop for each sample size, index width and corner order */
#define ATM_RUN(wide, idx32, ordered) ATM_NAME(atm_triangles)(v, values, tris, k, m, pixels, recip, edge_lim, table, w, h, \
                                              counts, spans, written, wide, idx32, ordered)
#define ATM_RUNS(wide, idx32) (ordered ? ATM_RUN(wide, idx32, 1) : ATM_RUN(wide, idx32, 0))
    if (idx32)
        return wide ? ATM_RUNS(1, 1) : ATM_RUNS(0, 1);
    return wide ? ATM_RUNS(1, 0) : ATM_RUNS(0, 0);
#undef ATM_RUNS
#undef ATM_RUN
}
