"""Bytes at a guaranteed maximum error on range data: .atm against the error-bounded
and lossless codecs users of depth maps and elevation models already have (issue #21).

    python benchmarks/range.py                       # table on stdout, plot in benchmarks/out/
    python benchmarks/range.py --images tum_depth --errors 0.5 --repeat 1
    python benchmarks/range.py --quick               # 128 x 128 crops: a smoke test

Images: every file in the shared range-data folder (the SRTM DEM read with tifffile,
its GDAL nodata tag honoured if any pixel has it; the 16-bit depth maps with their bit
depth kept and 0 as "no reading"), the corpus disparity map (0 where unknown) and a
synthetic 16-bit depth scene, and the DEM again as float32 (float data has no integer
step for a codec to find). E is a percentage of each image's value range over its
valid pixels; holes are kept.

At each E, every codec is asked for a maximum error of E on valid pixels and its error
is MEASURED on the decoded pixels: a codec that misses the bound, or whose output no
longer tells holes from data, is marked "!" and never counts as the best peer. Peers
(through imagecodecs): SZ3 (absolute bound), LERC (maxZError, with a validity mask),
JPEG-LS near-lossless (NEAR = floor(E), at most 255), ZFP (fixed accuracy), and
q2E+jxl: the levels of a uniform quantiser of step 2E (2 floor(E) + 1 for integer data,
holes a level of their own) coded by JPEG XL's lossless mode. Without a mask, holes
count as kept when thresholding |decoded - nodata| <= E gives back exactly the holes.
Lossless: .atm with lossless=True against PNG, JPEG-LS and JPEG XL lossless; float
images (the DEM as float32, in centimetres, resampled off its grid with NaN holes, the depth
maps in metres with NaN holes) against JPEG XL lossless of the floats, LERC at max
error 0 (with a validity mask), ZFP reversible, and zstd (level 19) and deflate
(level 9) of the TIFF floating-point predictor's bytes; a float codec counts as
lossless only if every valid sample keeps its binary32 bits and the holes stay NaN.
    python benchmarks/range.py --images srtm_dem_f32 srtm_cm_f32 srtm_f32_holes tum_depth_m kinect_depth_m --errors

Times: encode and decode of every codec run in interleaved rounds (each codec once per
round; the first round's output is the one measured), so load on a shared machine hits
them alike; the table gives the median over rounds of .atm's time divided by each
peer's in the same round. There is no untimed warm-up round: .atm's encode takes
seconds to a minute where the peers' first-call set-up is milliseconds.
"""

from __future__ import annotations

import argparse
import math
import statistics
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

import codec  # noqa: E402
from tests.corpus import range_data  # noqa: E402

OUT = ROOT / "benchmarks" / "out"
RANGE_DATA = range_data()
ERRORS = (0.1, 0.5, 2.0)  # percent of the valid value range
QUICK = 128  # side of the centre crop for --quick
GDAL_NODATA = 42113  # the TIFF tag GDAL writes the nodata value in
SIDE_INFO = 16  # bytes q2E+jxl needs beside the JPEG XL stream: offset and step


@dataclass(frozen=True)
class Case:
    """One range image: its pixels and the value its holes hold (None: no holes)."""

    name: str
    image: np.ndarray
    nodata: float | None

    @property
    def holes(self) -> np.ndarray:
        if self.nodata is None:
            return np.zeros(self.image.shape, bool)
        if isinstance(self.nodata, float) and math.isnan(self.nodata):
            return np.isnan(self.image)
        return self.image == self.nodata

    @property
    def valid(self) -> np.ndarray:
        return ~self.holes

    @property
    def integer(self) -> bool:
        return self.image.dtype.kind in "ui"

    @property
    def span(self) -> tuple[float, float]:
        v = self.image[self.valid]
        return float(v.min()), float(v.max())


# ---------------------------------------------------------------- images


def read_tiff(path: Path) -> tuple[np.ndarray, float | None]:
    """A GeoTIFF's first page and its GDAL nodata value (None when no pixel has it)."""
    import tifffile

    with tifffile.TiffFile(path) as tif:
        page = tif.pages[0]
        image = page.asarray()
        tag = page.tags.get(GDAL_NODATA)
    if tag is None:
        return image, None
    nodata = float(str(tag.value).strip("\x00 "))
    if math.isnan(nodata):
        return image, nodata if np.isnan(image).any() else None
    return image, nodata if (image == nodata).any() else None


