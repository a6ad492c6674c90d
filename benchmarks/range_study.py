"""Prototype study for issue #21: which near-lossless design gives the fewest bytes at a
guaranteed max error on range data. Measurements only; nothing here is a codec.

    python benchmarks/range_study.py                        # all images, E = 0.1/0.5/2 % and lossless
    python benchmarks/range_study.py --images tum_depth --errors 0.5 --quick

Every variant keeps the max error within E by construction (E = 0: lossless), holes
exact. Variants:

a. the quantiser alone, real bytes: the uniform quantiser's levels (step 2 floor(E) + 1,
   2E for float data; holes a level of their own) through zstd -19 ("q+zstd") and JPEG
   XL lossless ("q+jxl"); and "cover+jxl": the cover quantiser's levels (the fewest
   levels within E of every value used, see cover_quantiser: uniform on dense data, no
   empty levels on sparse data) through JPEG XL, its table of levels added.
b. "mesh": the mesh as predictor. An .atm file at a coarse vertex count (real bytes) is
   decoded; its pixels, as continuous levels, predict each level, MED on the causal
   neighbours' misses predicts what the mesh missed, and the residual levels are coded
   with the context model below (ESTIMATE), contexts: neighbour residuals x distance to
   a wall or hole edge x the mesh surface's slope. The mesh either carries the holes
   (.atm with nodata) or is made of the image with its holes filled (push-pull) and
   the hole mask is coded apart (ESTIMATE, JBIG-like contexts). The vertex count is
   swept per image and bound and the best total kept, mesh bytes included.
   "mesh value": the brief's form of it, in the value domain: data - mesh quantised
   around zero with the step (as near-lossless JPEG-LS and SZ do), the quantised
   residual coded as is or after MED, contexts: neighbour residuals x mesh.
   The last column: MED's residual (variant c) in its contexts x the mesh's, the mesh
   not charged, against without: what the mesh's contexts are worth at most.
   "MED+walls" / "WP+walls": variant c's predictors made wall-aware. The mesh's walls
   (its constraint polylines; hole edges too) cut the image into regions, and a
   predictor reads only neighbours in the pixel's own region (W where none is). Only
   the walls are paid for: their polylines coded alone (ESTIMATE),
   the mesh's other vertices and values are not stored.
c. "interp": a hierarchical interpolation predictor in the value domain (SZ3's idea,
   linear, see interpolation_bytes), the hole mask added.
   A plain causal predictor on the cover levels: "MED" (LOCO-I, as JPEG-LS) and "WP"
   (a blend of four predictors weighted by their recent errors, after JPEG XL's
   weighted predictor); contexts: neighbour residuals x local gradient; plus the hole
   mask and the table of levels.
d. lossless: the same at E = 0.

The context model (the ESTIMATES): each residual becomes a token (|r| below 16 as is,
above it the bit length and the bit below the top), a sign and raw low bits. Tokens and
signs are coded by adaptive frequency counts per context (pseudo-count KT, counts
from the residuals coded before): the figure is that model's exact adaptive code length,
what an arithmetic or rANS coder with those counts reaches to within a few bytes per
stream. Raw bits cost one bit each. The last column checks this on every row: MED's
residual through a real range coder (benchmarks/range_coder.py), decoded back. Ratios are to the best of SZ3, LERC, JPEG-LS and
quantise(2E)+JPEG XL at the same E (issue #21's criterion, measured by
benchmarks/range.py), and for lossless to the best of PNG, JPEG-LS and JPEG XL.
"""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import range as bench  # noqa: E402  (benchmarks/range.py: images, quantiser, peers)

import codec  # noqa: E402

MESH_DENSITIES = (0.001, 0.0025, 0.005, 0.01, 0.02, 0.04)  # vertices per pixel asked for
# the pseudo-count every symbol starts with: 0.5 is Krichevsky-Trofimov's; 0.2 measured
# 0.3-2 % fewer bytes on these images (most contexts use few of the tokens)
KT = 0.2
DIRECT = 16  # residual magnitudes below this are tokens of their own


# ---------------------------------------------------------------- the entropy estimate


