"""Every encoder option, once: its name, type, default and meaning.

`codec.encode`, `codec.StreamEncoder`, `codec.build_mesh` and the `atm encode` command
all take their options through `Settings`, so that an option is declared, checked and
documented in one place; the CLI forwards exactly the options marked `cli` (and a test
checks its flags against them). Options a mesher takes are passed to its `build()`
only when given, so the mesher's own default applies otherwise.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from dataclasses import dataclass, field
from typing import Any

from .errors import OptionError

#: Mesher name -> module with `build(image, points, **options) -> mesher.Meshed`.
MESHERS = ("adaptive", "uniform")
DEFAULT_MESHER = "adaptive"


def _option(default: Any, doc: str, *, cli: bool = False, meshers: tuple[str, ...] = ()) -> Any:
    """A settings field: `cli` if `atm encode` has a flag for it, `meshers` if it is an
    option of those meshers' build() rather than of the band pipeline."""
    return field(default=default, metadata={"doc": doc, "cli": cli, "meshers": meshers})


def _whole(value, name: str, low: int = 1, high: int | None = None) -> int:
    if isinstance(value, bool) or not isinstance(value, numbers.Integral) or value < low or (
        high is not None and value > high
    ):
        span = f"from {low} to {high}" if high is not None else "" if low == 1 else f">= {low}"
        kind = "a positive whole number" if low == 1 and high is None else f"a whole number {span}"
        raise OptionError(f"{name} must be {kind}, not {value!r}")
    return int(value)


