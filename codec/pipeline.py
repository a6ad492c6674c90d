"""The encoder's band pipeline: a band of rows in, its coded mesh out.

    plan = pipeline.plan(settings, width, height, dtype, channels)     # once an image
    coded = pipeline.code_band(rows, holes, plan, y0=..., top=..., last=..., step=...)

`code_band` is a pure function: what one band passes to the next (the shared row's
vertices, the base value step) goes in and comes out as values, so `codec.encode` and
`codec.StreamEncoder` (a row buffer around it) run the same code. Its stages: fill
holes, mesh (codec.mesher), and before the mesher's last triangulation (its Finish)
cut the holes out (codec.holes), pin the first row to the band above and sample the
last row for the band below (codec.banding), so that a band is triangulated once a
round; then quantise the values as stored (codec.meshcode.quantise) and refine to an
error bound (codec.error_bound).
"""

from __future__ import annotations

import inspect
import math
import numbers
from dataclasses import dataclass
from typing import Callable

import numpy as np

from . import banding, error_bound, holes as hole_stage, integers, meshcode, quantise
from . import slack as slack_rule
from .errors import ATMError, OptionError, UnsupportedError
from .image import SAMPLE_TYPES
from .mesh import Mesh
from .mesher import Finish, Meshed, builder
from .mesher import values as vertex_values
from .settings import Settings

#: Vertex density used when no size is asked for (the 2.8 % at which the paper,
#: "Approximation of Digital Images with Discontinuity-Preserving Adaptive Triangular
#: Meshes", meshes its Lenna test image).
DEFAULT_DENSITY = 0.028
#: Vertex density of the starting mesh when refinement to a bound decides the size.
START_DENSITY = 0.002
#: The automatic base value step, as a multiple of the first band's RMS error. Vertex
#: steps vary around it with fan area (meshcode.vertex_steps); at 1.0 the rounding
#: costs about a tenth of the squared error and buys more vertices than it costs
#: (benchmarks/rate.py: lower RMS at equal bytes than 0.7 or 1.4 on the corpus).
STEP_FACTOR = 1.0
#: A holed band is meshed again, at most REMESHES times, while the mesher's vertices
#: off the holes miss its share by more than REMESH_OFF (points=N is to give N
#: vertices within 10 %), asking for at most MAX_REMESH times the share.
REMESH_OFF = 0.05
REMESHES = 2
MAX_REMESH = 16
#: How the vertices off the holes grow with the mesher's budget before a second
#: measurement tells: as budget ** KEPT_GROWTH (tum and kinect depth: 1.1-1.3, as
#: the filled holes, which are smooth, need vertices last).
KEPT_GROWTH = 1.2


def _mesh_around_holes(build: Callable[[int], Meshed], kept: Callable[[Meshed], int], share: int) -> Meshed:
    """A mesh of a filled band (build(budget): the mesher's) of which about `share`
    vertices lie off the holes and their rims (kept(mesh): how many): the mesher
    meshes the filled holes too (tum depth at 500 points: three vertices in four), so
    it is asked for more, by a secant on log(budget) -> log(kept) from the budgets
    tried."""
    asked = share
    meshed = build(asked)
    got = kept(meshed)
    best = got
    tried = [(asked, got)]
    for _ in range(REMESHES):
        if abs(got - share) <= REMESH_OFF * share or got <= 0 and asked >= MAX_REMESH * share:
            break
        if len(tried) == 1:
            growth = KEPT_GROWTH
        else:
            (a0, k0), (a1, k1) = tried[-2:]
            growth = math.log(max(k1, 1) / max(k0, 1)) / math.log(a1 / a0) if a1 != a0 else KEPT_GROWTH
            growth = min(max(growth, 0.5), 2.0)
        nxt = int(min(max(round(asked * (share / max(got, 1)) ** (1 / growth)), 4), MAX_REMESH * share))
        if nxt == asked:
            break
        candidate = build(nxt)
        got = kept(candidate)
        tried.append((nxt, got))
        if abs(got - share) < abs(best - share):
            meshed, best = candidate, got
        asked = nxt
    return meshed


def _finisher(plan: Plan, band: np.ndarray, holes: np.ndarray | None, rims: list[np.ndarray] | None,
              top: tuple[np.ndarray, np.ndarray] | None, last: bool) -> Finish:
    """The mesher's Finish for a band: cut its holes out, pin its first row to `top`
    and sample its last row unless it is the image's `last`."""
    def finish(mesh: Mesh, mse: float | None) -> Mesh:
        if holes is not None:
            mesh = hole_stage.cut_open(mesh, holes, rims)
            # the rims' vertices too hold their pixels' values while the rows are made
            mesh = Mesh(mesh.vertices, vertex_values.sample(band, mesh.vertices), mesh.triangles,
                        mesh.width, mesh.height, mesh.constraints, holes)
        if top is not None:
            mesh = banding.pin_top_row(mesh, *top)
        if not last:
            # the next band starts from this band's last row: make that row good
            mesh = banding.sample_last_row(mesh, band, _row_tolerance(plan, mesh, band, mse))
        return mesh

    return finish


