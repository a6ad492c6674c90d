"""Builds the compiled kernels (Cython, codec/_*.pyx); everything else is in
pyproject.toml. Extra compiler flags (e.g. a sanitizer, fuzz/asan.sh) come through
the usual CFLAGS and LDFLAGS."""

import glob
import sys

from Cython.Build import cythonize
from setuptools import Extension, setup

#: The kernels, each a module of its own.
KERNELS = ["codec._rasterise", "codec._fields", "codec._cdt", "codec._residual", "codec._renumber", "codec._lsq"]

# MSVC spells optimisation its own way; gcc and clang take -O2.
OPTIMISE = ["/O2"] if sys.platform == "win32" else ["-O2"]

extensions = [
    # depends: C++ headers beside a kernel (codec/cdt.hpp), rebuilt on change, in the sdist
    Extension(name, [name.replace(".", "/") + ".pyx"], extra_compile_args=OPTIMISE,
              depends=glob.glob("codec/*.hpp"))
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
