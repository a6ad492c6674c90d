"""Speed against the peers a user would pick instead, as ratios measured in one process.

Four tables, each measured in interleaved rounds (every round times each contender
once, so that a burst of load on a shared machine hits all of them alike); a ratio is
the median over the rounds of each round's own ratio, a time the median time.

1. Decode, for each corpus image meshed at 2.8 % vertex density: codec.decode of the
   .atm bytes (backend="cpu", and "gl" when a context can be made) against JPEG
   quality 90 and PNG (cv2.imdecode), and WebP, AVIF and JPEG XL at level 90
   (imagecodecs, in the bench extra; left out when it is not installed; WebP codes a
   gray image as three equal channels). Also the parts of a decode:
   render (the rasteriser alone, mesh -> image, as a decode runs it on a validated
   mesh: decoder_cpu.render(tiles=True)) and triangulate (the constrained
   Delaunay triangulation the format leaves implicit, which no decoder can skip: the
   compiled kernel codec.triangulate.delaunay the decoder uses, and against it
   Triangle followed by the canonical flip pass, the way it was built before).
   "decoder" is a codec.Decoder's decode, the one object decoding the file round
   after round in the memory it keeps (what a caller decoding many files does).
   --large 2048 adds each image resized to 2048 x 2048 (cubic).
2. Threads: two threads each decoding its own list of files (the corpus files, each
   several times) against one thread decoding both lists in turn: throughput ratio; a
   row with codec.decode, a row with a codec.Decoder per thread.
3. Encode at equal vertex count: codec.encode(image, points=N) against pydelatin's
   Delatin(image, max_points=N) (bench extra; left out without it), by wall time and
   by process CPU time (steadier where others load the machine).
4. Encode at equal max error: codec.encode(dem, max_error=E) of a float DEM (the encode
   a user calls: the mesh and the residual layer that makes the bound hold) and
   codec.encode(dem, max_error=E, residual=False) (the mesh alone), in the same rounds,
   against Delatin(dem, max_error=E), for each E (a synthetic DEM, or --dem-file's
   GeoTIFF as float32), with the .atm bytes and both vertex counts, by wall time and
   process CPU time.
5. Encode to a quality: codec.encode(image, quality=Q) of each gray corpus image, and
   of the RGB astronaut when the astronaut is chosen, against a JPEG XL encode at
   level 90 (imagecodecs; JPEG quality 90 without it), by wall time and process CPU
   time.

Measures and prints; asserts nothing.

    python benchmarks/speed.py [--repeat 31] [--images camera moon] [--dem-size 1024]
"""

from __future__ import annotations

import argparse
import os
import queue
import statistics
import threading
import sys
import time
from pathlib import Path
from typing import Callable

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import codec  # noqa: E402
from codec import container, decoder_cpu, decoder_gl  # noqa: E402
from codec.errors import BackendError  # noqa: E402
from codec.mesh import segments  # noqa: E402
from codec.coding import canonical_triangles  # noqa: E402
from codec.triangulate import by_triangle, delaunay  # noqa: E402

DENSITY = 0.028


def interleaved(fns: dict[str, Callable[[], object]], repeat: int,
                clock: Callable[[], float] = time.perf_counter) -> dict[str, list[float]]:
    """Times in milliseconds of each function, `repeat` rounds in which each runs once
    (after one warm-up call each): wall time, or by `clock` (time.process_time: the
    process's CPU time, which load from other processes changes far less)."""
    for fn in fns.values():
        fn()
    times: dict[str, list[float]] = {name: [] for name in fns}
    for _ in range(repeat):
        for name, fn in fns.items():
            t0 = clock()
            fn()
            times[name].append(1e3 * (clock() - t0))
    return times


def ratio(times: dict[str, list[float]], a: str, b: str) -> float:
    """Median over the rounds of time a / time b."""
    return statistics.median(x / y for x, y in zip(times[a], times[b]))


