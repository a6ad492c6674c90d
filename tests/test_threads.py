"""Threads: the codec keeps no state between calls, so encodes and decodes running at
once in threads give the bytes and pixels they give one at a time."""

from __future__ import annotations

import threading
from concurrent.futures import ThreadPoolExecutor

import numpy as np

import codec
from tests.synthetic import range_scene

THREADS = 8


def _jobs() -> list[tuple[np.ndarray, dict]]:
    """Eight different encodes that between them take every path of the band pipeline:
    one band and several, holes, float data, an error bound, RGB, the uniform mesher."""
    jobs = []
    for k in range(THREADS):
        image = range_scene(96 + 8 * k, 80, seed=k)
        options: dict = {"points": 300 + 40 * k}
        if k % 4 == 1:
            options["band_height"] = 20
        if k == 2:
            image = image.astype(np.float32) * 0.01
            image[10:20, 30:50] = np.nan
        if k == 3:
            options = {"quality": 60}
        if k == 5:
            image = np.stack([image, image[::-1], 255 - image], axis=2)
        if k == 6:
            options["mesher"] = "uniform"
        if k == 7:
            options["mask"] = image > 200
        jobs.append((image, options))
    return jobs


def _at_once(fn, items: list) -> list:
    """fn over the items in THREADS threads that all start together, several times."""
    start = threading.Barrier(THREADS)

    def run(item):
        start.wait()
        return fn(item)

    with ThreadPoolExecutor(THREADS) as pool:
        return [list(pool.map(run, items)) for _ in range(3)]


def test_eight_threads_encode_the_bytes_one_thread_does():
    jobs = _jobs()
    alone = [codec.encode(image, **options) for image, options in jobs]
    for run in _at_once(lambda job: codec.encode(job[0], **job[1]), jobs):
        assert run == alone


def test_eight_threads_decode_the_pixels_one_thread_does():
    files = [codec.encode(image, **options) for image, options in _jobs()]
    alone = [codec.decode(data) for data in files]
    for run in _at_once(codec.decode, files):
        for got, want in zip(run, alone):
            np.testing.assert_array_equal(got, want)
