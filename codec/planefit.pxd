# The squared error of a plane over an element's pixels from the element's sums, as
# an inline function the encoder's kernels cimport (codec._elements' statistics walk,
# codec._lsq's planar share): elements.squared_error's float64 operations in its order,
# so that every kernel gives the numbers numpy gave.


cdef inline double plane_sse(double a, double b, double c, double m0, double m1, double m2, double m3,
                             double m4, double m5, double b0, double b1, double b2, double b3) noexcept nogil:
    # sum over the pixels of (v - f)^2 for f = a u + b v + c, from the moments (1, u, v,
    # uu, uv, vv) and the image sums (b, ub, vb, bb), term by term from
    # the left; below zero taken as zero (np.maximum: -0.0 and NaN stay as they are)
    cdef double ff, bf, d
    ff = a * a * m3
    ff = ff + 2 * a * b * m4
    ff = ff + b * b * m5
    ff = ff + 2 * a * c * m1
    ff = ff + 2 * b * c * m2
    ff = ff + c * c * m0
    bf = a * b1
    bf = bf + b * b2
    bf = bf + c * b0
    d = b3 - 2 * bf + ff
    return d if d >= 0.0 or d != d else 0.0
