"""Stage 2: edge polylines by the rule of the paper
"Approximation of Digital Images with Discontinuity-Preserving Adaptive Triangular Meshes",
section 3.3.2.1, "Edge Adaptive Sampling".

The edge map is thinned to one pixel, cut at bifurcations (pixels with three or more
8-neighbours) into simple chains, and each chain is ordered from its start point: its
first end in scan-line order (for a closed chain, its first pixel, the chain then
returning to it). Along a chain the paper's rule picks the control points: from the
starting point A a reference point C `segment_length` pixels ahead; while every pixel
between A and C is within `segment_error` of segment AC, C advances by
`segment_length`; otherwise the first offending pixel becomes the next starting point.
A chain ends at its extreme or at the bifurcation pixel, which closes the polyline.
Chains are taken in the scan-line order of their start points and share no pixels but
bifurcations, so the result depends on the image alone.

Chain ordering and the segment rule walk the chains pixel by pixel in a compiled
kernel (codec._polylines); the rest is vectorised.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .. import native
from ..errors import OptionError

# 8-neighbour offsets (dy, dx) in a fixed order; bit k of a pixel's code is neighbour k
_OFFSETS = np.array([(-1, -1), (-1, 0), (-1, 1), (0, 1), (1, 1), (1, 0), (1, -1), (0, -1)])


def _simple_table() -> np.ndarray:
    """For each 8-neighbourhood code: True when the centre pixel is redundant (it has at
    least two neighbours and they stay 8-connected without it), i.e. a staircase
    corner whose removal leaves a thinner curve with the same connectivity."""
    table = np.zeros(256, dtype=bool)
    for code in range(256):
        on = [k for k in range(8) if code >> k & 1]
        if len(on) < 2:
            continue
        seen, todo = {on[0]}, [on[0]]
        while todo:
            a = todo.pop()
            for b in on:
                if b not in seen and np.abs(_OFFSETS[a] - _OFFSETS[b]).max() <= 1:
                    seen.add(b)
                    todo.append(b)
        table[code] = len(seen) == len(on)
    return table


_REDUNDANT = _simple_table()


class _Grid:
    """The image padded by one pixel and flattened, so that the 8 neighbours of a pixel
    are fixed index offsets with no bounds checks."""

    def __init__(self, mask: np.ndarray):
        h, w = mask.shape
        self.h, self.w, self.stride = h, w, w + 2
        self.on = np.pad(mask, 1).ravel()
        self.offsets = _OFFSETS[:, 0] * self.stride + _OFFSETS[:, 1]


_REDUNDANT_U8 = _REDUNDANT.astype(np.uint8)
# constant tables, shared by every call and thread: frozen
for _table in (_OFFSETS, _REDUNDANT, _REDUNDANT_U8):
    _table.flags.writeable = False
del _table


def thin_split(grid: _Grid) -> tuple[np.ndarray, np.ndarray]:
    """Remove redundant staircase pixels in place (two passes over the two checkerboard
    colours, so that no two removed pixels are 4-neighbours and connectivity is kept;
    each pass's codes from the mask as it found it), then split what is left:
    (junction, simple) flat masks, the pixels with three or more neighbours and the
    others. One compiled pass over the edge pixels (codec._polylines.thin_split)
    instead of three image filters and two look-up passes over every pixel."""
    return native._polylines.thin_split(grid.on.view(np.uint8), grid.stride, _REDUNDANT_U8)


@dataclass(eq=False)
class Polylines:
    """Control points of all polylines: points[i] = (x, y); polyline k is
    points[starts[k]:starts[k+1]]. chain_pixels[k] / strength[k]: the edge pixels each
    polyline approximates and their summed squared gradient (its worth as a wall)."""

    points: np.ndarray
    starts: np.ndarray
    pixels: np.ndarray  # P x 2 (x, y) of all chain pixels
    pixel_line: np.ndarray  # P: polyline of each chain pixel
    strength: np.ndarray

    def __len__(self) -> int:
        return len(self.starts) - 1

    def line(self, k: int) -> np.ndarray:
        return self.points[self.starts[k] : self.starts[k + 1]]

    def take(self, chosen: np.ndarray) -> "Polylines":
        """The polylines chosen[0], chosen[1], ... (distinct indices), in that order."""
        chosen = np.asarray(chosen, dtype=np.int64)
        sizes = np.diff(self.starts)[chosen]
        # each chosen polyline's points, then its pixels, one block after another
        points = self.points[_blocks(self.starts[:-1][chosen], sizes)]
        line = self.pixel_line
        if len(line) and not (line[1:] >= line[:-1]).all():
            # pixels not grouped by polyline (trace's are): grouped first, stably
            grouped = np.argsort(line, kind="stable")
            pixels, line = self.pixels[grouped], line[grouped]
        else:
            pixels = self.pixels
        counts = np.bincount(line, minlength=len(self))
        firsts = np.cumsum(counts) - counts
        return Polylines(
            points,
            np.concatenate([[0], np.cumsum(sizes)]),
            pixels[_blocks(firsts[chosen], counts[chosen])],
            np.repeat(np.arange(len(chosen), dtype=np.int64), counts[chosen]),
            self.strength[chosen],
        )


def _blocks(firsts: np.ndarray, sizes: np.ndarray) -> np.ndarray:
    """Indices of the runs firsts[k] .. firsts[k] + sizes[k] - 1, one after another."""
    return np.repeat(firsts - (np.cumsum(sizes) - sizes), sizes) + np.arange(int(sizes.sum()))


def _order_chains(simple: np.ndarray, offsets: np.ndarray):
    """Order the pixels of the simple chains (max degree 2) of a padded flat mask, each
    chain walked from its start (codec._polylines.order_chains).

    Returns (flat, chain, closed): padded pixel indices in chain order, the chain of
    each, and for each chain whether it is a closed loop.
    """
    return native._polylines.order_chains(
        np.ascontiguousarray(simple, dtype=bool).view(np.uint8), np.ascontiguousarray(offsets, dtype=np.int64)
    )


def _control_points(xy: np.ndarray, first: np.ndarray, last: np.ndarray, k: int, d: float):
    """The paper's segment rule (section 3.3.2.1) on every chain, one after another
    (codec._polylines.control_points): indices into xy of the control points, in chain
    order."""
    return native._polylines.control_points(
        np.ascontiguousarray(xy, dtype=np.float64), np.ascontiguousarray(first, dtype=np.int64),
        np.ascontiguousarray(last, dtype=np.int64), k, d,
    )


def trace(
    edges: np.ndarray,
    magnitude: np.ndarray,
    *,
    segment_length: int = 4,
    segment_error: float = 1.0,
    min_pixels: int = 3,
    max_pixels: int | None = None,
) -> Polylines:
    """Polylines approximating the edges of a boolean edge map (see the module doc).

    max_pixels: trace only the chains of the largest mean squared gradient, as many as
    fit in this many pixels (all chains stay in scan-line order): the others would not
    be worth their walls."""
    if isinstance(segment_length, bool) or not isinstance(segment_length, (int, np.integer)) or segment_length < 1:
        raise OptionError(f"segment_length must be a whole number >= 1, not {segment_length!r}")
    if not isinstance(segment_error, (int, float, np.number)) or not segment_error >= 0:
        raise OptionError(f"segment_error must be a number >= 0, not {segment_error!r}")
    grid = _Grid(edges.astype(bool))
    junction, simple = thin_split(grid)
    flat_order, chain, closed = _order_chains(simple, grid.offsets)
    # the chains with their ends (a junction pixel next to an open chain's end, a closed
    # chain's first pixel again after its last), and each chain's summed squared gradient (as
    # np.bincount summed it), in one compiled pass
    pix, bounds, sums = native._polylines.chain_walks(
        flat_order, chain, closed.view(np.uint8), junction.view(np.uint8), grid.offsets,
        np.ascontiguousarray(magnitude, dtype=np.float32), grid.stride)
    sizes = np.diff(bounds)
    wanted = sizes >= max(2, min_pixels)
    if max_pixels is not None and sizes[wanted].sum() > max_pixels:
        order = np.argsort(-np.where(wanted, sums / sizes, -1.0), kind="stable")
        fits = np.cumsum(np.where(wanted, sizes, 0)[order]) <= max_pixels
        wanted = np.zeros_like(wanted)
        wanted[order[fits]] = True
    pix = pix[np.repeat(wanted, sizes)]
    sizes, strength = sizes[wanted], sums[wanted]
    nchains = len(sizes)
    ch = np.repeat(np.arange(nchains, dtype=np.int64), sizes)
    xy = np.stack([pix % grid.stride - 1, pix // grid.stride - 1], axis=1)
    last = np.cumsum(sizes) - 1
    ctrl = _control_points(xy.astype(np.float64), last - sizes + 1, last, int(segment_length), float(segment_error))
    starts = np.concatenate([[0], np.cumsum(np.bincount(ch[ctrl], minlength=nchains))])
    return Polylines(xy[ctrl], starts, xy, ch, strength)
