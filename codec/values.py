"""Vertex values: what each mesh vertex stores, given the image and the triangulation."""

from __future__ import annotations

import numpy as np

from .errors import OptionError

METHODS = ("sample", "lsq")


def sample(image: np.ndarray, vertices: np.ndarray) -> np.ndarray:
    """The pixel value under each vertex (the seed's choice)."""
    return image[vertices[:, 1], vertices[:, 0]].copy()


def _to_dtype(values: np.ndarray, dtype: np.dtype) -> np.ndarray:
    info = np.iinfo(dtype)
    return np.clip(np.round(values), info.min, info.max).astype(dtype)


def gram(raster) -> tuple[np.ndarray, np.ndarray]:
    """Per element, the 3 x 3 sums over its pixels of w_i w_j; and the moments used."""
    m = raster.moments()  # 1, u, v, uu, uv, vv
    a, b, g = (raster.coef[:, :, k].astype(np.float64) for k in range(3))
    out = np.empty((len(raster.den), 3, 3))
    for i in range(3):
        for j in range(3):
            out[:, i, j] = (
                a[:, i] * a[:, j] * m[:, 3]
                + (a[:, i] * b[:, j] + b[:, i] * a[:, j]) * m[:, 4]
                + b[:, i] * b[:, j] * m[:, 5]
                + (a[:, i] * g[:, j] + g[:, i] * a[:, j]) * m[:, 1]
                + (b[:, i] * g[:, j] + g[:, i] * b[:, j]) * m[:, 2]
                + g[:, i] * g[:, j] * m[:, 0]
            )
    den = raster.den.astype(np.float64)
    return out / (den * den)[:, None, None], m


def least_squares(image: np.ndarray, vertices: np.ndarray, raster) -> np.ndarray:
    """Vertex values minimising the squared error over all pixels, for the decoder's
    pixel weights (`raster`: a codec.raster.Raster of the mesh), in the image's dtype.

    The normal equations A^T A z = A^T b are assembled per element from closed-form
    pixel sums and solved by conjugate gradients from the sampled values; A^T A is
    positive definite because every vertex sits on a pixel where its own weight is 1.
    """
    import scipy.sparse as sp
    from scipy.sparse.linalg import cg

    from .raster import RowPrefix

    n = len(vertices)
    channels = 1 if image.ndim == 2 else image.shape[2]
    planes = image.reshape(image.shape[0], image.shape[1], channels)
    c = raster.corners
    g, _ = gram(raster)
    rows = np.repeat(c, 3, axis=1).ravel()
    cols = np.tile(c, (1, 3)).ravel()
    ata = sp.csr_matrix((g.ravel(), (rows, cols)), shape=(n, n))
    den = raster.den.astype(np.float64)
    coef = raster.coef.astype(np.float64)
    start = sample(image, vertices).reshape(n, channels).astype(np.float64)
    precond = sp.diags(1.0 / ata.diagonal())
    out = np.empty((n, channels))
    for ch in range(channels):
        mb = raster.image_moments(RowPrefix(planes[:, :, ch]))  # b, ub, vb, bb
        per_corner = (coef[:, :, 0] * mb[:, 1:2] + coef[:, :, 1] * mb[:, 2:3] + coef[:, :, 2] * mb[:, 0:1]) / den[:, None]
        atb = np.bincount(c.ravel(), weights=per_corner.ravel(), minlength=n)
        # values are rounded to integers afterwards, so a loose tolerance is enough
        out[:, ch], _ = cg(ata, atb, x0=start[:, ch], rtol=1e-5, maxiter=200, M=precond)
    out = _to_dtype(out, image.dtype)
    return out[:, 0] if image.ndim == 2 else out


def fit(image: np.ndarray, vertices: np.ndarray, triangles: np.ndarray, method: str) -> np.ndarray:
    """Vertex values by `method`, in the image's dtype."""
    if method == "sample":
        return sample(image, vertices)
    if method == "lsq":
        from .raster import rasterize

        height, width = image.shape[:2]
        return least_squares(image, vertices, rasterize(vertices, triangles, width, height))
    raise OptionError(f"unknown values method {method!r}; choose one of {', '.join(METHODS)}")