def print_table(head: list[str], rows: list[list[str]]) -> None:
    print("| " + " | ".join(head) + " |")
    print("|" + "|".join("---:" if i > 1 else "---" for i in range(len(head))) + "|")
    for row in rows:
        print("| " + " | ".join(row) + " |", flush=True)


def peer_codecs(img: np.ndarray) -> dict[str, tuple[Callable, Callable]]:
    """(encode, decode) of each peer that handles `img`: JPEG q90 and PNG through
    OpenCV, WebP, AVIF and JPEG XL (lossy, quality 90) through imagecodecs if present."""
    import cv2

    peers: dict[str, tuple[Callable, Callable]] = {
        "jpeg": (lambda a: cv2.imencode(".jpg", a, [cv2.IMWRITE_JPEG_QUALITY, 90])[1],
                 lambda b: cv2.imdecode(b, cv2.IMREAD_UNCHANGED)),
        "png": (lambda a: cv2.imencode(".png", a)[1],
                lambda b: cv2.imdecode(b, cv2.IMREAD_UNCHANGED)),
    }
    try:
        import imagecodecs as ic
    except ImportError:
        return peers
    # libwebp codes colour only: a gray image goes in as three equal channels
    rgb = (lambda a: np.dstack([a] * 3)) if img.ndim == 2 else (lambda a: a)
    for name, enc, dec in (("webp", lambda a: ic.webp_encode(rgb(a), level=90), ic.webp_decode),
                           ("avif", lambda a: ic.avif_encode(a, level=90), ic.avif_decode),
                           ("jxl", lambda a: ic.jpegxl_encode(a, level=90), ic.jpegxl_decode)):
        try:
            dec(enc(img))
        except Exception:  # a peer that cannot code this image is left out
            continue
        peers[name] = (enc, dec)
    return peers


def decode_table(corpus: dict[str, np.ndarray], names: list[str], repeat: int, cpu: bool = False) -> dict[str, bytes]:
    """Table 1 (cpu: process CPU times instead of wall times); returns each image's
    .atm bytes."""
    try:
        decoder_gl.context()
        gl = True
    except BackendError as exc:
        print(f"GL decoder unavailable: {exc}")
        gl = False
    files = {name: codec.encode(corpus[name], points=max(4, round(DENSITY * np.prod(corpus[name].shape[:2]))))
             for name in names}
    peers = list(peer_codecs(corpus[names[0]]))
    parts = ["render", "decode", "decoder", "triangulate", "triangle+canonical"] + (["gl render", "gl decode"] if gl else [])
    cols = peers + parts
    unit = "CPU ms" if cpu else "ms"
    head = ["image", "size", "triangles"] + [f"{c} {unit}" for c in cols]
    head += [f"decode / {p}" for p in peers] + ["decoder / jpeg", "decoder / png", "render / jpeg", "triangulate / jpeg",
                                                "triangulate / triangle+canonical"]
    head += ["gl decode / jpeg"] if gl else []
    rows = []
    for name in names:
        img, data = corpus[name], files[name]
        h, w = img.shape[:2]
        mesh = codec.decode_mesh(data)
        bands = [(m.vertices, segments(m.constraints)) for _, m in container.unpack(data)[1]]
        fns: dict[str, Callable[[], object]] = {}
        for peer, (enc, dec) in peer_codecs(img).items():
            if peer in peers:
                fns[peer] = lambda dec=dec, b=enc(img): dec(b)
        # as a decode renders it: a file's mesh is validated, so it tiles the image
        fns["render"] = lambda: decoder_cpu.render(mesh, tiles=True)
        fns["decode"] = lambda: codec.decode(data, backend="cpu")
        fns["decoder"] = lambda reused=codec.Decoder(): reused.decode(data)
        fns["triangulate"] = lambda: [delaunay(v, s) for v, s in bands]
        fns["triangle+canonical"] = lambda: [canonical_triangles(by_triangle(v, s)) for v, s in bands]
        if gl:
            fns["gl render"] = lambda: decoder_gl.render(mesh)
            fns["gl decode"] = lambda: codec.decode(data, backend="gl")
        times = interleaved(fns, repeat, time.process_time if cpu else time.perf_counter)
        row = [name, f"{w}x{h}", f"{len(mesh.triangles):,}"]
        row += [f"{statistics.median(times[c]):.2f}" if c in times else "-" for c in cols]
        row += [f"{ratio(times, 'decode', p):.1f}" if p in times else "-" for p in peers]
        row += [f"{ratio(times, 'decoder', p):.2f}" for p in ("jpeg", "png")]
        row += [f"{ratio(times, 'render', 'jpeg'):.1f}", f"{ratio(times, 'triangulate', 'jpeg'):.1f}",
                f"{ratio(times, 'triangulate', 'triangle+canonical'):.2f}"]
        row += [f"{ratio(times, 'gl decode', 'jpeg'):.1f}"] if gl else []
        rows.append(row)
    print_table(head, rows)
    return files