def _reshaped(plan: Plan, band: np.ndarray, holes: np.ndarray | None, rims, share: int,
              top, last: bool, build, options) -> Meshed:
    """The band's mesh made in turns (the mesher's, then holes cut, then the shared rows,
    each triangulated): for the rare band where a wall crosses a rim in a way only
    the triangulation finds."""
    meshed = build(band, share, None, **options)
    mesh = meshed.mesh
    if holes is not None:
        mesh = hole_stage.cut(mesh, holes.copy(), rims)
    reshaped = mesh
    if top is not None:
        reshaped = banding.pin_top_row(reshaped, *top)
    if not last:
        reshaped = banding.sample_last_row(reshaped, band, _row_tolerance(plan, reshaped, band, meshed.mse))
    mesh = meshcode.in_stored_order(reshaped) if reshaped is not mesh else mesh
    values = vertex_values.fit(band, mesh.vertices, mesh.triangles, plan.values)
    return Meshed(Mesh(mesh.vertices, values, mesh.triangles, mesh.width, mesh.height, mesh.constraints, holes),
                  None, True)


def default_points(width: int, height: int) -> int:
    """The vertex budget of an image when none is asked for."""
    return max(4, round(DEFAULT_DENSITY * width * height))


def start_points(width: int, height: int) -> int:
    """The vertex budget of the first mesh when refinement to a bound decides the size."""
    return max(4, round(START_DENSITY * width * height))


@dataclass(frozen=True)
class Plan:
    """What every band of one image shares, fixed before the first band is coded.

    storage: the dtype of the samples the mesher sees (uint16 levels for float data,
    through `quant`); points: the whole image's vertex budget; step: the base value
    step when it is fixed in advance (None: the first band sets it)."""

    settings: Settings
    width: int
    height: int
    dtype: np.dtype
    channels: int
    storage: np.dtype
    band_height: int
    points: int
    bound: error_bound.Bound
    step: int | None
    values: str
    quant: quantise.Quantiser | None
    nodata: float | None
    #: levels of max_error left to the mesh of float data (codec.slack)
    slack: int = 0


def needs_roughness(settings: Settings, dtype) -> bool:
    """Whether plan() takes the first band's roughness (codec.slack): float data under
    `max_error` alone, met by the mesh, with no precision given."""
    s = settings
    return (np.dtype(dtype).kind == "f" and s.precision is None and s.max_error is not None
            and s.max_rms is None and s.quality is None and not s.layered)


def _float_step(s: Settings, dtype, slack: int) -> float | None:
    """Float data's quantisation step: `precision` if given (the expert's override);
    under `max_error` alone, on the mesh path (needs_roughness), the step that leaves
    the mesh `slack` levels of the bound (the finest step would spend the budget on
    16-bit vertex values); otherwise None, the finest step 65,536 levels allow."""
    if s.precision is not None:
        return s.precision
    if not needs_roughness(s, dtype):
        return None
    return quantise.step_for_error(*s.value_range, s.max_error, slack)


