"""Builds the compiled kernels (Cython, codec/_*.pyx); everything else is in
pyproject.toml. Extra compiler flags (e.g. a sanitizer, fuzz/asan.sh) come through
the usual CFLAGS and LDFLAGS."""

import glob
import sys

from Cython.Build import cythonize
from setuptools import Extension, setup

#: The kernels, each a module of its own.
KERNELS = ["codec._rasterise", "codec._fields", "codec._cdt", "codec._residual", "codec._renumber", "codec._mask", "codec._elements", "codec._polylines", "codec._lsq", "codec._samples", "codec._gradients", "codec._bound"]

# MSVC spells optimisation its own way; gcc and clang take -O2. No fused multiply-add
# contraction (gcc and clang contract by default where the target has FMA, e.g. ARM):
# the encoder's float sums pick worst pixels and plane values, so an encode must give
# the same bytes on every platform (/fp:precise, MSVC's default, does not contract).
OPTIMISE = ["/O2", "/fp:precise"] if sys.platform == "win32" else ["-O2", "-ffp-contract=off"]

#: Encoder-only kernels built at -O3 (gcc and clang; MSVC's /O2 is its highest): their
#: per-triangle helpers (_elements' row walk, corner sort, plane) are `inline` but -O2's
#: inlining limits leave them as calls. -O3 keeps IEEE semantics (no reassociation
#: without -ffast-math; contraction stays off), so the numbers and bytes are the same.
#: _gradients' square roots (sqrtf, sqrt) vectorise only without errno, which nothing
#: reads: -fno-math-errno keeps their correctly rounded results. Its clips (selects
#: that keep NaN) and float-to-int conversions vectorise only with -fno-trapping-math:
#: nothing enables floating-point traps, and the values are the same.
PER_KERNEL = {} if sys.platform == "win32" else {
    "codec._elements": ["-O3"], "codec._lsq": ["-O3"],
    "codec._gradients": ["-O3", "-fno-math-errno", "-fno-trapping-math"],
}

extensions = [
    # depends: C++ headers beside a kernel (codec/cdt.hpp), rebuilt on change, in the sdist
    # (and the Cython declarations a kernel cimports, codec/rangecoder.pxd)
    Extension(name, [name.replace(".", "/") + ".pyx"], extra_compile_args=OPTIMISE + PER_KERNEL.get(name, []),
              depends=glob.glob("codec/*.hpp") + glob.glob("codec/*.pxd"))
    for name in KERNELS
]

setup(
    ext_modules=cythonize(
        extensions,
        compiler_directives={
            "language_level": 3,
            # the kernels check every index they read from a file themselves
            "boundscheck": False,
            "wraparound": False,
            "initializedcheck": False,
            "cdivision": True,
        },
    )
)