def adaptive_bits(ctx: np.ndarray, sym: np.ndarray, alphabet: int) -> float:
    """Code length in bits of `sym` (coding order) under adaptive counts per context:
    symbol s in context c costs -log2((n_cs + KT) / (n_c + KT * alphabet)), the counts
    taken over the symbols coded before it."""
    if len(sym) == 0:
        return 0.0
    ctx = ctx.astype(np.int64)
    key = ctx * alphabet + sym.astype(np.int64)
    n_c = _rank_in_group(ctx)
    n_cs = _rank_in_group(key)
    return float(-np.log2((n_cs + KT) / (n_c + KT * alphabet)).sum())


def _rank_in_group(groups: np.ndarray) -> np.ndarray:
    """For each element, how many earlier elements share its group."""
    order = np.argsort(groups, kind="stable")
    g = groups[order]
    starts = np.r_[0, np.flatnonzero(g[1:] != g[:-1]) + 1]
    rank_sorted = np.arange(len(g)) - np.repeat(starts, np.diff(np.r_[starts, len(g)]))
    rank = np.empty_like(rank_sorted)
    rank[order] = rank_sorted
    return rank


def tokens(r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Token of each residual magnitude and how many raw bits follow it."""
    a = np.abs(r).astype(np.int64)
    n = np.zeros_like(a)
    big = a >= DIRECT
    n[big] = np.floor(np.log2(a[big])).astype(np.int64) + 1  # bit length
    tok = np.where(big, DIRECT + 2 * (n - 5) + ((a >> np.maximum(n - 2, 0)) & 1), a)
    raw = np.where(big, n - 2, 0)
    return tok, raw


def residual_bits(r: np.ndarray, ctx: np.ndarray, sign_ctx: np.ndarray) -> float:
    """Estimated bits of residuals r (coding order) in contexts ctx."""
    tok, raw = tokens(r)
    alphabet = int(tok.max()) + 1  # a header field would carry it
    nz = r != 0
    return (adaptive_bits(ctx, tok, alphabet)
            + adaptive_bits(sign_ctx[nz], (r[nz] > 0).astype(np.int64), 2)
            + float(raw.sum()))


def range_coded_residual(r: np.ndarray, ctx: np.ndarray, sign_ctx: np.ndarray) -> int:
    """Real bytes of what residual_bits estimates: tokens, signs and raw bits through
    the pure-Python range coder (benchmarks/range_coder.py), with the same adaptive
    counts, decoded back and checked. Slow: for crops. The decoder is handed each
    symbol's context; deriving them from decoded values is the codec's job, not this
    check's."""
    import range_coder

    tok, raw = tokens(r)
    alphabet = int(tok.max()) + 1
    scale = round(1 / KT)
    items: list[tuple[int, int]] = []
    # context ids: tokens 0.., signs below -1, raw bits -1 (a fixed even split)
    for t, n, c, sc, v in zip(tok.tolist(), raw.tolist(), ctx.tolist(), sign_ctx.tolist(), r.tolist()):
        items.append((c, t))
        if v:
            items.append((-2 - sc, int(v > 0)))
        a = abs(v)
        items.extend((-1, (a >> i) & 1) for i in range(n - 1, -1, -1))

    def fresh() -> dict[int, range_coder.Model]:
        out: dict[int, range_coder.Model] = {-1: range_coder.Model(2, 0)}
        for c, _ in items:
            if c not in out:
                out[c] = range_coder.Model(alphabet if c >= 0 else 2, scale)
        return out

    data = range_coder.encode(items, fresh())
    back = list(range_coder.decode(data, [c for c, _ in items], fresh()))
    if back != [v for _, v in items]:
        raise AssertionError("the range coder did not give its symbols back")
    return len(data)


JBIG_TEMPLATE = ((0, -1), (0, -2), (-1, -2), (-1, -1), (-1, 0), (-1, 1), (-1, 2), (-2, -1), (-2, 0), (-2, 1))


def mask_bits(holes: np.ndarray) -> float:
    """Estimated bits of the hole mask, each pixel in the context of its ten causal
    neighbours of JBIG's three-line template."""
    if not holes.any():
        return 0.0
    ctx = sum((1 << i) * shifted(holes.astype(np.int64), dy, dx) for i, (dy, dx) in enumerate(JBIG_TEMPLATE))
    return adaptive_bits(ctx.ravel(), holes.ravel().astype(np.int64), 2)


def polyline_bits(lines: list[np.ndarray], width: int, height: int) -> float:
    """Estimated bits of wall polylines alone (no mesh): a count and start per line,
    then each vertex's step (dx, dy) as residuals of the context model."""
    if not lines:
        return 16.0
    start = math.ceil(math.log2(width)) + math.ceil(math.log2(height)) + 16
    steps = np.concatenate([np.diff(line, axis=0).ravel() for line in lines])
    zero = np.zeros(len(steps), np.int64)
    return 16 + start * len(lines) + residual_bits(steps, zero, zero)


# ---------------------------------------------------------------- predictors and contexts


def shifted(a: np.ndarray, dy: int, dx: int) -> np.ndarray:
    """a moved so that entry (y, x) holds a[y + dy, x + dx], zero outside."""
    h, w = a.shape
    p = np.pad(a, 2)
    return p[2 + dy : 2 + dy + h, 2 + dx : 2 + dx + w]


def med(a: np.ndarray) -> np.ndarray:
    """LOCO-I's median edge detector from the causal W, N and NW neighbours."""
    w_, n_, nw = shifted(a, 0, -1), shifted(a, -1, 0), shifted(a, -1, -1)
    lo, hi = np.minimum(w_, n_), np.maximum(w_, n_)
    return np.where(nw >= hi, lo, np.where(nw <= lo, hi, w_ + n_ - nw))


def fill_holes_causally(levels: np.ndarray, holes: np.ndarray) -> np.ndarray:
    """Hole levels replaced by the last valid level to their left in the row (the row
    above where the row starts with holes): causal, so a decoder can do the same."""
    out = levels.astype(np.int64).copy()
    h, w = out.shape
    idx = np.where(~holes, np.arange(w)[None, :], -1)
    np.maximum.accumulate(idx, axis=1, out=idx)
    for y in range(h):
        row, last = out[y], idx[y]
        known = last >= 0
        row[known] = row[last[known]]
        row[~known] = out[y - 1][~known] if y else 0
    return out


def weighted_prediction(a: np.ndarray) -> np.ndarray:
    """A blend of four causal predictors (W, N, W + N - NW, N + NE - NNE), each weighted
    by the inverse square of its own error summed over the W, N, NW and NE neighbours
    (after JPEG XL's weighted predictor, much simplified). Lossless in the level domain,
    so every error it weighs is known to a decoder."""
    a = a.astype(np.float64)
    w_, n_, nw, ne, nne = (shifted(a, 0, -1), shifted(a, -1, 0), shifted(a, -1, -1),
                           shifted(a, -1, 1), shifted(a, -2, 1))
    preds = [w_, n_, w_ + n_ - nw, n_ + ne - nne]
    num = np.zeros_like(a)
    den = np.zeros_like(a)
    for p in preds:
        err = np.abs(a - p)
        near = shifted(err, 0, -1) + shifted(err, -1, 0) + shifted(err, -1, -1) + shifted(err, -1, 1)
        weight = 1.0 / (0.5 + near) ** 2
        num += weight * p
        den += weight
    return np.rint(num / den).astype(np.int64)


def _same_region(regions: np.ndarray):
    lab = regions + 2  # padding (0) is no region

    def same(dy: int, dx: int) -> np.ndarray:
        return shifted(lab, dy, dx) == lab

    return same


def wall_aware_med(a: np.ndarray, regions: np.ndarray, fallback: np.ndarray) -> np.ndarray:
    """MED where W, N and NW lie in the pixel's own region (walls and holes separate
    regions); else the mean of W and N, or the one of W, N, NW, NE that does; where
    none does, the fallback."""
    same = _same_region(regions)
    w_, n_, nw, ne = shifted(a, 0, -1), shifted(a, -1, 0), shifted(a, -1, -1), shifted(a, -1, 1)
    sw, sn, snw, sne = same(0, -1), same(-1, 0), same(-1, -1), same(-1, 1)
    out = np.rint(fallback).astype(np.int64)
    for ok, value in ((sne, ne), (snw, nw), (sn, n_), (sw, w_), (sw & sn, (w_ + n_) // 2),
                      (sw & sn & snw, med(a))):
        out = np.where(ok, value, out)  # later lines take precedence
    return out


def wall_aware_wp(a: np.ndarray, regions: np.ndarray, fallback: np.ndarray) -> np.ndarray:
    """weighted_prediction with each of its predictors used only where all the
    neighbours it reads lie in the pixel's own region; where none does, the fallback."""
    same = _same_region(regions)
    a = a.astype(np.float64)
    w_, n_, nw, ne, nne = (shifted(a, 0, -1), shifted(a, -1, 0), shifted(a, -1, -1),
                           shifted(a, -1, 1), shifted(a, -2, 1))
    usable = [same(0, -1), same(-1, 0), same(0, -1) & same(-1, 0) & same(-1, -1),
              same(-1, 0) & same(-1, 1) & same(-2, 1)]
    num = np.zeros_like(a)
    den = np.zeros_like(a)
    for p, ok in zip([w_, n_, w_ + n_ - nw, n_ + ne - nne], usable):
        err = np.abs(a - p)
        near = shifted(err, 0, -1) + shifted(err, -1, 0) + shifted(err, -1, -1) + shifted(err, -1, 1)
        weight = np.where(ok, 1.0 / (0.5 + near) ** 2, 0.0)
        num += weight * p
        den += weight
    return np.where(den > 0, np.rint(num / np.maximum(den, 1e-300)), np.rint(fallback)).astype(np.int64)


def push_pull_fill(image: np.ndarray, holes: np.ndarray) -> np.ndarray:
    """Holes filled smoothly from the valid pixels around them (weighted averages down a
    pyramid, then back up): an encoder-side fill, so that a mesh of the filled image
    spends nothing on hole outlines."""
    import cv2

    out = image.astype(np.float64)
    if not holes.any():
        return out
    weight = (~holes).astype(np.float64)
    mass = np.where(holes, 0.0, out)
    pyramid = []
    while (weight <= 0).any() and min(weight.shape) > 1:
        pyramid.append((mass, weight))
        mass, weight = cv2.pyrDown(mass), cv2.pyrDown(weight)
    fallback = mass.sum() / max(weight.sum(), 1e-12)
    filled = np.where(weight > 0, mass / np.maximum(weight, 1e-12), fallback)
    for mass, weight in reversed(pyramid):
        up = cv2.pyrUp(filled, dstsize=(mass.shape[1], mass.shape[0]))
        filled = np.where(weight > 0, mass / np.maximum(weight, 1e-12), up)
    out[holes] = filled[holes]
    return out


def cover_quantiser(values: np.ndarray, e: float, integer: bool) -> tuple[np.ndarray, np.ndarray]:
    """Fewest representatives within E of every used value: greedy intervals of width
    2E over the sorted distinct values (2 floor(E) for integers), each represented by
    its middle. Returns the interval starts and each value's interval index. Dense data
    gets the uniform quantiser back; sparse data (a sensor's few hundred depth steps)
    gets no empty levels, and is exact where its gaps are wider than 2E."""
    width = 2 * math.floor(e) if integer else 2 * e
    distinct = np.unique(values)
    starts = []
    i = 0
    while i < len(distinct):
        starts.append(distinct[i])
        i = int(np.searchsorted(distinct, distinct[i] + width, side="right"))
    starts_a = np.asarray(starts, dtype=np.float64)
    return starts_a, np.searchsorted(starts_a, values, side="right") - 1


def table_bytes(starts: np.ndarray, e: float, integer: bool) -> int:
    """zstd bytes of the representatives table: each start's gap beyond the least
    possible (2E + 1 for integers), as varints."""
    import zstandard

    least = 2 * math.floor(e) + 1 if integer else 0
    gaps = np.diff(starts) - least if integer else np.diff(starts)
    if not integer:
        return len(zstandard.ZstdCompressor(level=19).compress(starts.astype(np.float64).tobytes()))
    raw = bytearray()
    for g in gaps.astype(np.int64).tolist():
        while g >= 128:
            raw.append(0x80 | (g & 127))
            g >>= 7
        raw.append(g)
    return 8 + len(zstandard.ZstdCompressor(level=19).compress(bytes(raw)))


def bucket(x: np.ndarray, edges: tuple[float, ...]) -> np.ndarray:
    return np.searchsorted(np.asarray(edges), x, side="right")


ACTIVITY_EDGES = (0.5, 1.5, 2.5, 4.5, 8.5, 16.5, 32.5, 64.5)  # 9 buckets
WALL_EDGES = (1.5, 4.5)  # pixels: 3 buckets
SLOPE_EDGES = (0.05, 0.25, 1.0)  # levels per pixel: 4 buckets


def neighbour_contexts(r: np.ndarray, levels: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Buckets of the causal neighbours' residual magnitudes and of the local gradient
    of the (causal) levels, and the sign context from the W and N residuals' signs."""
    ar = np.abs(r)
    act = shifted(ar, 0, -1) + shifted(ar, -1, 0) + (shifted(ar, -1, -1) + shifted(ar, -1, 1)) / 2
    grad = (np.abs(shifted(levels, -1, 1) - shifted(levels, -1, 0))
            + np.abs(shifted(levels, -1, 0) - shifted(levels, -1, -1))
            + np.abs(shifted(levels, -1, -1) - shifted(levels, 0, -1)))
    sign = 3 * (np.sign(shifted(r, 0, -1)) + 1) + np.sign(shifted(r, -1, 0)) + 1
    return bucket(act, ACTIVITY_EDGES), bucket(grad, ACTIVITY_EDGES), sign


@dataclass
class Levels:
    """The cover quantiser's levels of one image at one bound: what every estimated
    variant codes. filled: hole levels replaced causally, for predictors."""

    case: bench.Case
    e: float
    starts: np.ndarray
    levels: np.ndarray
    filled: np.ndarray
    table: int  # bytes of the representatives table

    @classmethod
    def of(cls, case: bench.Case, e: float) -> "Levels":
        valid = case.valid
        starts, index = cover_quantiser(case.image[valid].astype(np.float64), e, case.integer)
        levels = np.zeros(case.image.shape, np.int64)
        levels[valid] = index
        return cls(case, e, starts, levels, fill_holes_causally(levels, case.holes),
                   table_bytes(starts, e, case.integer))

    def level_of(self, values: np.ndarray) -> np.ndarray:
        """Continuous level coordinate of values (for predictions and slopes)."""
        middles = self.starts + (math.floor(self.e) if self.case.integer else self.e)
        if len(middles) == 1:
            return np.zeros(values.shape)
        return np.interp(values, middles, np.arange(len(middles), dtype=np.float64))


@dataclass
class MeshSide:
    """What a decoder knows from a mesh before the residual: its prediction in levels,
    the distance of each pixel to a wall or hole edge, the surface's slope."""

    size: int
    vertices: int
    prediction: np.ndarray
    values: np.ndarray  # the decoded mesh in data units
    wall_distance: np.ndarray
    slope: np.ndarray
    regions: np.ndarray  # connected parts between walls (wall pixels join the nearest); holes -1
    wall_bits: float  # estimate of the walls' polylines coded alone

    @property
    def contexts(self) -> np.ndarray:
        """Distance to the nearest wall or hole edge (3 buckets) x the surface's slope
        (4 buckets)."""
        return bucket(self.wall_distance, WALL_EDGES) * 4 + bucket(self.slope, SLOPE_EDGES)


def mesh_side(lv: Levels, density: float, filled: bool) -> MeshSide | None:
    """The .atm mesh at `density` vertices per pixel (asked for), of the image with its
    holes (the mesh then carries them) or of the image push-pull filled (holes coded
    apart). None when the mesh with holes does not give them back exactly."""
    import cv2
    from scipy import ndimage

    case = lv.case
    h, w = case.image.shape
    holes = case.holes
    if filled:
        image = np.clip(np.rint(push_pull_fill(case.image, holes)), 0, np.iinfo(case.image.dtype).max)
        data = codec.encode(image.astype(case.image.dtype), points=max(4, round(density * w * h)))
    else:
        data = codec.encode(case.image, points=max(4, round(density * w * h)), nodata=case.nodata)
    decoded = codec.decode(data).astype(np.float64)
    if not filled and case.nodata is not None and not np.array_equal(decoded == case.nodata, holes):
        return None
    m = codec.decode_mesh(data)
    walls = np.zeros((h, w), np.uint8)
    for line in m.constraints:
        cv2.polylines(walls, [m.vertices[line].astype(np.int32).reshape(-1, 1, 2)], False, 1)
    free = (walls == 0) & ~holes
    _, regions = cv2.connectedComponents(free.astype(np.uint8), connectivity=4)
    nearest = ndimage.distance_transform_edt(~free, return_distances=False, return_indices=True)
    regions = regions[nearest[0], nearest[1]]
    regions[holes] = -1
    walls[holes] = 1
    distance = cv2.distanceTransform((walls == 0).astype(np.uint8), cv2.DIST_L2, 3)
    pred = lv.level_of(decoded)
    pred[holes] = 0
    gy, gx = np.gradient(pred)
    lines = [m.vertices[line] for line in m.constraints]
    return MeshSide(len(data), len(m.vertices), pred, decoded, distance, np.abs(gx) + np.abs(gy), regions,
                    polyline_bits(lines, w, h))


# ---------------------------------------------------------------- the variants


def quantiser_alone(case: bench.Case, lv: Levels) -> dict[str, float]:
    """Real bytes: the uniform quantiser's levels through zstd and JPEG XL lossless, and
    the cover quantiser's through JPEG XL (its table added)."""
    import imagecodecs
    import zstandard

    def jxl(q: np.ndarray) -> int:
        return len(imagecodecs.jpegxl_encode(q, lossless=True, bitspersample=max(1, int(q.max()).bit_length())))

    cover = lv.levels + case.holes.any()
    cover[case.holes] = 0
    out = {"cover+jxl": float(lv.table + jxl(cover.astype(np.uint8 if cover.max() < 256 else np.uint16)))}
    if lv.e > 0 or case.integer:  # a uniform step of 2E is no quantiser at E = 0 on float data
        q = bench.quantise(case, lv.e)
        out["q+zstd"] = bench.SIDE_INFO + len(zstandard.ZstdCompressor(level=19).compress(q.tobytes()))
        out["q+jxl"] = bench.SIDE_INFO + jxl(q)
    return out


def coded_bytes(r: np.ndarray, lv: Levels, extra: np.ndarray | None = None, gradient: bool = True,
                real: bool = False) -> float:
    """Estimated bytes of residuals r over the valid pixels in raster order, in the
    contexts neighbour activity x level gradient (unless gradient=False) x extra (from
    the mesh, if given); real=True: range-coded bytes instead (slow)."""
    act, grad, sign = neighbour_contexts(r, lv.filled)
    ctx = act * 10 + grad if gradient else act
    if extra is not None:
        ctx = ctx * (int(extra.max()) + 1) + extra
    valid = lv.case.valid
    if real:
        return range_coded_residual(r[valid], ctx[valid], sign[valid])
    return residual_bits(r[valid], ctx[valid], sign[valid]) / 8


def value_residual(lv: Levels, side: MeshSide) -> np.ndarray:
    """The brief's route in the value domain: the residual data - mesh quantised with
    step 2 floor(E) + 1 (2E for float data) around zero, so the reconstruction mesh +
    q x step is within E by construction and, on smooth data, stays smooth (no terraces:
    nothing straddles a level boundary of the data's own quantiser)."""
    case = lv.case
    step = bench.quantiser_step(case, lv.e) if lv.e > 0 else 1.0
    d = np.where(case.valid, case.image.astype(np.float64) - side.values, 0.0)
    return quantise_around(d, lv.e, step, case.integer)


def quantise_around(d: np.ndarray, e: float, step: float, integer: bool) -> np.ndarray:
    """Residuals d quantised around zero with `step`: d - q x step is within E."""
    if integer:
        return (np.sign(d) * ((np.abs(d) + math.floor(e)) // step)).astype(np.int64)
    return np.rint(d / step).astype(np.int64)


def interpolation_bytes(case: bench.Case, e: float) -> float:
    """Estimated bytes of a hierarchical interpolation predictor in the value domain
    (after SZ3's): a coarse grid of anchors (DPCM), then at each halving of the stride
    the row midpoints and the column midpoints predicted as the mean of their two
    reconstructed neighbours (integer-rounded for integer data), the residual quantised
    around zero, so the bound holds by construction. Contexts: the level of the pyramid.
    Holes get no residual (the mask is coded apart)."""
    x = case.image.astype(np.float64)
    h, w = x.shape
    step = bench.quantiser_step(case, e) if e > 0 else 1.0
    valid = case.valid
    rec = np.zeros_like(x)
    symbols: list[np.ndarray] = []
    contexts: list[np.ndarray] = []

    def code(pred: np.ndarray, ys: np.ndarray, xs: np.ndarray, level: int) -> None:
        if case.integer:
            pred = np.floor(pred)
        q = np.where(valid[ys, xs], quantise_around(x[ys, xs] - pred, e, step, case.integer), 0)
        rec[ys, xs] = pred + q * step
        symbols.append(q[valid[ys, xs]])
        contexts.append(np.full(len(symbols[-1]), min(level, 30)))

    stride = 1
    while stride * 2 < max(h, w):
        stride *= 2
    previous = 0.0
    for y in range(0, h, stride):
        for x0 in range(0, w, stride):
            code(np.array([previous]), np.array([y]), np.array([x0]), 0)
            previous = rec[y, x0]
    level = 1
    while stride > 1:
        half = stride // 2
        ys, xs = np.arange(0, h, stride), np.arange(half, w, stride)
        if len(xs):
            right = np.where(xs + half < w, xs + half, xs - half)
            code((rec[np.ix_(ys, xs - half)] + rec[np.ix_(ys, right)]) / 2, ys[:, None], xs[None, :], level)
        ys, xs = np.arange(half, h, stride), np.arange(0, w, half)
        if len(ys):
            down = np.where(ys + half < h, ys + half, ys - half)
            code((rec[np.ix_(ys - half, xs)] + rec[np.ix_(down, xs)]) / 2, ys[:, None], xs[None, :], level + 1)
        stride, level = half, level + 2
    if np.abs(rec - x)[valid].max() > (math.floor(e) if case.integer else e) + 1e-9:
        raise AssertionError("the interpolation predictor broke its bound")
    q = np.concatenate(symbols)
    ctx = np.concatenate(contexts)
    return residual_bits(q, ctx, np.zeros_like(ctx)) / 8


def mesh_plus_causal(lv: Levels, side: MeshSide) -> np.ndarray:
    """Residual levels when the mesh predicts each pixel and MED predicts what the mesh
    missed from the causal neighbours' misses (kept at 1/8 level: the mesh's prediction
    is continuous, and rounding it first would add a jitter no predictor can follow)."""
    valid = lv.case.valid
    miss = np.where(valid, lv.filled - side.prediction, 0.0)
    miss_eighths = fill_holes_causally(np.rint(8 * miss).astype(np.int64), lv.case.holes)
    return np.where(valid, lv.levels - np.rint(side.prediction + med(miss_eighths) / 8).astype(np.int64), 0)


def study(case: bench.Case, e: float, densities: tuple[float, ...]) -> dict[str, tuple[float, str]]:
    """Bytes of every variant at bound E (the docstring says which are estimates), with
    how the mesh variants split their bytes."""
    lv = Levels.of(case, e)
    valid = case.valid
    out: dict[str, tuple[float, str]] = {k: (v, "") for k, v in quantiser_alone(case, lv).items()}
    mask = mask_bits(case.holes) / 8
    r_med = np.where(valid, lv.filled - med(lv.filled), 0)
    r_wp = np.where(valid, lv.filled - weighted_prediction(lv.filled), 0)
    wp = coded_bytes(r_wp, lv)
    med_bytes = coded_bytes(r_med, lv)
    out["MED"] = (med_bytes + mask + lv.table, f"{coded_bytes(r_med, lv, real=True) / med_bytes:.4f}")
    if e > 0 or case.integer:  # on float data at E = 0 only the value table is exact
        out["interp"] = (interpolation_bytes(case, e) + mask, "")
    out["WP"] = (wp + mask + lv.table, f"residual {wp:,.0f} + mask {mask:,.0f} + table {lv.table:,} B")
    for density in densities:
        for filled in (False, True) if case.holes.any() else (False,):
            side = mesh_side(lv, density, filled)
            if side is None:
                continue
            extra = lv.table + (mask if filled else 0)
            walls = side.wall_bits / 8
            what = "holes in mesh" if not filled else "filled, mask apart"
            q = value_residual(lv, side)
            q_med = np.where(valid, q - med(q), 0)
            tries = {
                "mesh": (side.size, coded_bytes(mesh_plus_causal(lv, side), lv, side.contexts, gradient=False),
                         f"mesh {side.size:,}"),
                "mesh value": (side.size, min(coded_bytes(q, lv, side.contexts, gradient=False),
                                              coded_bytes(q_med, lv, side.contexts, gradient=False)),
                               f"mesh {side.size:,}"),
            }
            for name, predict in (("MED+walls", wall_aware_med), ("WP+walls", wall_aware_wp)):
                # the walls alone are paid for: the fallback is W, not the mesh's values
                r = np.where(valid, lv.levels - predict(lv.filled, side.regions, shifted(lv.filled, 0, -1)), 0)
                tries[name] = (walls, coded_bytes(r, lv), f"walls {walls:,.0f}")
            for name, (side_bytes, residual, note) in tries.items():
                total = side_bytes + residual + extra
                if name not in out or total < out[name][0]:
                    out[name] = (total, f"{side.vertices:,} v ({what}): {note} + residual {residual:,.0f} B")
            # what the mesh's contexts are worth with the mesh free: MED's residual in
            # neighbour x gradient x (wall distance, slope) contexts, against without
            with_mesh = coded_bytes(r_med, lv, side.contexts)
            if with_mesh < out.get("meshctx", (math.inf,))[0]:
                out["meshctx"] = (with_mesh, f"{with_mesh / med_bytes:.3f}")
    return out


VARIANTS = ("q+zstd", "q+jxl", "cover+jxl", "MED", "WP", "interp", "mesh", "mesh value", "MED+walls", "WP+walls")


def best_peers(case: bench.Case, e: float) -> tuple[str, int]:
    """The smallest peer that meets the bound, and its bytes."""
    if e == 0:
        peers = {k: v for k, v in bench.LOSSLESS.items() if k != "atm"}
        results, _, _ = bench.measure(case, peers, 0.0, 0)
        among = tuple(peers)
    else:
        peers = {k: v for k, v in bench.bounded_codecs(e).items() if k in bench.CRITERION}
        results, _, _ = bench.measure(case, peers, e, 0)
        among = bench.CRITERION
    best = bench.best_peer(results, e, among)
    if best is None:
        raise SystemExit(f"no peer met max error {e:g} on {case.name}: nothing to compare with")
    return best, results[best].size


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--images", nargs="*", help="images to study (default: all)")
    parser.add_argument("--errors", nargs="*", type=float, default=[*bench.ERRORS, 0.0],
                        help="max errors in percent of the valid value range (0: lossless)")
    parser.add_argument("--densities", nargs="*", type=float, default=list(MESH_DENSITIES),
                        help="mesh vertex counts to sweep, per pixel")
    parser.add_argument("--quick", action="store_true", help=f"centre {bench.QUICK}x{bench.QUICK} crops")
    args = parser.parse_args(argv)
    loaders = bench.load_cases()
    names = args.images or list(loaders)
    unknown = sorted(set(names) - set(loaders))
    if unknown:
        parser.error(f"no range image {', '.join(unknown)}; choose from {', '.join(loaders)}")
    head = (["image", "E", "best peer (bytes)"] + [f"{v} ÷ peer" for v in VARIANTS]
            + ["WP split", "mesh split", "mesh value split", "MED+walls split", "MED residual range-coded ÷ estimate",
               "MED residual with mesh contexts (mesh free) ÷ without"])
    print(bench.markdown(head, []), flush=True)
    for name in names:
        case = loaders[name]()
        if args.quick:
            case = bench.crop(case, bench.QUICK)
        lo, hi = case.span
        h, w = case.image.shape
        for pct in args.errors:
            e = pct / 100 * (hi - lo)
            peer, size = best_peers(case, e)
            got = study(case, e, tuple(args.densities))
            row = [f"{name} {w}x{h}", "lossless" if e == 0 else f"{pct:g} % = {e:.4g}", f"{peer} {size:,}"]
            row += [f"{got[v][0] / size:.2f}" if v in got else "-" for v in VARIANTS]
            print(bench.markdown_row(row + [got[v][1] if v in got else "-" for v in ("WP", "mesh", "mesh value", "MED+walls", "MED", "meshctx")]),
                  flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