def plan(settings: Settings, width: int, height: int, dtype=np.uint8, channels: int = 1,
         roughness: tuple[float, float] | None = None) -> Plan:
    """The Plan of an image of this geometry under `settings`; OptionError or
    UnsupportedError if they do not fit together. roughness: the first band's
    (codec.slack.roughness: median and upper quartile, in data units) where
    needs_roughness(); None: not measured (the mesh then gets no slack)."""
    for name, value in (("width", width), ("height", height)):
        if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < 1:
            raise OptionError(f"{name} must be a positive whole number, not {value!r}")
    dtype = np.dtype(dtype)
    s = settings
    quant = None
    slack = 0
    max_rms, max_error = s.max_rms, s.max_error
    if integers.is_signed(dtype):
        if channels != 1:
            raise UnsupportedError("signed integer images must have one channel")
        if s.precision is not None:
            raise OptionError(f"{dtype} data is stored exactly; precision applies to float images only")
        value_range = s.value_range if s.value_range is not None else integers.default_range(dtype)
        if value_range is None:
            raise OptionError(
                f"a {dtype} stream needs value_range=(lowest, highest) so that the header can "
                "carry the offset before the data arrives"
            )
        # whole numbers with scale 1: bounds in sample units are bounds on q as they are
        quant = integers.plan(*value_range, dtype)
    elif dtype.kind == "f":
        if channels != 1:
            raise UnsupportedError("float images must have one channel")
        if s.value_range is None:
            raise OptionError(
                "a float stream needs value_range=(lowest, highest) so that the header can "
                "carry the quantisation before the data arrives"
            )
        if needs_roughness(s, dtype):
            slack = slack_rule.mesh_slack(s.max_error, roughness)
        quant = quantise.plan(*s.value_range, precision=_float_step(s, dtype, slack))
        if s.quality is None:
            max_rms, max_error = quant.integer_bounds(max_rms, max_error, quant.scale / 2)
    elif s.value_range is not None or s.precision is not None:
        raise OptionError("value_range applies to float and signed integer images; precision to float images only")
    elif dtype not in SAMPLE_TYPES:
        raise integers.unsupported(dtype)
    if channels not in (1, 3):
        raise UnsupportedError(f"{channels} channels; .atm stores 1 (gray) or 3 (RGB)")
    storage = quantise.STORAGE if quant is not None else dtype
    nodata = s.nodata
    if nodata is not None and dtype.kind in "ui":
        info = np.iinfo(dtype)
        if not (float(nodata).is_integer() and info.min <= nodata <= info.max):
            raise OptionError(f"nodata must be a {dtype} value, not {nodata!r}")
    # float data always has a nodata value (NaN unless given), as NaN can turn up in
    # any row; integer data has one when the user names it
    if dtype.kind == "f":
        nodata = float("nan") if nodata is None else quantise.check_nodata(nodata)
    band_height = s.band_height or banding.default_band_height(width, height)
    if s.quality is not None:
        max_rms = error_bound.quality_rms(s.quality, storage)
    bound = error_bound.Bound(max_rms=max_rms, max_error=max_error)
    # under an error bound, refinement decides every value exactly
    step = 1 if bound.active else (None if s.value_step == "auto" else int(s.value_step))
    points = s.points
    if points is None:
        points = start_points(width, height) if bound.active else default_points(width, height)
    # refinement picks new vertices' values as the mesher does: as given, or by its
    # build()'s default
    values = s.values or inspect.signature(builder(s.mesher)).parameters["values"].default
    return Plan(
        s, int(width), int(height), dtype, channels, np.dtype(storage),
        int(min(band_height, max(height - 1, 1))), int(points), bound, step, values, quant, nodata, slack,
    )


@dataclass(frozen=True)
class CodedBand:
    """A band's mesh as it will be stored, and what the next band and the writer need.

    mesh: in stored order (vertices in raster order), values quantised as stored.
    step: the base value step it was quantised with (the next bands use the same).
    delaunay: the triangles are the ones a decoder rebuilds (meshcode.encode_band).
    layout: the mesh's meshcode.Layout, which quantising it made (None if not made).
    """

    y0: int
    mesh: Mesh
    step: int
    delaunay: bool
    layout: meshcode.Layout | None = None

    def bottom_row(self) -> tuple[np.ndarray, np.ndarray]:
        """The last row's vertices (x sorted) and values, which the next band shares."""
        return banding.bottom_row(self.mesh)


def _decoded_mse(mesh: Mesh, band: np.ndarray, valid: np.ndarray | None) -> float:
    """The smallest channel's mean squared error of the decoded mesh over the valid
    pixels (the decoder's own rule)."""
    from . import decoder_cpu

    diff = decoder_cpu.render(mesh).astype(np.float64) - band
    diff = diff.reshape(mesh.height, mesh.width, -1)
    if valid is not None:
        diff = diff[valid]
    return float((diff.reshape(-1, mesh.channels) ** 2).mean(axis=0).min()) if diff.size else 0.0


#: A shared row follows the image to ROW_FACTOR times the band's RMS error (as the
#: mesher last measured it): closer costs more bytes than it saves error.
ROW_FACTOR = 2.0


def _row_tolerance(plan: Plan, mesh: Mesh, band: np.ndarray, mse: float | None) -> float:
    """How closely a shared row must follow the image: the error bound if there is
    one, else ROW_FACTOR times the band's RMS error as the mesher last measured it
    (`mse`; None: as the row's vertices so far follow the row, which lies on the
    band's hull and decodes as the line through them)."""
    if plan.bound.max_error is not None:
        return float(plan.bound.max_error)
    if plan.bound.max_rms is not None:
        return float(plan.bound.max_rms)
    if mse is None:
        xs, values = banding.bottom_row(mesh)
        row = band[mesh.height - 1].reshape(mesh.width, -1).astype(np.float64)
        values = values.reshape(len(xs), -1).astype(np.float64)
        if len(xs):
            line = np.stack([np.interp(np.arange(mesh.width), xs, v) for v in values.T], axis=1)
        else:
            line = row.mean(axis=0)
        mse = float(np.mean((line - row) ** 2))
    return max(1.0, ROW_FACTOR * float(np.sqrt(mse)))


