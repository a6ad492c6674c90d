"""Encoder kernel: the per-pixel arithmetic the adaptive mesher does on OpenCV's
derivatives, in one pass each instead of a numpy temporary per operation (a 512²
image's float32 planes are a megabyte each): the gradient magnitude and Canny's
fixed-point derivatives (codec.mesher.edges), the norm of the Hessian
(codec.mesher.sampling). Each gives the very float32 numbers numpy gave (the same
operations in the same order, in float32, without contraction). The GIL is released
while they work."""

from libc.math cimport rintf, sqrtf
from libc.stdint cimport int16_t

import numpy as np


def edge_gradient(const float[:, ::1] sx, const float[:, ::1] sy, float limit, float scale):
    """(magnitude, ix, iy) of Sobel derivatives sx, sy (H x W float32): dx = sx / 4,
    dy = sy / 4, magnitude = sqrt(dx dx + dy dy) (float32), and ix, iy = dx, dy clipped
    to +-limit, times scale, rounded half to even (int16; limit * scale within int16)."""
    cdef Py_ssize_t h = sx.shape[0], w = sx.shape[1]
    if sy.shape[0] != h or sy.shape[1] != w:
        raise ValueError("edge_gradient: dx and dy differ in size")
    if not (0 <= limit and rintf(limit * scale) <= 32767):
        raise ValueError("edge_gradient: the clipped derivatives do not fit int16")
    mag_out = np.empty((h, w), dtype=np.float32)
    ix_out = np.empty((h, w), dtype=np.int16)
    iy_out = np.empty((h, w), dtype=np.int16)
    if h == 0 or w == 0:
        return mag_out, ix_out, iy_out
    # flat pointers over the C-contiguous planes: a loop the compiler can vectorise
    cdef const float* a = &sx[0, 0]
    cdef const float* b = &sy[0, 0]
    cdef float[:, ::1] mag_v = mag_out
    cdef int16_t[:, ::1] ix_v = ix_out, iy_v = iy_out
    cdef float* mag = &mag_v[0, 0]
    cdef int16_t* ix = &ix_v[0, 0]
    cdef int16_t* iy = &iy_v[0, 0]
    cdef Py_ssize_t i, n = h * w
    # float constants: a literal would make Cython compute in double
    cdef float dx, dy, lo = -limit, quarter = 0.25, shift = 12582912
    with nogil:
        for i in range(n):
            # times 1/4 is sx / 4 exactly (a power of two), and quicker
            dx = a[i] * quarter
            dy = b[i] * quarter
            mag[i] = sqrtf(dx * dx + dy * dy)
            # np.clip: NaN stays NaN (and would not fit int16 anyway)
            dx = lo if dx < lo else (limit if dx > limit else dx)
            dy = lo if dy < lo else (limit if dy > limit else dy)
            # round half to even by adding and taking away 1.5 * 2^23 (exact below 2^22,
            # and |dx scale| <= 32767): rintf is a library call the loop cannot inline
            ix[i] = <int16_t>((dx * scale + shift) - shift)
            iy[i] = <int16_t>((dy * scale + shift) - shift)
    return mag_out, ix_out, iy_out


def hessian_norm(const float[:, ::1] dxx, const float[:, ::1] dyy, const float[:, ::1] dxy):
    """sqrt(dxx dxx + 2 dxy dxy + dyy dyy) (H x W float32) of second derivatives."""
    cdef Py_ssize_t h = dxx.shape[0], w = dxx.shape[1]
    if dyy.shape[0] != h or dyy.shape[1] != w or dxy.shape[0] != h or dxy.shape[1] != w:
        raise ValueError("hessian_norm: the derivatives differ in size")
    out = np.empty((h, w), dtype=np.float32)
    if h == 0 or w == 0:
        return out
    cdef float[:, ::1] o_v = out
    cdef float* o = &o_v[0, 0]
    cdef const float* pa = &dxx[0, 0]
    cdef const float* pb = &dxy[0, 0]
    cdef const float* pc = &dyy[0, 0]
    cdef Py_ssize_t i, n = h * w
    cdef float a, b, c, two = 2  # a float: a literal 2 would make Cython compute in double
    with nogil:
        for i in range(n):
            a = pa[i]
            b = pb[i]
            c = pc[i]
            o[i] = sqrtf(a * a + two * b * b + c * c)
    return out