def read_depth(path: Path) -> np.ndarray:
    """A 16-bit PNG or PGM with its bit depth kept."""
    import cv2

    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise SystemExit(f"cannot read {path}")
    return image


def load_cases(range_data: Path = RANGE_DATA) -> dict[str, Callable[[], Case]]:
    """Loaders by name: the range-data folder, the corpus disparity map, a synthetic
    scene. Loaded lazily so that --images reads only what it names."""
    loaders: dict[str, Callable[[], Case]] = {}
    for path in sorted(range_data.glob("*")):
        if path.suffix.lower() in (".tif", ".tiff"):
            loaders[path.stem] = lambda p=path: Case(p.stem, *read_tiff(p))
        elif path.suffix.lower() in (".png", ".pgm"):
            # the depth maps' 0 is "no reading" (the folder's README)
            loaders[path.stem] = lambda p=path: Case(p.stem, read_depth(p), 0)

    def disparity() -> Case:
        from tests.corpus import disparity

        return Case("motorcycle_disp", disparity(), 0)

    def scene() -> Case:
        from tests.synthetic import range_scene

        return Case("scene_u16", range_scene(512, 384, seed=0, dtype=np.uint16), None)

    loaders["motorcycle_disp"] = disparity
    loaders["scene_u16"] = scene
    dem = loaders.get("srtm_dem")
    if dem is not None:
        # the DEM as float32 metres: float data has no precision of its own for a codec
        # to find (issue #21: max_error alone must choose the quantisation)
        loaders["srtm_dem_f32"] = lambda: Case("srtm_dem_f32", dem().image.astype(np.float32), None)
        loaders["srtm_f32_holes"] = lambda: resampled_with_holes(dem())
        loaders["srtm_cm_f32"] = lambda: in_centimetres(dem())
    for name, per_metre in (("tum_depth", 5000), ("kinect_depth", 1000)):
        if name in loaders:
            loaders[f"{name}_m"] = lambda n=name, s=per_metre: in_metres(loaders[n](), s)
    return loaders


def resampled_with_holes(dem: Case) -> Case:
    """A float DEM whose values are no whole numbers of any step: the DEM bilinearly
    resampled 0.37 px right and 0.61 px down, in float32, with NaN voids (discs
    covering about 8 %)."""
    z = dem.image.astype(np.float64)
    fx, fy = 0.37, 0.61
    z = ((1 - fy) * ((1 - fx) * z[:-1, :-1] + fx * z[:-1, 1:]) + fy * ((1 - fx) * z[1:, :-1] + fx * z[1:, 1:]))
    z = z.astype(np.float32)
    h, w = z.shape
    y, x = np.mgrid[:h, :w]
    rng = np.random.default_rng(7)
    for cy, cx, r in zip(rng.integers(0, h, 12), rng.integers(0, w, 12), rng.integers(8, 30, 12)):
        z[(y - cy) ** 2 + (x - cx) ** 2 < r * r] = np.nan
    return Case("srtm_f32_holes", z, math.nan)


def in_centimetres(dem: Case) -> Case:
    """A float32 DEM in whole centimetres spanning more than 65,536 of them: the DEM's
    2 x 2 means plus up to 3 cm of deterministic noise."""
    z = dem.image.astype(np.float64)
    z = 0.25 * (z[:-1, :-1] + z[1:, 1:] + z[:-1, 1:] + z[1:, :-1])
    noise = np.random.default_rng(0).integers(-3, 4, z.shape)
    return Case("srtm_cm_f32", (np.round(z * 100 + noise) / 100).astype(np.float32), None)


def in_metres(depth: Case, per_metre: int) -> Case:
    """A 16-bit depth map as float32 metres, its holes (0) NaN."""
    metres = (depth.image / per_metre).astype(np.float32)
    metres[depth.image == 0] = np.nan
    return Case(f"{depth.name}_m", metres, math.nan)


