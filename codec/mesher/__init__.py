"""The meshers: an image (one band of rows) in, a Mesh of it out.

adaptive: the discontinuity-preserving mesher, in stages, each a module: edges
(Canny), polylines (edge pixels to control points), unfold (polylines to parallel
walls), sampling (curvature-driven region samples), refine (error-driven vertex
insertion to the budget) and values (vertex values). uniform: the grid baseline.
elements: which pixels each triangle owns and the sums over them that the stages
measure with.
"""
