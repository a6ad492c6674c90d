"""Issues #20/#21: the mesh's slack under `max_error` on float data with residual=False
(codec.slack): a level of the bound left to the mesh where the surface is smooth at
the scale of the bound, measured on the first band before its quantisation is fixed."""

from __future__ import annotations

import io

import numpy as np

import codec
from codec import pipeline, quantise, slack
from codec.cli.main import main
from codec.settings import Settings


def _smooth_dem(side: int, seed: int = 3) -> np.ndarray:
    """A float32 terrain in metres, octaves of smooth noise (as benchmarks/speed.py's dem)."""
    import cv2

    rng = np.random.default_rng(seed)
    out = np.zeros((side, side), np.float32)
    cells, amp = 4, 800.0
    while cells <= side:
        out += amp * cv2.resize(rng.standard_normal((cells, cells)).astype(np.float32), (side, side),
                                interpolation=cv2.INTER_CUBIC)
        cells, amp = cells * 2, amp / 2
    return out - out.min()


def _max_error(img: np.ndarray, data: bytes) -> float:
    valid = np.isfinite(img)
    return float(np.abs(codec.decode(data).astype(np.float64)[valid] - img[valid]).max())


def test_roughness_is_the_laplacians_median_and_upper_quartile_over_whole_neighbourhoods():
    y, x = np.mgrid[0:40, 0:50].astype(np.float64)
    assert slack.roughness(3 * x - 2 * y + 7) == (0.0, 0.0)  # a plane is not rough
    assert np.allclose(slack.roughness(0.5 * x * x), (1.0, 1.0))  # 4f - neighbours = -f'' = -1
    bumpy = 0.5 * x * x
    bumpy[5:35, 5:45] += 1000 * (np.arange(1200).reshape(30, 40) % 2)
    assert slack.roughness(bumpy)[1] > 100
    missing = np.zeros(bumpy.shape, bool)
    missing[4:36, 4:46] = True  # the bumps and their neighbours do not count
    assert np.allclose(slack.roughness(bumpy, missing), (1.0, 1.0))
    assert slack.roughness(np.where(missing, np.nan, bumpy)) == slack.roughness(bumpy, missing)
    assert slack.roughness(np.ones((2, 50))) is None
    assert slack.roughness(np.full((10, 10), np.nan)) is None
    # heavy-tailed curvature (sensor steps, texture) asks for a larger bound
    assert slack.mesh_slack(0.75, (1.0, 1.0)) == 1 and slack.mesh_slack(0.74, (1.0, 1.0)) == 0
    assert slack.mesh_slack(0.75, (1.0, 3.0)) == 0 and slack.mesh_slack(1.05, (1.0, 3.0)) == 1
    assert slack.mesh_slack(1e9, None) == 0


def test_a_smooth_dem_at_a_large_bound_gets_a_level_of_slack_and_fewer_vertices():
    # at E above the surface's roughness, a mesh that must return every level exactly
    # (step 2E) places vertices wherever the surface crosses a level; a level of slack
    # lets triangles bend over the curvature (benchmarks/speed.py's dem 512² at E = 50:
    # 88,172 -> 17,186 vertices, 48,407 -> 19,358 B)
    img = _smooth_dem(160)
    rough = slack.roughness(img)
    e = 2.0 * rough[0]
    lo, hi = float(img.min()), float(img.max())
    chosen = codec.encode(img, max_error=e, residual=False)
    no_slack = codec.encode(img, max_error=e, residual=False,
                            precision=quantise.step_for_error(lo, hi, e, 0))
    assert _max_error(img, chosen) <= e and _max_error(img, no_slack) <= e
    assert codec.info(chosen)["vertices"] < 0.6 * codec.info(no_slack)["vertices"]
    assert len(chosen) < 0.8 * len(no_slack)
    p = pipeline.plan(Settings(max_error=e, value_range=(lo, hi), residual=False), 160, 160, np.float32,
                      roughness=rough)
    assert p.slack == 1 and p.bound.max_error == 1


def test_a_rough_surface_or_a_small_bound_keeps_every_level_exact():
    img = _smooth_dem(96)
    rough = slack.roughness(img)
    lo, hi = float(img.min()), float(img.max())
    e = 0.25 * rough[0]
    data = codec.encode(img, max_error=e, residual=False)
    assert data == codec.encode(img, max_error=e, residual=False, precision=quantise.step_for_error(lo, hi, e, 0))
    p = pipeline.plan(Settings(max_error=e, value_range=(lo, hi), residual=False), 96, 96, np.float32,
                      roughness=rough)
    assert p.slack == 0 and p.bound.max_error == 0


def test_streamed_rows_cli_and_encode_give_the_same_bytes(tmp_path):
    # the slack is decided on the first band (band_height + 1 rows) however the rows
    # arrive; later bands are as rough or smoother than it, whichever: it is the same
    img = _smooth_dem(128, seed=5)
    img[40:60, 70:100] = np.nan  # holes, and in the first band
    img[100:, :30] *= 0.01  # the later bands smoother than the first
    lo, hi = float(np.nanmin(img)), float(np.nanmax(img))
    e = 2.0 * slack.roughness(img[:33])[1]
    whole = codec.encode(img, max_error=e, residual=False, band_height=32)
    assert _max_error(img, whole) <= e
    out = io.BytesIO()
    with codec.StreamEncoder(out, 128, 128, dtype=np.float32, value_range=(lo, hi), nodata=float("nan"),
                             max_error=e, residual=False, band_height=32) as enc:
        for y in range(0, 128, 7):
            enc.write(img[y:y + 7])
    assert out.getvalue() == whole
    src, dst = tmp_path / "dem.npy", tmp_path / "dem.atm"
    np.save(src, img)
    assert main(["encode", str(src), str(dst), "--max-error", repr(e), "--no-residual", "--band-height", "32"]) == 0
    assert dst.read_bytes() == whole
    # and the slack was taken: without it the file differs
    assert whole != codec.encode(img, max_error=e, residual=False, band_height=32,
                                 precision=quantise.step_for_error(lo, hi, e, 0))


def test_a_stream_cut_short_or_overfilled_before_its_first_band_is_refused_with_counts():
    img = _smooth_dem(64)

    def start() -> codec.StreamEncoder:
        return codec.StreamEncoder(io.BytesIO(), 64, 64, dtype=np.float32, value_range=(0.0, float(img.max())),
                                   max_error=50.0, residual=False)

    enc = start()
    enc.write(img[:40])
    try:
        enc.write(img[:30])
    except codec.ATMError as err:
        assert "more than the 64 rows" in str(err)
    else:
        raise AssertionError("70 rows of 64 accepted")
    enc = start()
    enc.write(img[:10])
    try:
        enc.close()
    except codec.ATMError as err:
        assert "10 of the 64 rows" in str(err)
    else:
        raise AssertionError("close() accepted 10 of 64 rows")