def _number(value, name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or not math.isfinite(value) or value < 0:
        raise OptionError(f"{name} must be a finite number >= 0, not {value!r}")
    return float(value)


@dataclass(frozen=True)
class Settings:
    """The options of an encode, checked when made (OptionError names the bad one).

    Size: `points`, or a bound that refinement guarantees on the decoded image, per
    channel: `quality`, `max_rms` or `max_error`. Float data: `value_range`,
    `precision`. Holes: `nodata`. The rest tune the mesher and the band pipeline.
    """

    points: int | None = _option(
        None, "target vertex count, within 10 % (default: 2.8 % of the pixels); with an error bound met by the residual layer (the default), the preview mesh's size; not with residual=False, where the bound sets the count itself", cli=True
    )
    quality: int | None = _option(None, "1..100 on JPEG's scale: an RMS bound at about JPEG's error at that quality (100 is lossless)", cli=True)
    max_rms: float | None = _option(None, "largest RMS error of the decoded image, per channel, in sample (float data: data) units", cli=True)
    max_error: float | None = _option(None, "largest error of any decoded sample, in sample (float data: data) units", cli=True)
    band_height: int | None = _option(None, "rows per band (default: about a megapixel per band)", cli=True)
    mesher: str = _option(DEFAULT_MESHER, "adaptive (walls along discontinuities) or uniform (the grid baseline)", cli=True)
    value_step: int | str = _option(
        "auto", "base quantisation step of vertex samples, 1..65535, or 'auto' (set by the first band's error; 1 under a bound)"
    )
    nodata: float | None = _option(None, "the value of pixels without data; they decode to it exactly (float data: NaN unless given)", cli=True)
    value_range: tuple[float, float] | None = _option(
        None, "float data: (lowest, highest) value, which sets the 16-bit quantisation (default: the image's finite range)", cli=True
    )
    precision: float | None = _option(None, "float data: the quantisation step (default: about 2 max_error under max_error alone, else the finest 16 bits allow)", cli=True)
    metadata: dict | None = _option(None, "a JSON object stored with the image", cli=True)
    effort: int | None = _option(
        None, "1 (quickest), 2 (default) or 3 (lowest error per byte, about 1.5x slower)", cli=True, meshers=("adaptive",)
    )
    values: str | None = _option(
        None, "vertex values: 'lsq' (least squares; the adaptive mesher's default) or 'sample' (the pixel's; the uniform one's)",
        meshers=("adaptive", "uniform"),
    )
    segment_length: int | None = _option(None, "edge polylines: longest segment in pixels (default 4)", meshers=("adaptive",))
    segment_error: float | None = _option(None, "edge polylines: largest distance of an edge pixel from its segment (default 1.0)", meshers=("adaptive",))
    tiles: tuple[int, int] | None = _option(None, "region sampling grid (H, V) (default: tiles of about 80 pixels)", meshers=("adaptive",))
    per_tile: tuple[int, int] | None = _option(None, "region samples per tile (R, Z) (default: from the budget)", meshers=("adaptive",))
    canny: tuple[float, float] | None = _option(None, "edge thresholds (low, high) in 8-bit gray levels (default: automatic)", meshers=("adaptive",))
    edge_share: float | None = _option(None, "largest share of the vertex budget on walls, 0..1 (default 0.3)", meshers=("adaptive",))
    region_share: float | None = _option(
        None, "share of the budget for curvature samples, 0..1 (default: by effort, less on piecewise-smooth images)", meshers=("adaptive",)
    )
    lossless: bool = _option(
        False, "every valid sample decodes exactly, float data to its binary32 bits (a residual layer over a coarse mesh, ATM.md §4.8, §4.10); not with an error bound", cli=True
    )
    residual: bool | str | None = _option(
        None, "how max_error or max_rms is met: None (the default) chooses the residual layer (ATM.md §4.8), the fewest bytes on "
        "every range, photo and synthetic image measured (codec.representation); True forces it, False keeps the mesh alone "
        "within the bound (what `atm mesh`, terrain tiles and codec.build_mesh need: beside a layer the stored mesh is a light "
        "preview, not within the bound); 'auto' (codec.encode only): encodes both and keeps the smaller", cli=True
    )

    def __post_init__(self) -> None:
        if self.points is not None:
            _whole(self.points, "points")
        if self.band_height is not None:
            _whole(self.band_height, "band_height")
        if self.quality is not None:
            _whole(self.quality, "quality", 1, 100)
        clash = size_conflict(
            (n for n in ("points", "quality", "max_rms", "max_error", "lossless", "residual")
             if getattr(self, n) not in (None, False)),
            mesh_only=self.residual is False or self.residual == "auto",
        )
        if clash:
            raise OptionError(f"{clash[0]} and {clash[1]} both set the size: give one of them")
        for name in ("max_rms", "max_error", "precision"):
            if getattr(self, name) is not None:
                _number(getattr(self, name), name)
        if not isinstance(self.lossless, bool):
            raise OptionError(f"lossless must be True or False, not {self.lossless!r}")
        if self.residual is not None and not isinstance(self.residual, bool) and self.residual != "auto":
            raise OptionError(f"residual must be True, False, 'auto' or None (the codec's choice), not {self.residual!r}")
        if self.residual and self.max_error is None and self.max_rms is None:
            raise OptionError("residual needs max_error or max_rms (the bound the layer meets); for exact samples give lossless")
        if self.mesher not in MESHERS:
            raise OptionError(f"unknown mesher {self.mesher!r}; choose one of {', '.join(MESHERS)}")
        if self.value_step != "auto" and (
            isinstance(self.value_step, bool) or not isinstance(self.value_step, numbers.Integral)
            or not 1 <= self.value_step <= 65535
        ):
            raise OptionError(f"value_step must be 'auto' or a whole number 1..65535, not {self.value_step!r}")
        if self.nodata is not None and (
            isinstance(self.nodata, bool) or not isinstance(self.nodata, numbers.Real)
        ):
            raise OptionError(f"nodata must be a number, not {self.nodata!r}")
        if self.value_range is not None:
            try:
                lo, hi = (float(v) for v in self.value_range)
            except (TypeError, ValueError):
                raise OptionError(f"value_range must be a pair (lowest, highest), not {self.value_range!r}") from None
            object.__setattr__(self, "value_range", (lo, hi))
        if self.metadata is not None and not isinstance(self.metadata, dict):
            raise OptionError(f"metadata must be a dict (a JSON object), not {type(self.metadata).__name__}")
        foreign = [
            f.name for f in dataclasses.fields(self)
            if f.metadata["meshers"] and self.mesher not in f.metadata["meshers"] and getattr(self, f.name) is not None
        ]
        if foreign:
            raise OptionError(
                f"mesher {self.mesher!r} has no option {', '.join(foreign)}; "
                f"its options are: {', '.join(mesher_option_names(self.mesher)) or 'none'}"
            )

    @classmethod
    def from_options(cls, *, also: tuple[str, ...] = (), **options) -> "Settings":
        """Settings from keyword options; an unknown one is an OptionError that lists
        the valid ones (and `also`, the caller's own keywords). None stands for the
        default, as if not given."""
        names = option_names()
        unknown = sorted(set(options) - set(names))
        if unknown:
            raise OptionError(
                f"unknown encoder option{'s' if len(unknown) > 1 else ''} {', '.join(unknown)}; "
                f"the options are: {', '.join(names + tuple(also))}"
            )
        return cls(**{k: v for k, v in options.items() if v is not None})

    def given(self) -> dict:
        """The options that differ from their defaults, by name."""
        return {
            f.name: getattr(self, f.name) for f in dataclasses.fields(self) if getattr(self, f.name) != f.default
        }

    def replace(self, **changes) -> "Settings":
        """A copy with some options changed (checked again)."""
        return dataclasses.replace(self, **changes)

    def mesher_options(self) -> dict:
        """The options given for the mesher's build(), by name."""
        return {n: getattr(self, n) for n in mesher_option_names(self.mesher) if getattr(self, n) is not None}

    @property
    def layered(self) -> bool:
        """Whether a residual layer meets the size option: `lossless`, or `max_error` /
        `max_rms` unless `residual=False` (codec.representation says why)."""
        if self.lossless:
            return True
        if self.max_error is None and self.max_rms is None or self.quality is not None:
            return False
        return self.residual is not False

    @property
    def bounded(self) -> bool:
        """Whether refinement to an error bound decides the mesh's size."""
        return self.quality is not None or self.max_rms is not None or self.max_error is not None


def size_conflict(given, mesh_only: bool = False) -> tuple[str, str] | None:
    """The first pair of the given size options (by name) that cannot go together:
    `quality` is an RMS bound, so it takes no `max_rms`, and `lossless` takes no bound.
    `max_rms` with `max_error` is two bounds, both met. A bound is met by a residual layer
    unless `mesh_only` (residual=False, or 'auto', which also encodes the mesh alone):
    `points` then sets the size of the preview mesh beside the layer, and only a mesh
    that must meet the bound itself refuses `points` with it."""
    given = list(given)
    pairs = [("points", "quality"), ("points", "max_rms"), ("points", "max_error"), ("quality", "max_rms"),
             ("lossless", "quality"), ("lossless", "max_rms"), ("lossless", "max_error"),
             ("residual", "quality"), ("lossless", "residual")]
    if not mesh_only:
        pairs = [(a, b) for a, b in pairs if not (a == "points" and b in ("max_rms", "max_error"))]
    for a, b in pairs:
        if a in given and b in given:
            return a, b
    return None


def option_names() -> tuple[str, ...]:
    """Every option's name, in declaration order."""
    return tuple(f.name for f in dataclasses.fields(Settings))


def cli_option_names() -> tuple[str, ...]:
    """The options `atm encode` has a flag for (--max-rms for max_rms, ...)."""
    return tuple(f.name for f in dataclasses.fields(Settings) if f.metadata["cli"])


def mesher_option_names(mesher: str) -> tuple[str, ...]:
    """The options the named mesher's build() takes."""
    return tuple(f.name for f in dataclasses.fields(Settings) if mesher in f.metadata["meshers"])


def describe() -> str:
    """One line per option: name, default and meaning (for docs and error messages)."""
    return "\n".join(
        f"{f.name} (default {f.default!r}): {f.metadata['doc']}" for f in dataclasses.fields(Settings)
    )
