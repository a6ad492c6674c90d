"""The compiled kernels (Cython, codec/_*.pyx), imported in one place, so that a
package installed without building them fails at once with a message saying how to
build them. There is no pure-Python fallback: one code path."""

from __future__ import annotations

try:
    from . import _cdt, _elements, _fields, _lsq, _mask, _polylines, _rasterise, _renumber, _residual, _samples, _gradients, _bound
except ImportError as exc:  # pragma: no cover - depends on how the package was installed
    raise ImportError(
        "codec's compiled kernels (codec._rasterise, codec._fields, codec._cdt, codec._residual, codec._renumber, codec._mask, codec._elements, codec._polylines, codec._lsq, codec._samples, codec._gradients, codec._bound) are not built: install "
        "the package with `pip install -e .` (or `pip install .`) from its source folder, "
        f"which compiles them (a C compiler is needed where no wheel fits); {exc}"
    ) from exc

__all__ = ["_cdt", "_fields", "_rasterise", "_renumber", "_residual", "_mask", "_elements", "_polylines", "_lsq", "_samples", "_gradients", "_bound"]