def crop(case: Case, side: int) -> Case:
    """The centre side x side crop (for smoke tests)."""
    h, w = case.image.shape
    y, x = max(0, (h - side) // 2), max(0, (w - side) // 2)
    return Case(case.name, np.ascontiguousarray(case.image[y : y + side, x : x + side]), case.nodata)


# ---------------------------------------------------------------- codecs
# Each codec is an encoder (case, E) -> bytes and a decoder (case, bytes) -> pixels
# whose holes hold what the codec gives back there.


def _tolerance(case: Case, e: float) -> float:
    # a float codec's output is rounded back to integers: a tolerance under
    # floor(E) + 0.5 keeps the rounded error within floor(E)
    return math.floor(e) + 0.49 if case.integer else e


def _to_dtype(case: Case, out: np.ndarray) -> np.ndarray:
    if not case.integer:
        return out.astype(case.image.dtype)
    info = np.iinfo(case.image.dtype)
    return np.clip(np.rint(out), info.min, info.max).astype(case.image.dtype)


def _float(case: Case) -> np.ndarray:
    # float32 holds 16-bit integers exactly; wider data keeps float64
    return case.image.astype(np.float32 if case.image.dtype.itemsize <= 2 else np.float64)


def atm_encode(case: Case, e: float) -> bytes:
    # the defaults, as a user writes it: max_error alone (codec.representation chooses)
    return codec.encode(case.image, max_error=e, nodata=case.nodata)


def atm_decode(case: Case, data: bytes) -> np.ndarray:
    return codec.decode(data)


def sz3_encode(case: Case, e: float) -> bytes:
    import imagecodecs

    return imagecodecs.sz3_encode(_float(case), mode="abs", abs=_tolerance(case, e))


def sz3_decode(case: Case, data: bytes) -> np.ndarray:
    import imagecodecs

    f = _float(case)
    return _to_dtype(case, imagecodecs.sz3_decode(data, shape=f.shape, dtype=f.dtype))


def lerc_encode(case: Case, e: float) -> bytes:
    import imagecodecs

    return imagecodecs.lerc_encode(case.image, _tolerance(case, e), masks=case.valid)


def lerc_decode(case: Case, data: bytes) -> np.ndarray:
    import imagecodecs

    out, valid = imagecodecs.lerc_decode(data, masks=True)
    if case.nodata is not None:
        out = out.copy()
        out[~valid] = case.nodata
    return out


def jpegls_encode(case: Case, e: float) -> bytes:
    import imagecodecs

    # NEAR is at most 255 in JPEG-LS: a larger E gets 255 (the bound still holds)
    return imagecodecs.jpegls_encode(case.image, min(math.floor(e), 255))


def jpegls_decode(case: Case, data: bytes) -> np.ndarray:
    import imagecodecs

    return imagecodecs.jpegls_decode(data)


def zfp_encode(case: Case, e: float) -> bytes:
    import imagecodecs

    return imagecodecs.zfp_encode(_float(case), _tolerance(case, e), mode="a")


def zfp_decode(case: Case, data: bytes) -> np.ndarray:
    import imagecodecs

    return _to_dtype(case, imagecodecs.zfp_decode(data))


def quantiser_step(case: Case, e: float) -> float:
    """The widest uniform step whose rounding error stays within E."""
    return 2 * math.floor(e) + 1 if case.integer else 2 * e


def quantise(case: Case, e: float) -> np.ndarray:
    """Levels of valid pixels, step quantiser_step(E) from the smallest valid value;
    with holes, level 0 is the holes' and data starts at 1. The levels' dtype is the
    narrowest unsigned one that holds them."""
    lo, hi = case.span
    step = quantiser_step(case, e)
    first = 1 if case.holes.any() else 0
    top = first + round((hi - lo) / step)
    levels = np.zeros(case.image.shape, np.uint8 if top < 256 else np.uint16 if top < 65536 else np.uint32)
    valid = case.valid
    levels[valid] = first + np.rint((case.image[valid].astype(np.float64) - lo) / step)
    return levels


def dequantise(case: Case, levels: np.ndarray, e: float) -> np.ndarray:
    lo, _ = case.span
    first = 1 if case.holes.any() else 0
    out = lo + (levels.astype(np.float64) - first) * quantiser_step(case, e)
    if first:
        out[levels == 0] = case.nodata
    return _to_dtype(case, out)


def q2e_jxl_encode(case: Case, e: float) -> bytes:
    import imagecodecs

    levels = quantise(case, e)
    if levels.dtype == np.uint32:
        raise ValueError("more than 2^16 levels: JPEG XL lossless takes at most 16 bits")
    bits = max(1, int(levels.max()).bit_length())
    return bytes(SIDE_INFO) + imagecodecs.jpegxl_encode(levels, lossless=True, bitspersample=bits)


def q2e_jxl_decode(case: Case, data: bytes, e: float) -> np.ndarray:
    import imagecodecs

    return dequantise(case, imagecodecs.jpegxl_decode(data[SIDE_INFO:]), e)


def atm_lossless_encode(case: Case) -> bytes:
    return codec.encode(case.image, lossless=True, nodata=case.nodata)


def png_encode(case: Case) -> bytes:
    import imagecodecs

    return imagecodecs.png_encode(case.image, level=9)


def png_decode(case: Case, data: bytes) -> np.ndarray:
    import imagecodecs

    return imagecodecs.png_decode(data)


def jpegls_lossless_encode(case: Case) -> bytes:
    import imagecodecs

    return imagecodecs.jpegls_encode(case.image, 0)


def jxl_lossless_encode(case: Case) -> bytes:
    import imagecodecs

    return imagecodecs.jpegxl_encode(case.image, lossless=True)


def jxl_decode(case: Case, data: bytes) -> np.ndarray:
    import imagecodecs

    return imagecodecs.jpegxl_decode(data)


def lerc_lossless_encode(case: Case) -> bytes:
    return lerc_encode(case, 0.0)


def zfp_reversible_encode(case: Case) -> bytes:
    import imagecodecs

    return imagecodecs.zfp_encode(case.image, mode="R")


def zfp_reversible_decode(case: Case, data: bytes) -> np.ndarray:
    import imagecodecs

    return imagecodecs.zfp_decode(data)


def float_predicted(compress: Callable[[bytes], bytes]) -> Encoder:
    """An encoder: the TIFF floating-point predictor (predictor 3) of the rows, then
    `compress` of its bytes."""
    def encode(case: Case) -> bytes:
        import imagecodecs

        return compress(imagecodecs.floatpred_encode(np.ascontiguousarray(case.image), axis=-1).tobytes())

    return encode


def float_unpredicted(decompress: Callable[[bytes], bytes]) -> Decoder:
    def decode(case: Case, data: bytes) -> np.ndarray:
        import imagecodecs

        shuffled = np.frombuffer(decompress(data), case.image.dtype).reshape(case.image.shape)
        return imagecodecs.floatpred_decode(shuffled, axis=-1)

    return decode


def _zstd(level: int) -> Callable[[bytes], bytes]:
    import imagecodecs

    return lambda b: imagecodecs.zstd_encode(b, level=level)


def _deflate(level: int) -> Callable[[bytes], bytes]:
    import imagecodecs

    return lambda b: imagecodecs.zlib_encode(b, level=level)


def _unzstd(b: bytes) -> bytes:
    import imagecodecs

    return imagecodecs.zstd_decode(b)


def _inflate(b: bytes) -> bytes:
    import imagecodecs

    return imagecodecs.zlib_decode(b)


Encoder = Callable[[Case], bytes]
Decoder = Callable[[Case, bytes], np.ndarray]


def bounded_codecs(e: float) -> dict[str, tuple[Encoder, Decoder]]:
    """The codecs at maximum error E, .atm first."""
    return {
        "atm": (lambda c: atm_encode(c, e), atm_decode),
        "sz3": (lambda c: sz3_encode(c, e), sz3_decode),
        "lerc": (lambda c: lerc_encode(c, e), lerc_decode),
        "jpegls": (lambda c: jpegls_encode(c, e), jpegls_decode),
        "zfp": (lambda c: zfp_encode(c, e), zfp_decode),
        "q2E+jxl": (lambda c: q2e_jxl_encode(c, e), lambda c, d: q2e_jxl_decode(c, d, e)),
    }


LOSSLESS: dict[str, tuple[Encoder, Decoder]] = {
    "atm": (atm_lossless_encode, atm_decode),
    "png": (png_encode, png_decode),
    "jpegls": (jpegls_lossless_encode, jpegls_decode),
    "jxl": (jxl_lossless_encode, jxl_decode),
}
LOSSLESS_FLOAT: dict[str, tuple[Encoder, Decoder]] = {
    "atm": (atm_lossless_encode, atm_decode),
    "jxl": (jxl_lossless_encode, jxl_decode),
    "lerc": (lerc_lossless_encode, lerc_decode),
    "zfp-R": (zfp_reversible_encode, zfp_reversible_decode),
    "zstd+fpred": (float_predicted(_zstd(19)), float_unpredicted(_unzstd)),
    "deflate+fpred": (float_predicted(_deflate(9)), float_unpredicted(_inflate)),
}
#: the peers issue #21's criterion compares against (ZFP is measured, not counted)
CRITERION = ("sz3", "lerc", "jpegls", "q2E+jxl")


# ---------------------------------------------------------------- measuring


@dataclass
class Result:
    """One codec on one case at one bound."""

    size: int | None  # None: the codec cannot take this image
    error: float = math.nan  # largest |decoded - original| over valid pixels
    holes_kept: bool = True
    note: str = ""

    def meets(self, e: float) -> bool:
        return self.size is not None and self.error <= e and self.holes_kept

    def cell(self, e: float) -> str:
        if self.size is None:
            return "n/a"
        mark = "" if self.meets(e) else " !"
        return f"{self.size:,} ({self.error:.3g}){mark}"


def max_error(case: Case, decoded: np.ndarray) -> float:
    valid = case.valid
    return float(np.abs(decoded[valid].astype(np.float64) - case.image[valid]).max())


def holes_kept(case: Case, decoded: np.ndarray, e: float) -> bool:
    """Whether the decoded pixels still tell holes from data: thresholding at E from
    the nodata value gives back exactly the holes."""
    if case.nodata is None:
        return True
    if isinstance(case.nodata, float) and math.isnan(case.nodata):
        return bool(np.array_equal(np.isnan(decoded), case.holes))
    tolerance = math.floor(e) if case.integer else e
    near = np.abs(decoded.astype(np.float64) - case.nodata) <= tolerance
    return bool(np.array_equal(near, case.holes))


def interleaved(fns: dict[str, Callable[[], object]], repeat: int) -> dict[str, list[float]]:
    """Wall times (s) of each function over `repeat` rounds in which each runs once."""
    times: dict[str, list[float]] = {name: [] for name in fns}
    for _ in range(repeat):
        for name, fn in fns.items():
            t0 = time.perf_counter()
            fn()
            times[name].append(time.perf_counter() - t0)
    return times


def ratios(times: dict[str, list[float]], ours: str, peers: list[str]) -> dict[str, float]:
    """Median over rounds of our time divided by each peer's in the same round."""
    return {p: statistics.median(a / b for a, b in zip(times[ours], times[p])) for p in peers}


def bits_kept(case: Case, decoded: np.ndarray) -> bool:
    """Float lossless: every valid sample has its binary32 bits, every hole is NaN."""
    valid = case.valid
    same = np.array_equal(decoded[valid].view(np.uint32), case.image[valid].view(np.uint32))
    return bool(same and np.isnan(decoded[~valid]).all())


def measure(
    case: Case, codecs: dict[str, tuple[Encoder, Decoder]], e: float, repeat: int, bits: bool = False
) -> tuple[dict[str, Result], dict[str, float], dict[str, float]]:
    """Bytes and measured error of every codec, and .atm's encode and decode time ratios
    to each peer over `repeat` interleaved rounds. The first round is the one whose
    output is measured (an .atm encode of a whole DEM takes a minute: it runs `repeat`
    times, not once more). bits: holes_kept is `bits_kept` (float lossless)."""
    results: dict[str, Result] = {}
    blobs: dict[str, bytes] = {}
    first_enc: dict[str, float] = {}
    first_dec: dict[str, float] = {}
    for name, (enc, dec) in codecs.items():
        t0 = time.perf_counter()
        try:
            blobs[name] = enc(case)
        except (ValueError, RuntimeError, TypeError, codec.ATMError) as exc:
            # the codec cannot take this image (dtype, range): say so, do not count it
            results[name] = Result(None, note=str(exc).splitlines()[0])
            continue
        first_enc[name] = time.perf_counter() - t0
        t0 = time.perf_counter()
        decoded = dec(case, blobs[name])
        first_dec[name] = time.perf_counter() - t0
        kept = bits_kept(case, decoded) if bits else holes_kept(case, decoded, e)
        results[name] = Result(len(blobs[name]), max_error(case, decoded), kept)
    ran = [n for n in codecs if n in blobs]
    peers = [n for n in ran if n != "atm"]
    if repeat < 1 or "atm" not in blobs or not peers:
        return results, {}, {}
    enc_t = interleaved({n: (lambda f=codecs[n][0]: f(case)) for n in ran}, repeat - 1)
    dec_t = interleaved({n: (lambda f=codecs[n][1], b=blobs[n]: f(case, b)) for n in ran}, repeat - 1)
    for n in ran:
        enc_t[n].insert(0, first_enc[n])
        dec_t[n].insert(0, first_dec[n])
    return results, ratios(enc_t, "atm", peers), ratios(dec_t, "atm", peers)


def best_peer(results: dict[str, Result], e: float, among: tuple[str, ...]) -> str | None:
    ok = [n for n in among if n in results and results[n].meets(e)]
    return min(ok, key=lambda n: results[n].size) if ok else None


# ---------------------------------------------------------------- reporting


def lossless_row(label: str, results: dict[str, Result], enc_r: dict[str, float], dec_r: dict[str, float],
                 codecs: list[str]) -> list[str]:
    """A lossless table's row: whether .atm was exact, every codec's bytes, .atm's bytes
    and times as ratios to each peer's."""
    ours = results["atm"]
    exact = "n/a" if ours.size is None else "lossless" if ours.meets(0.0) else f"NOT lossless (err {ours.error:.3g})"
    others = codecs[1:]
    return ([label, exact] + [results[c].cell(0.0) for c in codecs]
            + [f"{ours.size / results[p].size:.2f}" if results[p].size and ours.size else "-" for p in others]
            + [f"{enc_r[p]:.1f} / {dec_r[p]:.1f}" if p in enc_r else "-" for p in others])


def markdown(head: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(head) + " |", "|" + "|".join("---" if i < 2 else "---:" for i in range(len(head))) + "|"]
    lines += [markdown_row(r) for r in rows]
    return "\n".join(lines)


def markdown_row(cells: list[str]) -> str:
    return "| " + " | ".join(cells) + " |"


def plot(points: dict[str, list[tuple[float, float, dict[str, Result]]]], path: Path) -> None:
    """Bytes against E per image, one line per codec; crosses mark missed bounds. The
    tables are printed already: without matplotlib (the bench extra) only this is skipped."""
    try:
        import matplotlib
    except ImportError:
        print(f"\nno plot ({path}): matplotlib is not installed; pip install -e '.[bench]'")
        return

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(points)
    cols = min(3, len(names))
    rows_ = math.ceil(len(names) / cols)
    fig, axes = plt.subplots(rows_, cols, figsize=(4.4 * cols, 3.6 * rows_), squeeze=False)
    for ax in axes.flat[len(names):]:
        ax.set_axis_off()
    for ax, name in zip(axes.flat, names):
        rows = points[name]
        for c in rows[0][2]:
            xs = [pct for pct, _, r in rows if r[c].size is not None]
            ys = [r[c].size for _, _, r in rows if r[c].size is not None]
            line, = ax.plot(xs, ys, "o-" if c == "atm" else ".--", label=c, lw=2 if c == "atm" else 1)
            bad = [(pct, r[c].size) for pct, e, r in rows if r[c].size is not None and not r[c].meets(e)]
            if bad:
                ax.plot(*zip(*bad), "x", color=line.get_color(), ms=9)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_title(name)
        ax.set_xlabel("max error, % of value range")
        ax.set_ylabel("bytes")
    axes.flat[0].legend(fontsize=7)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    print(f"\nplot: {path}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--images", nargs="*", help="images to measure (default: all)")
    parser.add_argument("--errors", nargs="*", type=float, default=list(ERRORS),
                        help="max errors in percent of the valid value range")
    parser.add_argument("--repeat", type=int, default=3, help="rounds per codec (0: bytes only, no times)")
    parser.add_argument("--quick", action="store_true", help=f"centre {QUICK}x{QUICK} crops (smoke test)")
    parser.add_argument("--no-lossless", action="store_true", help="skip the lossless comparison")
    parser.add_argument("--plot", type=Path, default=OUT / "range.png", help="where the plot goes")
    args = parser.parse_args(argv)
    try:
        import imagecodecs  # noqa: F401
        import tifffile  # noqa: F401
    except ImportError as exc:
        parser.error(f"{exc.name} is missing: pip install -e '.[bench]'")
    loaders = load_cases()
    names = args.images or list(loaders)
    unknown = sorted(set(names) - set(loaders))
    if unknown:
        parser.error(f"no range image {', '.join(unknown)}; choose from {', '.join(loaders)}")

    peers = [n for n in bounded_codecs(1.0) if n != "atm"]
    head = ["image", "E", "atm (err)"] + [f"{p} (err)" for p in peers] + ["best", "atm / best"]
    time_head = ["image", "E"] + [f"enc / {p}" for p in peers] + [f"dec / {p}" for p in peers]
    time_rows: list[list[str]] = []
    lossless_rows: list[list[str]] = []
    float_rows: list[list[str]] = []
    refused: dict[str, str] = {}  # "codec on image" -> why it is n/a
    points: dict[str, list[tuple[float, float, dict[str, Result]]]] = {}
    print("## Bytes at max error E on valid pixels (measured max error in brackets; ! = bound missed or holes lost)\n")
    print(markdown(head, []), flush=True)
    for name in names:
        case = loaders[name]()
        if args.quick:
            case = crop(case, QUICK)
        lo, hi = case.span
        h, w = case.image.shape
        label = f"{name} {w}x{h} {case.image.dtype}"
        for pct in args.errors:
            e = pct / 100 * (hi - lo)
            results, enc_r, dec_r = measure(case, bounded_codecs(e), e, args.repeat)
            best = best_peer(results, e, CRITERION)
            ratio = f"{results['atm'].size / results[best].size:.2f}" if best and results["atm"].size else "-"
            row = [label, f"{pct:g} % = {e:.4g}", results["atm"].cell(e)] + [results[p].cell(e) for p in peers]
            print(markdown_row(row + [best or "-", ratio]), flush=True)  # as it comes: a long run shows progress
            time_rows.append([label, f"{pct:g} %"]
                             + [f"{enc_r[p]:.1f}" if p in enc_r else "-" for p in peers]
                             + [f"{dec_r[p]:.1f}" if p in dec_r else "-" for p in peers])
            points.setdefault(label, []).append((pct, e, results))
            refused.update({f"{c} on {label}": r.note for c, r in results.items() if r.size is None})
        if not args.no_lossless and case.image.dtype.kind == "f":
            results, enc_r, dec_r = measure(case, LOSSLESS_FLOAT, 0.0, args.repeat, bits=True)
            refused.update({f"lossless {c} on {label}": r.note for c, r in results.items() if r.size is None})
            float_rows.append(lossless_row(label, results, enc_r, dec_r, list(LOSSLESS_FLOAT)))
        elif not args.no_lossless:
            results, enc_r, dec_r = measure(case, LOSSLESS, 0.0, args.repeat)
            refused.update({f"lossless {c} on {label}": r.note for c, r in results.items() if r.size is None})
            lossless_rows.append(lossless_row(label, results, enc_r, dec_r, list(LOSSLESS)))
    if args.repeat > 0:
        print("\n## .atm time / peer time (median of per-round ratios)\n")
        print(markdown(time_head, time_rows))
    if lossless_rows:
        others = list(LOSSLESS)[1:]
        print("\n## Lossless (atm with lossless=True)\n")
        print(markdown(["image", "atm lossless"] + [f"{c} bytes (err)" for c in LOSSLESS]
                       + [f"atm / {p}" for p in others] + [f"enc / dec ÷ {p}" for p in others], lossless_rows))
    if float_rows:
        others = list(LOSSLESS_FLOAT)[1:]
        print("\n## Lossless float (every valid binary32 bit kept, holes NaN; ! = not so)\n")
        print(markdown(["image", "atm lossless"] + [f"{c} bytes (err)" for c in LOSSLESS_FLOAT]
                       + [f"atm / {p}" for p in others] + [f"enc / dec ÷ {p}" for p in others], float_rows))
    if refused:
        print()
    for what, why in refused.items():
        print(f"n/a: {what}: {why}")
    if points:
        plot(points, args.plot)
    return 0


if __name__ == "__main__":
    sys.exit(main())