def thread_table(files: dict[str, bytes], repeat: int, cpu: bool = False) -> None:
    """Table 2, the criterion as stated: two threads each decoding its own files against
    one thread decoding the same files in turn; the throughput ratio is one thread's
    time over two threads' (wall time: what a user sees), the median over interleaved
    rounds. cpu: also each run's process CPU time and the cores it kept busy (CPU time /
    wall time, at most 1 for one thread and 2 for two): work done with the GIL held
    leaves the other thread waiting off the CPU, so the two-thread run's cores used over
    the one-thread run's shows how far decodes overlap, and the CPU ratio whether they
    cost more CPU side by side. Load from other processes lowers both runs' use of the
    cores: read it beside the wall-time ratio, not instead."""
    lists = thread_lists(list(files.values()))
    print()
    rows = [_thread_row(lists, repeat, cpu, "codec.decode", lambda: codec.decode)]
    # a Decoder per thread, kept from run to run (each worker thread makes its own)
    mine = threading.local()

    def own() -> Callable[[bytes], np.ndarray]:
        if not hasattr(mine, "decoder"):
            mine.decoder = codec.Decoder()
        return mine.decoder.decode

    rows.append(_thread_row(lists, repeat, cpu, "a Decoder per thread", own))
    print_table(rows[0][0], [r for _, r in rows])