def code_band(
    rows: np.ndarray,
    holes: np.ndarray | None,
    plan: Plan,
    *,
    y0: int,
    top: tuple[np.ndarray, np.ndarray] | None,
    last: bool,
    step: int | None,
    progress: Callable[[float], None] | None = None,
) -> CodedBand:
    """The coded mesh of `rows` (image rows y0 .. y0 + len(rows) - 1, in the plan's
    storage dtype; `holes`: pixels without data, or None).

    top: the previous band's bottom_row() (None for the first band), which this band's
    first row takes exactly; last: whether the band ends the image (otherwise its last
    row is sampled closely for the next band); step: the base value step chosen so far
    (None: this band chooses it); progress: called with the share of the band's work
    done, 0..1, as it goes (the mesh, then each round of refinement to a bound)."""
    has_holes = holes is not None and bool(holes.any())
    count = len(rows) - (y0 > 0)
    share = max(4, round(plan.points * count / plan.height))
    rims = None
    if has_holes:
        # the holes' rims are vertices of the band's budget too: the mesher gets the rest
        rims = hole_stage.rims(holes, int(hole_stage.RIM_SHARE * share))
        share = max(4, share - len(np.unique(np.concatenate(rims), axis=0)) if rims else share)
    band = hole_stage.fill(rows, holes) if has_holes else rows
    build = builder(plan.settings.mesher)
    options = plan.settings.mesher_options()
    finish = None
    if has_holes or top is not None or not last:
        # the holes, the shared first row and the sampled last row go in before the
        # mesher's last triangulation, so that the band is triangulated once a round
        finish = _finisher(plan, band, holes if has_holes else None, rims, top, last)
    try:
        if has_holes:
            rim_count = len(np.unique(np.concatenate(rims), axis=0)) if rims else 0
            meshed = _mesh_around_holes(lambda n: build(band, n, finish, **options),
                                        lambda m: len(m.mesh.vertices) - rim_count, share)
        else:
            meshed = build(band, share, finish, **options)
    except ATMError:
        # a wall and a rim still cross: mesh first, then cut and pin (triangulating again)
        meshed = _reshaped(plan, band, holes, rims, share, top, last, build, options)
    if progress is not None and plan.bound.active:
        progress(0.2)
    mesh, delaunay, mse = meshed.mesh, meshed.delaunay, meshed.mse
    if finish is not None:
        # the mesher fitted every value; the shared rows' are fixed: the first row's as
        # the band above stored them, the last row's its pixels (sample_last_row)
        values = mesh.values.copy()
        if top is not None:
            on = np.flatnonzero(mesh.vertices[:, 1] == 0)
            values[on] = top[1][np.searchsorted(top[0], mesh.vertices[on, 0])]
        if not last:
            on = np.flatnonzero(mesh.vertices[:, 1] == mesh.height - 1)
            values[on] = band[mesh.height - 1, mesh.vertices[on, 0]]
        mesh = Mesh(mesh.vertices, values, mesh.triangles, mesh.width, mesh.height, mesh.constraints,
                    holes if has_holes else None)
        # the mesher's error describes its own values, over the filled holes too: the
        # step is measured again (holes: over the valid pixels)
        mse = None if has_holes or top is not None or not last else mse
    if step is None:
        if mse is None:
            mse = _decoded_mse(mesh, band, ~holes if has_holes else None)
        step = max(1, int(STEP_FACTOR * np.sqrt(mse)))
    # the values as the file will store them (pinned first-row values stay exact); the
    # stored order and sample order made for that serve the writer too
    mesh = meshcode.in_stored_order(mesh, triangulate_again=False)
    layout = meshcode.layout(mesh)
    mesh = meshcode.quantise(mesh, step, top is not None, layout)
    refined, delaunay = error_bound.refine_to_bound(
        mesh,
        band,
        plan.bound,
        values=plan.values,
        pinned_rows=1 if top is not None else 0,
        last_band=last,
        valid=~holes if has_holes else None,
        delaunay=delaunay,
        # the mesh is the first fifth of a bounded band's work; refinement the rest
        progress=None if progress is None else (lambda done: progress(0.2 + 0.8 * done)),
    )
    if refined is not mesh:
        return CodedBand(y0, meshcode.in_stored_order(refined, triangulate_again=False), step, delaunay)
    return CodedBand(y0, mesh, step, delaunay, layout)
