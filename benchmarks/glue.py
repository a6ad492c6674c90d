"""The decode's glue: the CPU time of a whole codec.decode outside its two kernels (the
triangulation, codec._cdt.triangulate, and the rasteriser, codec._rasterise.rasterise),
per decode, for a set of files; against another checkout of the codec in the same
interleaved rounds with --against.

The files (made once into --files, default benchmarks/out/glue): camera, moon and
astronaut at 2.8 % vertices, camera in bands of 32 rows, and TUM's 16-bit depth map
with its holes (nodata 0). Each build runs in a worker process of its own (the two
`codec` packages cannot share one); a round asks each worker for --decodes decodes of
every file, timed by thread CPU time (steadier than wall time where others load the
machine), the kernels timed inside each decode by wrapping their entry points. Every
worker checks that each file decodes to the same pixels every time, and the table
says whether the builds' pixels agree. Each build's columns also give the MESH field
passes' part of the glue (_fields.band_front and band_values, where the build has
them) and the minor page faults a decode takes in its thread (Linux; a property of
the process's heap as much as of the decode: glibc gives freed memory back to the
system, and a decode then faults in fresh pages).

    python benchmarks/glue.py [--rounds 7] [--decodes 20] [--against /path/to/other/checkout] [--decoder]

--decoder: each worker decodes with one codec.Decoder kept from decode to decode (its
decompressor and triangulation buffers reused) where its checkout has one, and with
codec.decode where it has not (the table's head says which each build used).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DENSITY = 0.028


def make_files(folder: Path) -> list[Path]:
    """The measured files, written into `folder` unless there already."""
    import cv2
    import numpy as np

    sys.path.insert(0, str(ROOT))
    import codec
    from tests.corpus import load_corpus, range_data

    folder.mkdir(parents=True, exist_ok=True)
    corpus = None
    wanted = ["camera", "moon", "astronaut", "camera_bands32", "tum_depth16"]
    for name in wanted:
        path = folder / f"{name}.atm"
        if path.exists():
            continue
        corpus = corpus or load_corpus()
        if name == "tum_depth16":
            image = cv2.imread(str(range_data() / "tum_depth.png"), cv2.IMREAD_UNCHANGED)
            if image is None:
                continue
            data = codec.encode(image, points=round(DENSITY * image.size), nodata=0)
        else:
            image = corpus[name.split("_")[0]]
            bands = {"band_height": 32} if name == "camera_bands32" else {}
            data = codec.encode(image, points=round(DENSITY * np.prod(image.shape[:2])), **bands)
        path.write_bytes(data)
    return [folder / f"{name}.atm" for name in wanted if (folder / f"{name}.atm").exists()]


def worker(files: list[str], reuse: bool = False) -> None:
    """A round per line on stdin (the number of decodes): prints, as JSON, each file's
    [whole, triangulation, rasteriser] thread CPU ns per decode, its pixels' hash, the
    field passes' ns and the minor page faults per decode (-1 where not counted).
    reuse: decode with one codec.Decoder where the checkout has it."""
    import resource

    import numpy as np

    import codec
    from codec.native import _cdt, _fields, _rasterise

    spent = {"cdt": 0, "raster": 0, "fields": 0}
    clock = time.thread_time_ns

    def timed(module, name: str, key: str) -> None:
        kernel = getattr(module, name)

        def run(*args, **kwargs):
            t0 = clock()
            try:
                return kernel(*args, **kwargs)
            finally:
                spent[key] += clock() - t0

        setattr(module, name, run)

    timed(_cdt, "triangulate", "cdt")
    timed(_rasterise, "rasterise", "raster")
    for name in ("band_front", "band_values"):  # (a checkout before them has neither)
        if hasattr(_fields, name):
            timed(_fields, name, "fields")
    who = getattr(resource, "RUSAGE_THREAD", None)

    def faults() -> int:
        return resource.getrusage(who).ru_minflt if who is not None else 0
    from codec import triangulate as triangulation
    if hasattr(triangulation, "Delaunay"):
        # a Reader triangulates in its own triangulate.Delaunay: its kernel object's
        # entry point is timed the same way (a compiled class takes no new attribute,
        # so a plain object stands in front of it)
        made = triangulation.Delaunay.__init__

        def owned(self) -> None:
            made(self)
            front = type("TimedKernel", (), {})()
            front.triangulate = self._kernel.triangulate
            timed(front, "triangulate", "cdt")
            self._kernel = front

        triangulation.Delaunay.__init__ = owned
    decode = codec.Decoder().decode if reuse and hasattr(codec, "Decoder") else codec.decode
    print(json.dumps("codec.Decoder" if decode is not codec.decode else "codec.decode"), flush=True)
    data = {f: Path(f).read_bytes() for f in files}
    first = {f: decode(d) for f, d in data.items()}
    digest = {f: hashlib.sha256(str(img.dtype).encode() + img.tobytes()).hexdigest()[:12] for f, img in first.items()}
    for line in sys.stdin:
        n = int(line)
        out = {}
        for f, d in data.items():
            spent.update(cdt=0, raster=0, fields=0)
            f0 = faults()
            t0 = clock()
            for _ in range(n):
                image = decode(d)
            whole = clock() - t0
            paged = (faults() - f0) / n if who is not None else -1
            assert np.array_equal(image, first[f]), f"{f} decoded to other pixels"
            out[f] = [whole / n, spent["cdt"] / n, spent["raster"] / n, digest[f], spent["fields"] / n, paged]
        print(json.dumps(out), flush=True)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rounds", type=int, default=7)
    parser.add_argument("--decodes", type=int, default=20, help="decodes of each file a round")
    parser.add_argument("--against", help="another checkout with its kernels built (e.g. a git worktree of main)")
    parser.add_argument("--files", default=str(ROOT / "benchmarks" / "out" / "glue"), help="where the files are made")
    parser.add_argument("--decoder", action="store_true",
                        help="decode with one codec.Decoder a worker, where the checkout has it")
    args = parser.parse_args(argv)
    files = [str(p) for p in make_files(Path(args.files))]
    builds = [str(ROOT)] + ([str(Path(args.against).resolve())] if args.against else [])
    # each worker imports its own checkout's codec (its folder first on the path)
    procs = [subprocess.Popen([sys.executable, __file__, "--worker" + ("-decoder" if args.decoder else ""), b, *files],
                              stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, cwd=b)
             for b in builds]
    how = [json.loads(proc.stdout.readline()) for proc in procs]  # what each decodes with
    results: list[list[dict]] = [[] for _ in builds]
    for round_ in range(args.rounds + 1):  # the first round warms up
        for proc, got in zip(procs, results):
            proc.stdin.write(f"{args.decodes if round_ else 2}\n")
            proc.stdin.flush()
            line = json.loads(proc.stdout.readline())
            if round_:
                got.append(line)
    for proc in procs:
        proc.stdin.close()
        proc.wait()
    names = [f"this checkout ({how[0]})"] + ([f"--against ({how[1]})"] if args.against else [])
    head = ["file"]
    for name in names:
        head += [f"{name}: decode us", "triangulation us", "rasteriser us", "glue us", "of it field passes us",
                 "page faults"]
    if args.against:
        head += ["glue this / against", "same pixels"]
    print(f"{args.rounds} interleaved rounds of {args.decodes} decodes a file; thread CPU time per decode, "
          "medians over the rounds; glue = decode - triangulation - rasteriser")
    print("| " + " | ".join(head) + " |")
    print("|---|" + "---:|" * (len(head) - 1))
    for f in files:
        row = [Path(f).stem]
        glue = []
        for got in results:
            rounds = [r[f] for r in got]
            glue.append([w - c - r for w, c, r, *_ in rounds])
            for k in range(3):
                row.append(f"{statistics.median(x[k] for x in rounds) / 1e3:.0f}")
            row.append(f"{statistics.median(glue[-1]) / 1e3:.0f}")
            row.append(f"{statistics.median(x[4] for x in rounds) / 1e3:.0f}")
            paged = statistics.median(x[5] for x in rounds)
            row.append("-" if paged < 0 else f"{paged:.0f}")
        if args.against:
            row.append(f"{statistics.median(a / b for a, b in zip(*glue)):.2f}")
            row.append("yes" if results[0][0][f][3] == results[1][0][f][3] else "NO")
        print("| " + " | ".join(row) + " |", flush=True)
    return 0


if __name__ == "__main__":
    if sys.argv[1:2] in (["--worker"], ["--worker-decoder"]):  # a build's worker: glue.py --worker CHECKOUT FILE...
        sys.path.insert(0, sys.argv[2])
        worker(sys.argv[3:], sys.argv[1] == "--worker-decoder")
    else:
        sys.exit(main())
