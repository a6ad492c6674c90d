"""The meshers: an image (one band of rows) in, a Mesh of it out.

adaptive: the discontinuity-preserving mesher, in stages, each a module: edges
(Canny), polylines (edge pixels to control points), unfold (polylines to parallel
walls), sampling (curvature-driven region samples), refine (error-driven vertex
insertion to the budget) and values (vertex values). uniform: the grid baseline.
elements: which pixels each triangle owns and the sums over them that the stages
measure with.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass
from typing import Callable

from ..mesh import Mesh


@dataclass(frozen=True)
class Meshed:
    """What a mesher's build() returns: the mesh, and what later stages would otherwise
    measure again.

    mse: the mean squared error (over all pixels, against the image meshed) that
        decoding the mesh gives, where the mesher's own sums tell it at no cost; else
        None. It describes this mesh only: a stage that changes the mesh drops it.
    delaunay: the triangles are the constrained Delaunay triangulation of the vertices
        and walls in stored order (codec.meshcode.in_stored_order), the one a decoder
        rebuilds, so the band's coder need not triangulate to find out.
    """

    mesh: Mesh
    mse: float | None = None
    delaunay: bool = False


#: A change a mesher's caller makes to the mesh just before its last triangulation:
#: finish(mesh, mse) -> mesh, given the mesh's vertices (their values their pixels')
#: and walls without triangles, and the mean squared error the mesher last measured
#: (None if it measured none); the mesher then triangulates what it returns, fits its
#: values and returns that (a band's shared rows and holes: codec.pipeline).
Finish = Callable[[Mesh, "float | None"], Mesh]

#: Mesher name -> its module (each has `build(image, points, **options) -> Meshed`).
_MODULES = (("adaptive", "codec.mesher.adaptive"), ("uniform", "codec.mesher.uniform"))


def builder(name: str) -> Callable[..., Meshed]:
    """The named mesher's build() (names: codec.settings.MESHERS)."""
    return importlib.import_module(dict(_MODULES)[name]).build