def thread_lists(files: list[bytes], least: int = 48) -> list[list[bytes]]:
    """The threads table's two lists: each at least `least` decodes, so that the steady
    throughput, not the run's tail, is measured. Every entry is a file of its own (its
    own copy of the bytes: no two decodes read one buffer, as no two requests to a
    server do); the second list starts one file on, so that the two threads mostly
    decode different images, although unequal decode times let them drift together."""
    reps = max(1, -(-least // len(files)))
    return [[bytes(bytearray(files[(i + k) % len(files)])) for i in range(reps * len(files))] for k in (0, 1)]


class _Worker:
    """A thread kept for every run of a row (no thread start inside a timed run, and a
    Decoder per thread lives from run to run): run(job) hands it a job, wait() returns
    when it is done. The main thread only waits while workers decode."""

    def __init__(self) -> None:
        self._jobs: queue.SimpleQueue = queue.SimpleQueue()
        self._done: queue.SimpleQueue = queue.SimpleQueue()
        self._thread = threading.Thread(target=self._loop, daemon=True)
        self._thread.start()

    def _loop(self) -> None:
        while (job := self._jobs.get()) is not None:
            try:
                job()
            except BaseException as exc:  # reported by wait(), in the main thread
                self._done.put(exc)
            else:
                self._done.put(None)

    def run(self, job: Callable[[], None] | None) -> None:
        self._jobs.put(job)

    def wait(self) -> None:
        exc = self._done.get()
        if exc is not None:
            raise exc

    def stop(self) -> None:
        self.run(None)
        self._thread.join()


def _thread_row(lists: list[list[bytes]], repeat: int, cpu: bool, label: str,
                decoder: Callable[[], Callable[[bytes], np.ndarray]]) -> tuple[list[str], list[str]]:
    """thread_table's head and row for one way of decoding: decoder() gives the calling
    thread's decode function. One thread decodes both lists in turn; two threads one list
    each, started together."""
    workers = [_Worker(), _Worker()]
    used: dict[str, list[float]] = {"one thread": [], "two threads": []}

    #: each run's time less the longest run-queue wait of its threads (ns): what the
    #: run would take had other processes left the cores free
    unloaded: dict[str, list[float]] = {"one thread": [], "two threads": []}
    waits: list[tuple[int, int]] = []  # (wall, run-queue wait) of each job of a run

    def decode_all(files: list[bytes]) -> Callable[[], None]:
        def job() -> None:
            decode = decoder()
            q0, t0 = _run_queue_wait(), time.perf_counter_ns()
            for data in files:
                decode(data)
            q1, t1 = _run_queue_wait(), time.perf_counter_ns()
            if q0 is not None and q1 is not None:
                waits.append((t1 - t0, q1 - q0))
        return job

    def note(name: str, jobs: int) -> None:
        if len(waits) == jobs:
            unloaded[name].append(max(wall - wait for wall, wait in waits) / 1e6)
        waits.clear()

    def one() -> None:
        workers[0].run(decode_all(lists[0] + lists[1]))
        workers[0].wait()
        note("one thread", 1)

    def two() -> None:
        for worker, files in zip(workers, lists):
            worker.run(decode_all(files))
        for worker in workers:
            worker.wait()
        note("two threads", 2)

    others: dict[str, list[float]] = {"one thread": [], "two threads": []}  # cores busy elsewhere, each run

    def timed(name: str, fn: Callable[[], None]) -> Callable[[], None]:
        def run() -> None:
            busy0, t0, w0 = _machine_busy(), time.process_time(), time.perf_counter()
            fn()
            busy1, t1, w1 = _machine_busy(), time.process_time(), time.perf_counter()
            used[name].append(1e3 * (t1 - t0))
            if busy0 is not None and busy1 is not None:
                others[name].append(max(0.0, (busy1 - busy0) - (t1 - t0)) / (w1 - w0))
        return run

    workers[1].run(decode_all(lists[1][:1]))  # each worker's first decode before the rounds
    workers[1].wait()
    waits.clear()
    times = interleaved({"one thread": timed("one thread", one), "two threads": timed("two threads", two)}, repeat)
    for worker in workers:
        worker.stop()
    for name in used:
        del used[name][0]  # interleaved's warm-up call
    head = ["decoding by", "decodes", "one thread ms", "two threads ms", "two threads / one thread throughput"]
    row = [label, str(len(lists[0]) + len(lists[1])), f"{statistics.median(times['one thread']):.1f}",
           f"{statistics.median(times['two threads']):.1f}", f"{ratio(times, 'one thread', 'two threads'):.2f}"]
    if cpu:
        use = {name: [c / w for c, w in zip(used[name], times[name])] for name in used}
        head += ["one thread CPU ms", "two threads CPU ms", "CPU two / one", "cores used by one thread",
                 "cores used by two threads", "cores used two / one"]
        row += [f"{statistics.median(used['one thread']):.1f}", f"{statistics.median(used['two threads']):.1f}",
                f"{ratio(used, 'two threads', 'one thread'):.2f}", f"{statistics.median(use['one thread']):.2f}",
                f"{statistics.median(use['two threads']):.2f}", f"{ratio(use, 'two threads', 'one thread'):.2f}"]
        if all(len(others[name]) == len(times[name]) + 1 for name in others):
            for name in others:
                del others[name][0]  # interleaved's warm-up call
            every = others["one thread"] + others["two threads"]
            # the rounds in which no other process kept as much as a fifth of a core
            # busy in either run: on a shared machine, the ratio the codec itself gives
            quiet = [k for k, (a, b) in enumerate(zip(others["one thread"], others["two threads"]))
                     if max(a, b) < QUIET_CORES]
            head += ["other processes' cores, median (max)", "quiet rounds", "throughput in quiet rounds"]
            row += [f"{statistics.median(every):.2f} ({max(every):.2f})", f"{len(quiet)} of {len(times['one thread'])}",
                    f"{statistics.median(times['one thread'][k] / times['two threads'][k] for k in quiet):.2f}"
                    if quiet else "-"]
        if all(len(unloaded[name]) == len(times[name]) + 1 for name in unloaded):
            for name in unloaded:
                del unloaded[name][0]  # interleaved's warm-up call
            # the threads' own time: only what the codec spends or waits for (the GIL,
            # memory), not other processes' hold on the cores (Linux's schedstat). An
            # estimate for a loaded machine, optimistic by up to the cost of running side
            # by side (CPU two / one) where load made the two threads take turns on one
            # core (seen: 1.97-2.00 loaded, against 1.86-1.89 in quiet rounds)
            head += ["throughput less run-queue waits"]
            row += [f"{ratio(unloaded, 'one thread', 'two threads'):.2f}"]
    return head, row


def _run_queue_wait() -> int | None:
    """Nanoseconds the calling thread has waited, runnable, for a core (Linux's
    /proc/thread-self/schedstat; None elsewhere): time other processes' load took
    from it. Time it spent asleep (waiting for the GIL, say) is not counted."""
    try:
        with open("/proc/thread-self/schedstat") as f:
            return int(f.read().split()[1])
    except (OSError, IndexError, ValueError):
        return None


#: Cores other processes may keep busy during a round of the threads table for it to
#: count as quiet (their load takes cores from the two threads).
QUIET_CORES = 0.2


def _machine_busy() -> float | None:
    """CPU seconds the whole machine has spent busy (Linux's /proc/stat; None
    elsewhere): a run's share beyond this process's own is other processes' load, which
    takes cores from the two threads (in ticks of 10 ms: coarse for one run)."""
    try:
        with open("/proc/stat") as f:
            fields = f.readline().split()
    except OSError:
        return None
    # user nice system idle iowait irq softirq steal: all but idle and iowait
    user, nice, system, _, _, irq, softirq, steal = (int(x) for x in fields[1:9])
    return (user + nice + system + irq + softirq + steal) / os.sysconf("SC_CLK_TCK")


def dem(size: int, seed: int = 1) -> np.ndarray:
    """A size x size float32 terrain in metres (0 .. ~1500): octaves of smooth noise,
    each twice as fine and half as high as the one before."""
    import cv2

    rng = np.random.default_rng(seed)
    out = np.zeros((size, size), np.float32)
    cells, amp = 4, 800.0
    while cells <= size:
        coarse = rng.standard_normal((cells, cells)).astype(np.float32)
        out += amp * cv2.resize(coarse, (size, size), interpolation=cv2.INTER_CUBIC)
        cells, amp = cells * 2, amp / 2
    return out - out.min()


def quality_table(corpus: dict[str, np.ndarray], names: list[str], quality: int, repeat: int) -> None:
    """Table 5: encode to `quality` against a JPEG XL (or JPEG) encode of the image, each
    gray image and, when the astronaut is among them, the RGB astronaut (scikit-image's
    photograph as it comes: colour refinement measures and refits three channels), by
    wall time and by process CPU time (the "under 1 s" criterion's clock)."""
    import cv2

    try:
        import imagecodecs

        peer, encode_peer = "jxl", lambda a: imagecodecs.jpegxl_encode(a, level=90)
    except ImportError:
        peer, encode_peer = "jpeg", lambda a: cv2.imencode(".jpg", a, [cv2.IMWRITE_JPEG_QUALITY, 90])[1]
    work = [(name, corpus[name]) for name in names if corpus[name].ndim == 2]
    if "astronaut" in names:
        from skimage import data

        work.append(("astronaut RGB", data.astronaut()))
    rows = []
    for name, img in work:
        cpu: dict[str, list[float]] = {"atm": [], peer: []}
        times = interleaved({"atm": _cpu_timed(cpu["atm"], lambda: codec.encode(img, quality=quality)),
                             peer: _cpu_timed(cpu[peer], lambda: encode_peer(img))}, repeat)
        h, w = img.shape[:2]
        rows.append([name, f"{w}x{h}", f"{statistics.median(times['atm']):.0f}",
                     f"{statistics.median(times[peer]):.1f}", f"{ratio(times, 'atm', peer):.0f}",
                     f"{statistics.median(cpu['atm']):.0f}", f"{statistics.median(cpu[peer]):.1f}"])
    print()
    print_table(["image", "size", f"atm quality={quality} ms", f"{peer} encode ms", f"atm / {peer}",
                 "atm CPU ms", f"{peer} CPU ms"], rows)


def _cpu_timed(into: list[float], fn: Callable[[], object]) -> Callable[[], None]:
    """fn, appending the process CPU time of each call after the first (interleaved's
    warm-up) to `into`, in ms: on a machine others share, CPU time varies far less
    than wall time (all threads count; pydelatin runs on one)."""
    calls = []

    def timed() -> None:
        t0 = time.process_time()
        fn()
        if calls:
            into.append(1e3 * (time.process_time() - t0))
        calls.append(1)

    return timed


def encode_tables(corpus: dict[str, np.ndarray], names: list[str], dem_size: int,
                  errors: list[float], repeat: int, sides: list[int] = (), dem_file: str | None = None) -> None:
    """Tables 3 and 4 (pydelatin, bench extra); table 3 also for the images resized to
    each of `sides` (cubic), table 4 on `dem_file` (a GeoTIFF, as float32) if given."""
    try:
        from pydelatin import Delatin
    except ImportError:
        print("\npydelatin not installed (the bench extra): encode tables left out")
        return
    import cv2

    rows = []
    work = [corpus[name] for name in names if corpus[name].ndim == 2]
    labels = [name for name in names if corpus[name].ndim == 2]
    for side in sides:
        work += [cv2.resize(img, (side, side), interpolation=cv2.INTER_CUBIC) for img in work[: len(labels)]]
    labels = labels * (1 + len(sides))
    for name, img in zip(labels, work):
        n = max(4, round(DENSITY * img.size))
        heights = img.astype(np.float32)
        cpu: dict[str, list[float]] = {"atm": [], "delatin": []}
        times = interleaved({"atm": _cpu_timed(cpu["atm"], lambda: codec.encode(img, points=n)),
                             "delatin": _cpu_timed(cpu["delatin"], lambda: Delatin(heights, max_points=n))}, repeat)
        h, w = img.shape
        rows.append([name, f"{w}x{h}", f"{n:,}", f"{statistics.median(times['atm']):.0f}",
                     f"{statistics.median(times['delatin']):.0f}", f"{ratio(times, 'atm', 'delatin'):.2f}",
                     f"{statistics.median(cpu['atm']):.0f}", f"{statistics.median(cpu['delatin']):.0f}",
                     f"{ratio(cpu, 'atm', 'delatin'):.2f}"])
    print()
    print_table(["image", "size", "vertices", "atm encode ms", "delatin ms", "atm / delatin",
                 "atm CPU ms", "delatin CPU ms", "CPU atm / delatin"], rows)
    if dem_file is None:
        terrain = dem(dem_size)
    else:
        import tifffile

        terrain = tifffile.imread(dem_file).astype(np.float32)
    rows = []
    # the encode a user calls (the mesh and its residual layer, which makes the bound
    # hold) and the mesh alone, in the same rounds
    paths = {"default": {}, "mesh only": {"residual": False}}
    for e in errors:
        cpu = {name: [] for name in (*paths, "delatin")}
        made = {}  # each contender's last result, for the bytes and vertex counts

        def run(name, make):
            return _cpu_timed(cpu[name], lambda: made.__setitem__(name, make()))

        fns = {name: run(name, lambda o=options: codec.encode(terrain, max_error=e, **o))
               for name, options in paths.items()}
        fns["delatin"] = run("delatin", lambda: Delatin(terrain, max_error=e))
        times = interleaved(fns, repeat)
        h, w = terrain.shape
        delatin_vertices = len(made["delatin"].vertices)
        for name in paths:
            data = made[name]
            rows.append([f"{w}x{h}", f"{e:g}", name, f"{len(data):,}", f"{codec.info(data)['vertices']:,}",
                         f"{delatin_vertices:,}", f"{statistics.median(times[name]):.0f}",
                         f"{statistics.median(times['delatin']):.0f}", f"{ratio(times, name, 'delatin'):.2f}",
                         f"{statistics.median(cpu[name]):.0f}", f"{statistics.median(cpu['delatin']):.0f}",
                         f"{ratio(cpu, name, 'delatin'):.2f}"])
    print()
    print_table(["float DEM", "max error (m)", "atm encode", "atm bytes", "atm vertices", "delatin vertices",
                 "atm encode ms", "delatin ms", "atm / delatin", "atm CPU ms", "delatin CPU ms",
                 "CPU atm / delatin"], rows)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeat", type=int, default=31, help="timed rounds per decode table row")
    parser.add_argument("--encode-repeat", type=int, default=3, help="timed rounds per encode row")
    parser.add_argument("--images", nargs="*", help="corpus images to measure (default: all)")
    parser.add_argument("--dem-size", type=int, default=1024, help="side of the float DEM (table 4)")
    parser.add_argument("--max-errors", type=float, nargs="*", default=[0.5, 5.0, 50.0],
                        help="max_error bounds in metres (table 4)")
    parser.add_argument("--no-encode", action="store_true", help="decode and thread tables only")
    parser.add_argument("--large", type=int, nargs="*", default=[],
                        help="also decode each image resized to N x N (cubic), e.g. 2048")
    parser.add_argument("--no-decode", action="store_true", help="encode tables only")
    parser.add_argument("--encode-sides", type=int, nargs="*", default=[],
                        help="also encode the images resized to these sides (table 3)")
    parser.add_argument("--dem-file", help="a GeoTIFF DEM for table 4, read as float32 (default: synthetic)")
    parser.add_argument("--quality", type=int, default=70, help="quality of table 5")
    parser.add_argument("--cpu", action="store_true",
                        help="decode table in process CPU time, thread table with each run's CPU time and cores used "
                             "(figures that load from other processes changes less)")
    args = parser.parse_args(argv)
    from tests.corpus import load_corpus

    corpus = load_corpus()
    names = args.images or list(corpus)
    unknown = sorted(set(names) - set(corpus))
    if unknown:
        parser.error(f"no corpus image {', '.join(unknown)}; choose from {', '.join(corpus)}")
    if not args.no_decode:
        files = decode_table(corpus, names, args.repeat, args.cpu)
        if args.large:
            import cv2

            large = {f"{name}@{n}": cv2.resize(corpus[name], (n, n), interpolation=cv2.INTER_CUBIC)
                     for name in names for n in args.large}
            decode_table(large, list(large), max(3, args.repeat // 4), args.cpu)
        thread_table(files, max(3, args.repeat // 4), args.cpu)
    if not args.no_encode:
        encode_tables(corpus, names, args.dem_size, args.max_errors, args.encode_repeat,
                      args.encode_sides, args.dem_file)
        quality_table(corpus, names, args.quality, args.encode_repeat)
    return 0


if __name__ == "__main__":
    sys.exit(main())
