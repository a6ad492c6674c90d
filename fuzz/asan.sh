#!/usr/bin/env bash
# The decode tests (and the encoder kernels' own) once under AddressSanitizer: fuzz/asan.sh [extra pytest arguments]
#
# Builds the package, its compiled kernels with -fsanitize=address, from a copy of this
# tree (tracked and new files, no build products) into a venv of its own (.venv-asan,
# or $ASAN_VENV), then runs the decode tests there with the ASan runtime preloaded
# (Python itself is not instrumented, so the runtime must come first). The working
# tree, its .venv and its in-place kernels are left as they are. Needs gcc (or clang
# as CC) with libasan.
set -euo pipefail
cd "$(dirname "$0")/.."
root=$PWD
venv=${ASAN_VENV:-$root/.venv-asan}
cc=${CC:-gcc}
runtime=$("$cc" -print-file-name=libasan.so)
if [ ! -e "$runtime" ]; then
  echo "fuzz/asan.sh: $cc has no AddressSanitizer runtime (libasan.so)" >&2
  exit 1
fi
src=$(mktemp -d)
trap 'rm -rf "$src"' EXIT
git ls-files -z --cached --others --exclude-standard | tar -c --null -T - -f - | tar -x -C "$src" -f -

[ -x "$venv/bin/python" ] || python3 -m venv "$venv"
"$venv/bin/pip" install -q --disable-pip-version-check --upgrade pip
"$venv/bin/pip" install -q --disable-pip-version-check "$src[test]"
# then the package again, instrumented (compiled anew: the build objects of the first
# install would be reused); not editable, so the kernels live in the venv and not
# beside the sources
rm -rf "$src/build"
# (CXXFLAGS too: the C++ kernel, codec/_cdt, is compiled with them)
sanitize="-fsanitize=address -fno-omit-frame-pointer -g -O1"
CC="$cc" CFLAGS="$sanitize" CXXFLAGS="$sanitize" LDFLAGS="-fsanitize=address" \
  "$venv/bin/pip" install -q --disable-pip-version-check --no-cache-dir --force-reinstall --no-deps "$src"
# The kernels the tests will import must be the instrumented ones, in the venv (from
# /, so that the import cannot find the sources instead).
# detect_leaks=0: CPython keeps objects until exit, which LeakSanitizer reports.
export ASAN_OPTIONS="detect_leaks=0:abort_on_error=1:strict_init_order=1"
kernels=$(cd / && LD_PRELOAD="$runtime" "$venv/bin/python" -c \
  "import codec._rasterise as r, codec._fields as f, codec._cdt as c, codec._residual as e, codec._renumber as n, codec._mask as m, codec._elements as l, codec._polylines as p, codec._lsq as q, codec._samples as s, codec._gradients as g, codec._bound as b; print(r.__file__, f.__file__, c.__file__, e.__file__, n.__file__, m.__file__, l.__file__, p.__file__, q.__file__, s.__file__, g.__file__, b.__file__)")
[ -n "$kernels" ] || { echo "fuzz/asan.sh: the kernels do not import" >&2; exit 1; }
for kernel in $kernels; do
  case $kernel in "$venv"/*) ;; *) echo "fuzz/asan.sh: $kernel is not the venv's" >&2; exit 1 ;; esac
  # grep reads all of nm's output: with -q it could stop early, and under pipefail
  # the SIGPIPE that nm then gets would fail the test
  if ! nm -D "$kernel" 2>/dev/null | grep __asan >/dev/null; then
    echo "fuzz/asan.sh: $kernel is not instrumented" >&2
    exit 1
  fi
  echo "instrumented kernel: $kernel"
done

# The tests run from the copy, with the installed package ahead of its sources
# (--import-mode=append, and the pytest script, which does not put the cwd first);
# the copy has no compiled kernels, so a test that imported it would fail.
# From / rather than the copy: a test that starts `python -m codec` in a child process
# would otherwise import the copy's uncompiled sources (the child puts its working folder
# first on its path).
# test_profile_encode_... runs benchmarks/profile_encode.py, which puts the sources beside
# it first on its path (the copy's, with no compiled kernels): it tests the benchmark,
# not a kernel, and is left to the plain test run (a node id relative to --rootdir).
cd /
LD_PRELOAD="$runtime" PYTHONMALLOC=malloc "$venv/bin/pytest" -q -p no:cacheprovider --import-mode=append \
  --rootdir="$src" -c "$src/pyproject.toml" \
  --deselect "tests/test_encode_front.py::test_profile_encode_prints_a_cpu_budget_per_stage_and_puts_the_stages_back" \
  "$src"/tests/test_{decoders,container,meshcode,fuzz_smoke,stream,conformance,fields,cdt,canonical,residual,refit,lossless_float,holes,holemask,mesher_elements,mesher_polylines,stages,bound,encode_front,cdt_insert_checks,raster_order_split,decoder_object,decode_out,rasterise_order,vertex_steps_pairs,rasterise_walks,mesher_refine}.py "$@"
