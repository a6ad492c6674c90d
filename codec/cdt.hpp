// The constrained Delaunay triangulation of format version 6 (format_spec/ATM.md
// §4.2.5), built directly: vertices in raster order whose first row spans them all (a
// band's, whose corners are vertices) by a sweep-line with an advancing front (Žalik),
// any others by the convex hull's corners and then the other vertices inserted one by
// one; Lawson flips under the perturbed rule throughout; then each segment put in by
// taking out the triangles it crosses and triangulating the polygon on either side
// (Anglada's method; where a polygon meets itself, by Sloan's flips and Lawson flips
// around them). The result is the unique triangulation of §4.2.5 whatever the construction, so it equals Triangle
// followed by codec/canonical.py's flip pass. Plain C++ without the Python API, so that
// the Cython wrapper (codec/_cdt.pyx) runs it with the GIL released.
#ifndef ATM_CDT_HPP
#define ATM_CDT_HPP

#include <algorithm>
#include <cstdint>
#include <memory>
#include <new>
#include <utility>
#include <vector>

#include "crc32.hpp"
#include "inline.hpp"

namespace atmcdt {
// Internal linkage (one translation unit, the Cython wrapper's): the compiler sees every
// call, so the predicates and flips inline instead of going through the shared object's
// symbol table (interposable calls, the PLT).
namespace {

typedef int64_t i64;
typedef int32_t i32;


enum Status {
  CDT_OK = 0,
  CDT_CROSSING = 1,   // two segments cross: the triangulation would need a new vertex
  CDT_DUPLICATE = 2,  // two vertices at one position
  CDT_EXTENT = 3,     // coordinates too far apart for the exact predicates
  CDT_INDEX = 4,      // a segment names no vertex
  CDT_MEMORY = 5,
  CDT_INTERNAL = 6,   // a broken invariant (a bug, never a file's fault)
  CDT_OVER = 7,       // (strict) a segment passes over a vertex, so it is no edge
  CDT_OUTSIDE = 8,    // a point inserted outside the triangulated hull
  CDT_BUDGET = 9,     // (inside build() only) the sweep-line ran over its flips
};

//: Largest coordinate extent accepted: differences below 2^28 keep incircle's products
//: below 2^114, exact in 128-bit integers (ATM.md §8 needs only 2^20).
const i64 MAX_EXTENT = (i64(1) << 28) - 1;

//: Most vertices: up to 6 half-edges each, numbered in int32 (ATM.md §8 allows a band
//: 2^28 + 16).
const i64 MAX_VERTICES = ((i64(1) << 31) - 1) / 6;

// A 128-bit two's complement integer.
struct Wide {
  uint64_t hi, lo;
};

inline Wide add(Wide a, Wide b) {
  Wide r;
  r.lo = a.lo + b.lo;
  r.hi = a.hi + b.hi + (r.lo < a.lo);
  return r;
}

// The exact product of two int64 of magnitude below 2^63.
inline Wide product(i64 a, i64 b) {
  bool negative = (a < 0) != (b < 0);
  uint64_t u = a < 0 ? 0 - (uint64_t)a : (uint64_t)a;
  uint64_t v = b < 0 ? 0 - (uint64_t)b : (uint64_t)b;
  uint64_t u1 = u >> 32, u0 = u & 0xFFFFFFFFu, v1 = v >> 32, v0 = v & 0xFFFFFFFFu;
  uint64_t p00 = u0 * v0, p01 = u0 * v1, p10 = u1 * v0, p11 = u1 * v1;
  uint64_t mid = (p00 >> 32) + (p01 & 0xFFFFFFFFu) + (p10 & 0xFFFFFFFFu);
  Wide r;
  r.lo = (mid << 32) | (p00 & 0xFFFFFFFFu);
  r.hi = p11 + (p01 >> 32) + (p10 >> 32) + (mid >> 32);
  if (negative) {  // two's complement: invert and add one
    r.lo = ~r.lo + 1;
    r.hi = ~r.hi + (r.lo == 0);
  }
  return r;
}

// (unsigned: a half-edge index is never negative, and the unsigned remainder is a
// multiply and a shift)
inline i32 nxt(i32 e) { return (uint32_t)e % 3 == 2 ? e - 2 : e + 1; }
inline i32 prv(i32 e) { return (uint32_t)e % 3 == 0 ? e + 2 : e - 1; }

// A vertex: coordinates below MAX_EXTENT + 1 < 2^31, side by side so that a predicate
// reads one cache line per corner.
struct Pt {
  i32 x, y;
};

// Half-edge slots, 3 a triangle: grown by grow(3) with one capacity check inline
// (std::vector's push_back is an out-of-line call, 9 a triangle), left uninitialised
// until written.
template <class X>
class Slots {
  std::unique_ptr<X[]> a_;
  size_t n_ = 0, cap_ = 0;

 public:
  size_t size() const { return n_; }
  bool empty() const { return n_ == 0; }
  void clear() { n_ = 0; }
  X& operator[](size_t i) { return a_[i]; }
  const X& operator[](size_t i) const { return a_[i]; }
  X* data() { return a_.get(); }
  const X* data() const { return a_.get(); }
  void reserve(size_t k) {
    if (k <= cap_) return;
    std::unique_ptr<X[]> b(new X[k]);
    std::copy(a_.get(), a_.get() + n_, b.get());
    a_ = std::move(b);
    cap_ = k;
  }
  // room for k more: a pointer to the first
  X* grow(size_t k) {
    if (n_ + k > cap_) reserve(std::max(2 * cap_, n_ + k + 64));
    X* p = a_.get() + n_;
    n_ += k;
    return p;
  }
};

// A stack (of half-edges, vertices, ...) that grows by doubling: push and pop inline
// (std::vector's push_back is an out-of-line call on these paths).
template <class X>
class Stack {
  std::vector<X> a_;
  size_t n_ = 0;

 public:
  bool empty() const { return n_ == 0; }
  size_t size() const { return n_; }
  X back() const { return a_[n_ - 1]; }
  X operator[](size_t i) const { return a_[i]; }
  X* begin() { return a_.data(); }
  X* end() { return a_.data() + n_; }
  void pop_back() { --n_; }
  void clear() { n_ = 0; }
  void push_back(X e) {
    if (n_ == a_.size()) a_.resize(2 * n_ + 64);
    a_[n_++] = e;
  }
};
typedef Stack<i32> EdgeStack;

// A set of positions (open addressing, Fibonacci hashing), for the incremental
// triangulation's check that a point's position is not taken.
class Positions {
 public:
  bool has(Pt p) const {
    if (slot_.empty()) return false;
    uint64_t k = key(p);
    for (size_t s = at(k);; s = (s + 1) & (slot_.size() - 1)) {
      if (slot_[s] == k) return true;
      if (slot_[s] == EMPTY) return false;
    }
  }
  void add(Pt p) {
    if (2 * (count_ + 1) > slot_.size()) grow();
    uint64_t k = key(p);
    size_t s = at(k);
    while (slot_[s] != EMPTY && slot_[s] != k) s = (s + 1) & (slot_.size() - 1);
    if (slot_[s] == EMPTY) { slot_[s] = k; ++count_; }
  }

 private:
  static const uint64_t EMPTY = ~uint64_t(0);
  std::vector<uint64_t> slot_;
  size_t count_ = 0;
  int bits_ = 0;
  static uint64_t key(Pt p) { return (uint64_t)(uint32_t)p.y << 32 | (uint32_t)p.x; }
  size_t at(uint64_t k) const { return (size_t)((k * 0x9E3779B97F4A7C15ull) >> (64 - bits_)); }
  void grow() {
    std::vector<uint64_t> old;
    old.swap(slot_);
    bits_ = bits_ ? bits_ + 1 : 6;
    const uint64_t empty = EMPTY;  // a copy: assign() takes a reference, which a
    slot_.assign(size_t(1) << bits_, empty);  // class constant has no storage for
    count_ = 0;
    for (uint64_t k : old)
      if (k != EMPTY) add(Pt{(i32)(uint32_t)k, (i32)(k >> 32)});
  }
};

class CDT {
 public:
  // vertices in raster order (y, then x): the index is the priority of §4.2.5
  std::vector<Pt> pt;
  Slots<i32> V;      // start vertex of each half-edge; triangle t is 3t..3t+2
  Slots<i32> T;      // the twin half-edge, -1 on the hull
  Slots<uint8_t> C;  // whether the edge is a segment
  std::vector<i32> vinc;  // one outgoing half-edge of each vertex (-1 before it has one)
  EdgeStack stack;
  i64 flips = 0;
  bool narrow = false;  // every coordinate difference below 2^14 (set by the caller;
                        // incircle then skips its per-call check)
  bool strict = false;  // refuse a segment over a vertex instead of cutting it there

  i64 orient(i32 a, i32 b, i32 c) const {
    const Pt &A = pt[a], &B = pt[b], &C_ = pt[c];
    return (i64)(B.x - A.x) * (C_.y - A.y) - (i64)(B.y - A.y) * (C_.x - A.x);
  }

  // The exact sign of incircle(a, b, c, d) (ATM.md §4.2.5).
  // GCC -O2 kept incircle() and illegal() out of line, a call for each test of the
  // Lawson loop: inlined, a decode's triangulation takes ~2 % less time.
  ATM_INLINE int incircle(i32 a, i32 b, i32 c, i32 d) const {
    const Pt &A = pt[a], &B = pt[b], &C_ = pt[c], &D = pt[d];
    i64 adx = A.x - D.x, ady = A.y - D.y;
    i64 bdx = B.x - D.x, bdy = B.y - D.y;
    i64 cdx = C_.x - D.x, cdy = C_.y - D.y;
    // x ^ (x >> 63) is |x| for x >= 0 and |x| - 1 below: the OR of them is below 2^14
    // only if every |difference| is at most 2^14
    if (narrow || ((adx ^ (adx >> 63)) | (ady ^ (ady >> 63)) | (bdx ^ (bdx >> 63)) |
                   (bdy ^ (bdy >> 63)) | (cdx ^ (cdx >> 63)) | (cdy ^ (cdy >> 63))) < (i64(1) << 14)) {
      // differences at most 2^14 (all of them when narrow; in a wide band, most: the
      // four corners of a quadrilateral are neighbours): lifts and minors at most 2^29,
      // products at most 2^58, their sum below 2^60: exact in int64
      i64 det = (adx * adx + ady * ady) * (bdx * cdy - bdy * cdx) +
                (bdx * bdx + bdy * bdy) * (cdx * ady - cdy * adx) +
                (cdx * cdx + cdy * cdy) * (adx * bdy - ady * bdx);
      return (det > 0) - (det < 0);
    }
    // differences below 2^28: lifts and minors below 2^57, products below 2^114 and
    // their sum below 2^116, in 128-bit two's complement built from 64-bit halves (MSVC
    // has no __int128)
    Wide det = product(adx * adx + ady * ady, bdx * cdy - bdy * cdx);
    det = add(det, product(bdx * bdx + bdy * bdy, cdx * ady - cdy * adx));
    det = add(det, product(cdx * cdx + cdy * cdy, adx * bdy - ady * bdx));
    if ((int64_t)det.hi < 0) return -1;
    return (det.hi | det.lo) ? 1 : 0;
  }

  // Whether the perturbed rule flips the free edge of half-edge e: triangles (a, b, c)
  // and (b, a, d); on an exact tie, flip iff a or b is the first of the four.
  ATM_INLINE bool illegal(i32 e) const {
    i32 f = T[e];
    i32 a = V[e], b = V[nxt(e)], c = V[prv(e)], d = V[prv(f)];
    int s = incircle(a, b, c, d);
    return s > 0 || (s == 0 && before(before(a, b) ? a : b, before(c, d) ? c : d));
  }

  // Raster order (ATM.md §4.2.5's priority): p before q.
  bool before(i32 p, i32 q) const {
    return pt[p].y < pt[q].y || (pt[p].y == pt[q].y && pt[p].x < pt[q].x);
  }

  // Change tracking for Triangulation.changes(): the first time a triangle slot changes
  // after the last report, its old corners are kept (-1 for a slot that is new).
  bool track = false;
  std::vector<uint8_t> dirty_mark;
  std::vector<i32> dirty, old;

  void touch(i32 t) {
    if (!track) return;
    if ((size_t)t >= dirty_mark.size()) dirty_mark.resize(2 * (size_t)t + 16, 0);
    if (dirty_mark[t]) return;
    dirty_mark[t] = 1;
    dirty.push_back(t);
    bool exists = 3 * (size_t)t < V.size();
    for (int j = 0; j < 3; ++j) old.push_back(exists ? V[3 * t + j] : -1);
  }

  i32 add_triangle(i32 a, i32 b, i32 c) {
    i32 t = (i32)V.size();
    touch(t / 3);
    i32* v = V.grow(3);
    i32* w = T.grow(3);
    uint8_t* k = C.grow(3);
    v[0] = a; v[1] = b; v[2] = c;
    w[0] = w[1] = w[2] = -1;
    k[0] = k[1] = k[2] = 0;
    vinc[a] = t; vinc[b] = t + 1; vinc[c] = t + 2;
    return t;
  }

  void link(i32 s, i32 t, uint8_t c) {
    T[s] = t;
    C[s] = c;
    if (t >= 0) T[t] = s;
  }

  // Replace edge ab of (a, b, c) and (b, a, d) by cd: (d, c, a) in e's triangle and
  // (c, d, b) in its twin's, e and its twin the new edge dc / cd.
  void flip(i32 e) {
    i32 f = T[e], e1 = nxt(e), e2 = prv(e), f1 = nxt(f), f2 = prv(f);
    i32 a = V[e], b = V[f], c = V[e2], d = V[f2];
    i32 te1 = T[e1], te2 = T[e2], tf1 = T[f1], tf2 = T[f2];
    uint8_t ce1 = C[e1], ce2 = C[e2], cf1 = C[f1], cf2 = C[f2];
    touch(e / 3);
    touch(f / 3);
    V[e] = d; V[e1] = c; V[e2] = a;
    V[f] = c; V[f1] = d; V[f2] = b;
    link(e1, te2, ce2);
    link(e2, tf1, cf1);
    link(f1, tf2, cf2);
    link(f2, te1, ce1);
    T[e] = f; T[f] = e; C[e] = C[f] = 0;
    vinc[a] = e2; vinc[b] = f2; vinc[c] = e1; vinc[d] = e;
    if (sweeping) {  // a front edge moved to another slot: the front follows it
      if (T[e1] < 0) fedge[V[nxt(e1)]] = e1;
      if (T[e2] < 0) fedge[V[nxt(e2)]] = e2;
      if (T[f1] < 0) fedge[V[nxt(f1)]] = f1;
      if (T[f2] < 0) fedge[V[nxt(f2)]] = f2;
    }
    ++flips;
  }

  // Lawson flips until no half-edge on the stack (or moved by a flip) is illegal.
  // star: after a point p went in (split_triangle or split_edge), every half-edge on the
  // stack has p as its triangle's third corner, and only the edges opposite p need
  // checking: the edges at p are locally Delaunay once the star of p is (the insertion
  // lemma holds for the perturbed rule, a lifting like any other), so a flip leaves
  // two new edges to check instead of four, half the incircle tests.
  // False (the stack left as it is) after more flips than can be: each flip lowers the
  // lifted surface (§4.2.5), so an edge it removes never comes back, and no call makes
  // more than n (n - 1) / 2 of them unless the predicate is broken (flip_limit >= 0
  // sets a smaller bound, for tests).
  bool legalise(bool star = false) {
    i64 n = (i64)pt.size(), limit = flip_limit >= 0 ? flip_limit : n * (n - 1) / 2, done = 0;
    while (!stack.empty()) {
      i32 e = stack.back();
      stack.pop_back();
      if (T[e] < 0 || C[e] || !illegal(e)) continue;
      if (++done > limit) return false;
      i32 f = T[e];
      flip(e);  // (a, b, c) + (b, a, d) -> (d, c, a) in e's slot, (c, d, b) in f's
      stack.push_back(prv(e)); stack.push_back(nxt(f));  // a-d and d-b: opposite c
      if (!star) { stack.push_back(nxt(e)); stack.push_back(prv(f)); }
    }
    return true;
  }
  i64 flip_limit = -1;

  void push_all() {
    for (i32 e = 0; e < (i32)V.size(); ++e)
      if (T[e] > e && !C[e]) stack.push_back(e);
  }

  // Split triangle t at p (strictly inside): (a, b, c) becomes (a, b, p), (b, c, p)
  // and (c, a, p); the old outer edges go on the stack.
  void split_triangle(i32 t, i32 p) {
    i32 e0 = 3 * t, e1 = e0 + 1, e2 = e0 + 2;
    i32 a = V[e0], b = V[e1], c = V[e2];
    i32 t1e = T[e1], t2e = T[e2];
    uint8_t c1 = C[e1], c2 = C[e2];
    touch(t);
    i32 s = add_triangle(b, c, p), r = add_triangle(c, a, p);
    V[e2] = p;  // e0: a-b, e1: b-p, e2: p-a
    C[e1] = C[e2] = 0;
    link(s, t1e, c1);
    link(r, t2e, c2);
    T[e1] = s + 2; T[s + 2] = e1;
    T[s + 1] = r + 2; T[r + 2] = s + 1;
    T[r + 1] = e2; T[e2] = r + 1;
    vinc[a] = e0; vinc[b] = s; vinc[c] = r; vinc[p] = e2;
    stack.push_back(e0); stack.push_back(s); stack.push_back(r);
  }

  // Split edge e (a to b, in triangle (a, b, c); its twin in (b, a, d) if any) at p on
  // it: (a, p, c), (p, b, c), and (b, p, d), (p, a, d).
  void split_edge(i32 e, i32 p) {
    i32 en = nxt(e), ep = prv(e), f = T[e];
    i32 a = V[e], b = V[en], c = V[ep];
    i32 ten = T[en];
    uint8_t ce = C[e], cen = C[en];  // a segment split stays a segment, in two
    touch(e / 3);
    if (f >= 0) touch(f / 3);
    i32 q = add_triangle(p, b, c);
    V[en] = p;  // e: a-p, en: p-c, ep: c-a
    C[en] = 0;
    C[q] = ce;
    link(q + 1, ten, cen);
    T[en] = q + 2; T[q + 2] = en;
    vinc[a] = e; vinc[c] = ep; vinc[b] = q + 1; vinc[p] = q;
    stack.push_back(ep); stack.push_back(q + 1);
    if (f < 0) {
      link(e, -1, ce);  // both halves on the hull
      link(q, -1, ce);
      return;
    }
    i32 fn = nxt(f), fp = prv(f);
    i32 d = V[fp], tfn = T[fn];
    uint8_t cfn = C[fn];
    i32 w = add_triangle(p, a, d);
    V[fn] = p;  // f: b-p, fn: p-d, fp: d-b
    C[fn] = 0;
    C[w] = ce;
    link(w + 1, tfn, cfn);
    T[fn] = w + 2; T[w + 2] = fn;
    T[e] = w; T[w] = e;   // a-p with p-a
    T[q] = f; T[f] = q;   // p-b with b-p
    vinc[d] = fp; vinc[a] = w + 1;
    stack.push_back(fp); stack.push_back(w + 1);
  }

  // The triangle holding p, by a visibility walk from half-edge `from`: *on is the
  // half-edge p lies on, or -1 when p is strictly inside. Falls back to a scan of
  // every triangle should the walk not arrive (it does on a Delaunay triangulation).
  i32 locate(i32 from, i32 p, i32* on) {
    static const int8_t first[3][3] = {{0, 1, 2}, {1, 2, 0}, {2, 0, 1}};
    i32 t = from / 3, entry = -1;  // entry: the half-edge of t the walk came in by
    i64 steps = 0, limit = 64 + 4 * (i64)V.size();
    int turn = 0;
    for (;;) {
      i32 moved = -1, zero = -1;
      turn = turn == 2 ? 0 : turn + 1;  // the first edge tried rotates
      for (int k = 0; k < 3; ++k) {
        i32 e = 3 * t + first[turn][k];
        if (e == entry) continue;  // p is strictly on its inner side: that is why we came
        i64 o = orient(V[e], V[nxt(e)], p);
        if (o < 0) { moved = e; break; }
        if (o == 0) zero = e;
      }
      if (moved < 0) {
        *on = zero;
        return t;
      }
      if (T[moved] < 0 || ++steps > limit) break;
      entry = T[moved];
      t = entry / 3;
    }
    i32 m = (i32)(V.size() / 3);
    for (t = 0; t < m; ++t) {
      i32 e = 3 * t;
      if (orient(V[e], V[e + 1], p) >= 0 && orient(V[e + 1], V[e + 2], p) >= 0 &&
          orient(V[e + 2], V[e], p) >= 0) break;
    }
    if (t == m) return -1;
    *on = -1;
    for (i32 e = 3 * t; e < 3 * t + 3; ++e)
      if (orient(V[e], V[nxt(e)], p) == 0) *on = e;
    return t;
  }

  // The Delaunay triangulation of the vertices (CDT_DUPLICATE if two share a position):
  // by sweep() when their first row in raster order spans them (a band's, in any order:
  // 2x faster), otherwise the convex hull's corners fanned and flipped, then every other
  // vertex inserted with Lawson flips, in rounds of growing size (a biased randomised
  // insertion order), each round along a Hilbert curve, so that point location walks
  // are short.
  Status build() {
    if ((i64)pt.size() > MAX_VERTICES) return CDT_MEMORY;
    i32 n = (i32)pt.size();
    vinc.assign(n, -1);
    V.reserve(6 * (size_t)n); T.reserve(6 * (size_t)n); C.reserve(6 * (size_t)n);
    if (n < 3) return n == 2 && !before(0, 1) && !before(1, 0) ? CDT_DUPLICATE : CDT_OK;
    // Andrew's monotone chain in raster order, corners only (collinear points dropped);
    // triangulate() passes the vertices in that order already
    bool in_order = true;
    for (i32 i = 1; i < n && in_order; ++i) in_order = before(i - 1, i);
    std::vector<i32> ranked;
    if (!in_order) {
      ranked.resize(n);
      i64 xmax = 0, ymax = 0;  // (coordinates are never negative here)
      for (i32 i = 0; i < n; ++i) { xmax = std::max(xmax, (i64)pt[i].x); ymax = std::max(ymax, (i64)pt[i].y); }
      int bits = 1;
      while (bits < 64 && (uint64_t(1) << bits) <= (uint64_t)(ymax * (xmax + 1) + xmax)) ++bits;
      if (bits + INDEX_BITS <= 64) {
        // each vertex's pixel number above its index, radix sorted (2 passes for a
        // 512 x 512 image; std::sort with before() took a sixth of an encoder's start)
        std::vector<uint64_t> keys((size_t)n), spare;
        for (i32 i = 0; i < n; ++i)
          keys[i] = (uint64_t)(pt[i].y * (xmax + 1) + pt[i].x) << INDEX_BITS | (uint64_t)i;
        radix_sort(&keys, &spare, INDEX_BITS, bits);
        for (i32 i = 0; i < n; ++i) ranked[i] = (i32)(keys[i] & INDEX_MASK);
      } else {
        for (i32 i = 0; i < n; ++i) ranked[i] = i;
        std::sort(ranked.begin(), ranked.end(), [&](i32 p, i32 q) { return before(p, q); });
      }
      // the same position twice: neighbours once sorted (in raster order, each comes
      // strictly before the next)
      for (i32 i = 1; i < n; ++i)
        if (!before(ranked[i - 1], ranked[i])) return CDT_DUPLICATE;
    }
    {
      // vertices in any order (an encoder's Triangulation of a band's) are swept in
      // raster order and the triangles numbered back after: the triangulation is the
      // same (unique, and the predicates see positions only)
      std::vector<Pt> given;
      if (!in_order) {
        given = pt;
        for (i32 i = 0; i < n; ++i) pt[i] = given[ranked[i]];
      }
      i32 k = 1;
      while (k < n && pt[k].y == pt[0].y) ++k;
      i32 xmin = pt[0].x, xmax = pt[0].x;
      for (i32 i = 1; i < n; ++i) { xmin = std::min(xmin, pt[i].x); xmax = std::max(xmax, pt[i].x); }
      Status st = CDT_BUDGET;
      if (k >= 2 && k < n && pt[0].x == xmin && pt[k - 1].x == xmax) st = sweep(k);
      if (!in_order) {
        pt.swap(given);
        if (st == CDT_OK) {
          for (size_t e = 0; e < V.size(); ++e) V[e] = ranked[V[e]];
          std::vector<i32> swept;
          swept.swap(vinc);
          vinc.resize(n);
          for (i32 i = 0; i < n; ++i) vinc[ranked[i]] = swept[i];
          last = ranked[last];
        }
      }
      if (st == CDT_OK) {
        // the front is done: its arrays' pages serve constrain's stamps and
        // canonical()'s counts (fresh pages are much of a decode's cost)
        seen.swap(fprev); seen.clear();
        counts.swap(fnext); counts.clear();
      }
      if (st != CDT_BUDGET) return st;
      // no sweep, or an input the sweep takes quadratic time on (a long first row
      // fanned from one vertex: a file of 200 bytes took minutes): start again by
      // insertion, whose expected time does not depend on the input
      V.clear(); T.clear(); C.clear(); stack.clear();
      vinc.assign(n, -1);
      dirty.clear(); old.clear(); std::fill(dirty_mark.begin(), dirty_mark.end(), 0);
    }
    std::vector<i32> hull;
    hull.reserve(n + 1);
    for (int pass = 0; pass < 2; ++pass) {
      size_t base = hull.size();
      for (i32 k = 0; k < n; ++k) {
        i32 r = pass ? n - 1 - k : k, i = in_order ? r : ranked[r];
        while (hull.size() >= base + 2 && orient(hull[hull.size() - 2], hull.back(), i) <= 0)
          hull.pop_back();
        hull.push_back(i);
      }
      hull.pop_back();
    }
    if (hull.size() < 3) return CDT_OK;  // all on one line: no triangles
    // the chain runs one way round; make it counterclockwise (orient > 0)
    if (orient(hull[0], hull[1], hull[2]) < 0) std::reverse(hull.begin(), hull.end());
    std::vector<uint8_t> done(n, 0);
    for (size_t j = 1; j + 1 < hull.size(); ++j) {
      i32 t = add_triangle(hull[0], hull[j], hull[j + 1]);
      if (j > 1) { T[t] = t - 1; T[t - 1] = t; }  // h0-hj with the last one's hj-h0
    }
    for (i32 h : hull) done[h] = 1;
    push_all();
    if (!legalise()) return CDT_INTERNAL;
    std::vector<i32> rest;
    rest.reserve(n);
    for (i32 i = 0; i < n; ++i)
      if (!done[i]) rest.push_back(i);
    last = hull[0];
    return insert_in_order(insertion_order(rest), n);
  }

  // The front of sweep(): the upper boundary of the triangulated region, left to right
  // (x strictly increasing); fedge[v] is the boundary half-edge from fnext[v] to v.
  std::vector<i32> fnext, fprev, fedge;
  bool sweeping = false;

  // Whether the angle at m between p and o is below about 110 degrees (cos > -0.346):
  // the sweep's rule for joining p to o over m. Žalik's is 90 degrees; a little wider
  // leaves fewer pits in the front that later flips must fill (camera's decode: 1.04
  // flips per vertex at 90, 0.66 at 110, 0.75 at 120). A heuristic only: the
  // triangulation is the same either way, and the arithmetic is the same everywhere.
  bool narrow_at(i32 m, i32 p, i32 o) const {
    double ax = pt[p].x - pt[m].x, ay = pt[p].y - pt[m].y;
    double bx = pt[o].x - pt[m].x, by = pt[o].y - pt[m].y;
    double dot = ax * bx + ay * by;
    return dot >= 0 || 25 * dot * dot < 3 * (ax * ax + ay * ay) * (bx * bx + by * by);
  }

  // The triangle (a, b, c) on front vertices a, b = fnext[a], c = fnext[b], with b below
  // a-c: b leaves the front (fnext -2), both old front edges go on the stack.
  void fill(i32 a) {
    i32 b = fnext[a], c = fnext[b];
    i32 u = add_triangle(a, b, c);
    link(u, fedge[a], 0); link(u + 1, fedge[b], 0);
    stack.push_back(u); stack.push_back(u + 1);
    fnext[a] = c; fprev[c] = a; fedge[a] = u + 2; fnext[b] = -2;
  }

  // The triangulation of vertices in raster order whose first row (k >= 2 vertices, not
  // all of them) holds both the smallest and the largest x, by a sweep-line (Žalik, "An
  // efficient sweep-line Delaunay triangulation algorithm"): the first row is a fan
  // from vertex k; every later vertex lies above the region triangulated so far and
  // within its x range, so it is joined to the front edge below it, then to the front
  // vertices on either side while the angle at the one passed over is narrow. Its
  // new triangles' edges and those of every flip go on the stack (the region is no
  // convex hull, so flips at p can be needed too, unlike after an insertion); at the end
  // the front's concave corners are filled, which leaves the convex hull. With every
  // free edge then locally Delaunay under the perturbed rule, this is the unique
  // triangulation, as by insertion (§4.2.5).
  Status sweep(i32 k) {
    i32 n = (i32)pt.size();
    // at most SWEEP_FLIPS flips a vertex (a band's sweep makes under one), else
    // CDT_BUDGET: build() then inserts instead
    const i64 budget = SWEEP_FLIPS * (i64)n + 4096, before_flips = flips, saved_limit = flip_limit;
    if (flip_limit < 0 || flip_limit > budget) flip_limit = budget;
    auto over = [&]() { return flips - before_flips > budget; };
    fnext.reserve(n + 1);  // (canonical()'s counts later: n + 1)
    fnext.assign(n, -1); fprev.assign(n, -1); fedge.assign(n, -1);
    sweeping = true;
    for (i32 j = 0; j + 1 < k; ++j) {
      i32 t = add_triangle(j, j + 1, k);
      if (j > 0) { T[t + 2] = t - 2; T[t - 2] = t + 2; }
    }
    i32 left = 0, right = k - 1;
    fnext[0] = k; fprev[k] = 0; fedge[0] = 2;
    fnext[k] = k - 1; fprev[k - 1] = k; fedge[k] = 3 * (k - 2) + 1;
    if (pt[k].x == pt[0].x) { left = k; fprev[k] = -1; }
    if (pt[k].x == pt[k - 1].x) { right = k; fnext[k] = -1; }
    // where a vertex meets the front: a front vertex near its x, by buckets of x, each
    // the last vertex inserted there or, when a fill takes a vertex off the front, the
    // one whose new front edge passes over its x (checked still on the front; else up
    // to two buckets on the left, else the last vertex). The walk from there along the
    // front then takes 0.4 steps a vertex on camera, moon and astronaut's decodes;
    // buckets of inserted vertices alone left it 2.0 to 2.5 (mostly from the last
    // vertex, further along its row), each step a dependent load and a branch.
    i32 x0 = pt[0].x, span = pt[k - 1].x - x0 + 1;
    int shift = 0;
    while ((i64)(span >> shift) * (span >> shift) > 4 * (i64)n) ++shift;
    std::vector<i32> bucket((span >> shift) + 1, -1);
    bucket[0] = left;
    bucket[(pt[k].x - x0) >> shift] = k;
    i32 cur = k;
    for (i32 p = k + 1; p < n; ++p) {
      i32 px = pt[p].x;
      // the front edge (l, fnext[l]) below p: l.x <= p.x < r.x, or r the right end at p.x
      i32 l = cur;
      {
        i32 j = (px - x0) >> shift, b = bucket[j];
        for (int probe = 0; probe < 2 && j > 0 && (b < 0 || fnext[b] == -2); ++probe) b = bucket[--j];
        if (b >= 0 && fnext[b] != -2) l = b;  // (-2: off the front)
      }
      if (pt[l].x > px) { do l = fprev[l]; while (pt[l].x > px); }
      else { while (fnext[l] >= 0 && pt[fnext[l]].x <= px) l = fnext[l]; }
      if (l == right) l = fprev[l];
      i32 r = fnext[l];
      i32 t = add_triangle(l, r, p);
      link(t, fedge[l], 0);
      stack.push_back(t);
      // front: l, p, r
      fnext[l] = p; fprev[p] = l; fnext[p] = r; fprev[r] = p;
      fedge[l] = t + 2; fedge[p] = t + 1;
      if (pt[r].x == px) {  // r the right end, straight below p: p replaces it
        fnext[p] = -1; right = p; fnext[r] = -2;
      }
      if (pt[l].x == px) {  // straight above l: l leaves the front
        if (l == left) { left = p; fprev[p] = -1; fnext[l] = -2; }
        else fill(fprev[l]);
      }
      // right: (p, r, rr) while r lies below p-rr and the angle at r is narrow
      for (;;) {
        i32 r1 = fnext[p];
        if (r1 < 0) break;
        i32 r2 = fnext[r1];
        if (r2 < 0 || orient(p, r1, r2) <= 0) break;
        if (!narrow_at(r1, p, r2)) break;
        fill(p);
        bucket[(pt[r1].x - x0) >> shift] = p;  // r1 left the front: p-r2 spans its x
      }
      for (;;) {
        i32 l1 = fprev[p];
        if (l1 < 0) break;
        i32 l2 = fprev[l1];
        if (l2 < 0 || orient(l2, l1, p) <= 0) break;
        if (!narrow_at(l1, p, l2)) break;
        fill(l2);
        bucket[(pt[l1].x - x0) >> shift] = l2;  // likewise l2-p over l1's
      }
      cur = p;
      bool done = legalise();
      if (!done || over()) {
        sweeping = false;
        flip_limit = saved_limit;
        return CDT_BUDGET;  // (a test's smaller flip_limit fails again in insertion)
      }
      bucket[(px - x0) >> shift] = p;
    }
    // the front made convex (the hull's upper chain)
    i32 a = left;
    while (fnext[a] >= 0 && fnext[fnext[a]] >= 0) {
      i32 b = fnext[a], c = fnext[b];
      if (orient(a, b, c) > 0) {
        fill(a);
        if (fprev[a] >= 0) a = fprev[a];
      } else {
        a = b;
      }
    }
    sweeping = false;
    last = cur;
    bool done = legalise();
    flip_limit = saved_limit;
    if (!done || over()) return CDT_BUDGET;
    return CDT_OK;
  }
  static const i64 SWEEP_FLIPS = 16;

  // Insert the vertices of `keys` (insertion_order's) below `end`, one by one with
  // Lawson flips, each walk starting from the last one's triangle, or from a vertex
  // near the point where `near` (indexed by vertex - first) names one already in: a
  // hint only, since any start finds the same triangle (locate scans if a walk fails).
  Status insert_in_order(const std::vector<uint64_t>& keys, i64 end,
                         const i64* near = nullptr, i64 first = 0) {
    for (uint64_t key : keys) {
      i32 p = (i32)(key & INDEX_MASK), on = -1;
      if (p >= end) continue;
      i32 from = vinc[last];
      if (near) {
        i64 h = near[p - first];
        if (h >= 0 && h < (i64)vinc.size() && vinc[h] >= 0) from = vinc[h];
      }
      i32 t = locate(from, p, &on);
      if (t < 0) return CDT_INTERNAL;
      if (on >= 0) split_edge(on, p);
      else split_triangle(t, p);
      last = p;
      if (!legalise(true)) return CDT_INTERNAL;
    }
    return CDT_OK;
  }

  // Vertex indices are below MAX_VERTICES < 2^29: an insertion key keeps one in its low
  // bits.
  static const int INDEX_BITS = 29;
  static const uint64_t INDEX_MASK = (uint64_t(1) << INDEX_BITS) - 1;

  // The vertices `which` in insertion order (any order gives the same triangles; this
  // one keeps walks short), each as a key whose low INDEX_BITS are its index: round r
  // holds about half the points of round r + 1 (a biased randomised insertion order),
  // each round along a Hilbert curve over a grid of about two cells per point (points
  // sharing a cell go in index order); radix sorted.
  std::vector<uint64_t> insertion_order(const std::vector<i32>& which) const {
    i64 span = 1, n = (i64)which.size();
    for (i32 i : which) span = std::max(span, (i64)std::max(pt[i].x, pt[i].y) + 1);
    int order = 1, grid = 1;
    while ((i64(1) << order) < span) ++order;
    while (grid < 15 && (i64(1) << (2 * grid)) < 2 * n) ++grid;
    int shift = order > grid ? order - grid : 0;
    grid = order - shift;
    const int key_bits = 4 + 2 * grid;  // round, then Hilbert distance: at most 34 bits
    std::vector<uint64_t> keys, spare;
    keys.reserve(n);
    for (i32 i : which) {
      uint64_t h = (uint64_t)i * 0x9E3779B97F4A7C15ull;  // a fixed hash: same order every run
      h ^= h >> 31; h *= 0xBF58476D1CE4E5B9ull; h ^= h >> 29;
      uint64_t round = 0;
      while (round < 12 && (h & 1)) { ++round; h >>= 1; }
      uint64_t key = (12 - round) << (2 * grid) | hilbert(grid, pt[i].x >> shift, pt[i].y >> shift);
      keys.push_back(key << INDEX_BITS | (uint64_t)i);
    }
    radix_sort(&keys, &spare, INDEX_BITS, key_bits);
    return keys;
  }

  // Sort *a by bits low .. low + bits of each value, stably (LSD, 11 bits a pass);
  // *spare is scratch.
  static void radix_sort(std::vector<uint64_t>* a, std::vector<uint64_t>* spare, int low, int bits) {
    const int digit = 11;
    spare->resize(a->size());
    std::vector<size_t> count(size_t(1) << digit);
    for (int at = low; at < low + bits; at += digit) {
      std::fill(count.begin(), count.end(), 0);
      const uint64_t mask = (uint64_t(1) << digit) - 1;
      for (uint64_t v : *a) ++count[(v >> at) & mask];
      size_t sum = 0;
      for (size_t& c : count) { size_t k = c; c = sum; sum += k; }
      for (uint64_t v : *a) (*spare)[count[(v >> at) & mask]++] = v;
      a->swap(*spare);
    }
  }

  // Distance along the Hilbert curve of order `order` (coordinates below 2^order).
  static uint64_t hilbert(int order, i64 px, i64 py) {
    uint64_t d = 0, hx = (uint64_t)px, hy = (uint64_t)py;
    for (uint64_t s = uint64_t(1) << (order - 1); s > 0; s >>= 1) {
      uint64_t rx = (hx & s) ? 1 : 0, ry = (hy & s) ? 1 : 0;
      d += s * s * ((3 * rx) ^ ry);
      if (ry == 0) {
        if (rx == 1) { hx = s - 1 - (hx & (s - 1)); hy = s - 1 - (hy & (s - 1)); }
        else { hx &= s - 1; hy &= s - 1; }
        uint64_t tmp = hx; hx = hy; hy = tmp;
      } else {
        hx &= s - 1; hy &= s - 1;
      }
    }
    return d;
  }

  // A half-edge of the edge u-w (u to w, or w to u on the hull), or -1 if none.
  i32 find_edge(i32 u, i32 w) const {
    i32 start = vinc[u], e = start;
    for (;;) {  // counterclockwise around u
      if (V[nxt(e)] == w) return e;
      if (V[prv(e)] == w) return prv(e);
      i32 g = T[prv(e)];
      if (g < 0) break;
      if (g == start) return -1;  // a full turn
      e = g;
    }
    e = start;
    for (;;) {  // clockwise, up to the hull
      i32 g = T[e];
      if (g < 0) return -1;
      e = nxt(g);
      if (V[nxt(e)] == w) return e;
      if (V[prv(e)] == w) return prv(e);
    }
  }

  void mark(i32 e) {
    C[e] = 1;
    if (T[e] >= 0) C[T[e]] = 1;
  }

  // From vertex a towards b: the first edge the segment crosses, as a half-edge on
  // a's side, or (through `on`) the neighbour of a on the segment: b itself when a-b is
  // an edge already. Returns 0 for a crossed edge in *h, 1 for a vertex on it in *on
  // (*h a half-edge of a-on), -1 if nothing fits.
  int first_step(i32 a, i32 b, i32* h, i32* on) const {
    i32 start = vinc[a], e = start;
    const Pt A = pt[a];
    i64 bx = pt[b].x - A.x, by = pt[b].y - A.y;
    auto side = [&](i32 v) { return bx * (pt[v].y - A.y) - by * (pt[v].x - A.x); };  // orient(a, b, v)
    auto ahead = [&](i32 v) { return (pt[v].x - A.x) * bx + (pt[v].y - A.y) * by > 0; };
    // every outgoing half-edge of a, counterclockwise then clockwise from vinc
    for (int pass = 0; pass < 2; ++pass) {
      e = start;
      for (;;) {
        i32 u = V[nxt(e)], w = V[prv(e)];
        if (u == b) { *on = b; *h = e; return 1; }  // most segments: index compares only
        if (w == b) { *on = b; *h = prv(e); return 1; }
        i64 ou = side(u), ow = side(w);
        if (ou == 0 && ahead(u)) { *on = u; *h = e; return 1; }
        if (ow == 0 && ahead(w)) { *on = w; *h = prv(e); return 1; }
        if (ou < 0 && ow > 0) {  // u on the right of a -> b, w on its left
          *h = nxt(e);
          return 0;
        }
        i32 g;
        if (pass == 0) {
          g = T[prv(e)];
          if (g < 0 || g == start) break;
          e = g;
        } else {
          g = T[e];
          if (g < 0) break;
          e = nxt(g);
          if (e == start) break;
        }
      }
      if (pass == 0 && T[prv(e)] >= 0) break;  // a full turn: all seen
    }
    return -1;
  }

  // The sign of incircle(a, b, c, d) under §4.2.5's perturbation, for any four distinct
  // points with orient(a, b, c) != 0 (d on either side of ab): when the exact value is 0,
  // the sign of the term of the first of the four in raster order, whose coefficient is
  // + orient(b, c, d), - orient(a, c, d), + orient(a, b, d) or - orient(a, b, c) for a,
  // b, c or d (the lift's cofactors; nonzero, as three of four cocircular points are
  // never collinear). With d across ab this is illegal()'s rule.
  int incircle_perturbed(i32 a, i32 b, i32 c, i32 d) const {
    int s = incircle(a, b, c, d);
    if (s) return s;
    i32 first = a;
    if (before(b, first)) first = b;
    if (before(c, first)) first = c;
    if (before(d, first)) first = d;
    i64 o = first == a ? orient(b, c, d) : first == b ? -orient(a, c, d)
          : first == c ? orient(a, b, d) : -orient(a, b, c);
    return (o > 0) - (o < 0);
  }

  // constrain's cavity (kept: no allocation per segment): the triangle slots the
  // segment crosses; the polygon on its right (rv: a, ..., end) and on its left (lv:
  // end, ..., a), each with the half-edges along it (re, le: rv[i] -> rv[i + 1]) as the
  // outside's twin and segment mark (rt, rc, lt, lc); jobs for cavity().
  Stack<i32> slots, rv, re, rt, lv, le, lt, jobs;
  Stack<uint8_t> rc, lc;

  // The triangles of the polygon pv[0 .. m] (m >= 2) on the right of pv[0] -> pv[m],
  // whose sides pv[i] -> pv[i + 1] have the outside twins pt_[i] (marks pc[i]), in the
  // slots from slots[*next]; its base pv[m] -> pv[0] is the half-edge returned. Each
  // triangle (pv[hi], pv[lo], pv[c]) takes the c whose circle has no other vertex of
  // pv[lo .. hi] inside under the perturbed rule (Anglada; Shewchuk and Brown, "Fast
  // segment insertion and incremental construction of constrained Delaunay
  // triangulations"): the polygon's own constrained Delaunay triangulation, which is the
  // whole one's there. Jobs on a stack, not recursion: a polygon can be long.
  i32 cavity(const Stack<i32>& pv, const Stack<i32>& pt_, const Stack<uint8_t>& pc, size_t* next) {
    i32 m = (i32)pv.size() - 1, base = -1;
    jobs.clear();
    jobs.push_back(0); jobs.push_back(m); jobs.push_back(-1);  // (lo, hi, half-edge to twin)
    while (!jobs.empty()) {
      i32 up = jobs.back(); jobs.pop_back();
      i32 hi = jobs.back(); jobs.pop_back();
      i32 lo = jobs.back(); jobs.pop_back();
      i32 c = lo + 1;
      for (i32 v = lo + 2; v < hi; ++v)
        if (incircle_perturbed(pv[hi], pv[lo], pv[c], pv[v]) > 0) c = v;
      i32 t = slots[(*next)++], e = 3 * t;
      touch(t);
      V[e] = pv[hi]; V[e + 1] = pv[lo]; V[e + 2] = pv[c];
      vinc[pv[hi]] = e; vinc[pv[lo]] = e + 1; vinc[pv[c]] = e + 2;
      if (up >= 0) link(e, up, 0);
      else base = e;
      // pv[lo] -> pv[c], then pv[c] -> pv[hi]: a side of the polygon, or a smaller one
      if (c == lo + 1) link(e + 1, pt_[lo], pc[lo]);
      else { C[e + 1] = 0; jobs.push_back(lo); jobs.push_back(c); jobs.push_back(e + 1); }
      if (hi == c + 1) link(e + 2, pt_[c], pc[c]);
      else { C[e + 2] = 0; jobs.push_back(c); jobs.push_back(hi); jobs.push_back(e + 2); }
    }
    return base;
  }

  // Make the segment a-b an edge (cutting it at the vertices on it): each piece not yet
  // an edge by taking out the triangles it crosses and triangulating the two polygons
  // on its sides. The triangles no piece crosses stay constrained Delaunay (a segment
  // only hides vertices from them), so no flips follow. A polygon that meets itself (a
  // vertex whose every triangle the piece crosses, joined to the rest by one edge, or a
  // pinch) is no simple polygon: that piece is forced in by flips instead.
  Status constrain(i32 a, i32 b) {
    if (seen.size() != pt.size()) seen.assign(pt.size(), 0);
    while (a != b) {
      i32 h = -1, on = -1;
      int r = first_step(a, b, &h, &on);
      if (r < 0) return CDT_INTERNAL;
      if (r == 1) {
        if (strict && on != b) return CDT_OVER;
        mark(h);
        a = on;
        continue;
      }
      // walk across the triangles the segment enters, to b or a vertex on it: h crosses
      // it from right (V[h]) to left, in the triangle (a, V[h], V[nxt(h)])
      if (stamp == INT32_MAX) { std::fill(seen.begin(), seen.end(), 0); stamp = 0; }
      ++stamp;
      i32 h0 = h, end = -1;
      bool simple = true;
      slots.clear(); rv.clear(); re.clear(); lv.clear(); le.clear();
      slots.push_back(h / 3);
      rv.push_back(a); rv.push_back(V[h]); re.push_back(prv(h));
      lv.push_back(a); lv.push_back(V[nxt(h)]); le.push_back(nxt(h));
      seen[V[h]] = seen[V[nxt(h)]] = stamp;
      for (;;) {
        if (C[h]) return CDT_CROSSING;
        i32 f = T[h];
        if (f < 0) return CDT_INTERNAL;
        slots.push_back(f / 3);
        i32 v = V[prv(f)];
        i64 ov = v == b ? 0 : orient(a, b, v);
        if (ov == 0) {
          if (strict && v != b) return CDT_OVER;
          end = v;
          rv.push_back(v); re.push_back(nxt(f));
          lv.push_back(v); le.push_back(prv(f));
          break;
        }
        if (seen[v] == stamp) simple = false;
        seen[v] = stamp;
        if (ov < 0) { rv.push_back(v); re.push_back(nxt(f)); h = prv(f); }
        else { lv.push_back(v); le.push_back(prv(f)); h = nxt(f); }
      }
      // a long polygon too: cavity() tests each remaining vertex for each triangle,
      // so a fan of k is k^2 / 2 tests (a wall past two columns of 32,000 vertices: 4 s)
      if (!simple || rv.size() > CAVITY_MOST || lv.size() > CAVITY_MOST) {
        Status st = flip_in(a, b, h0, end);
        if (st != CDT_OK) return st;
        a = end;
        continue;
      }
      // the left polygon from end back to a, so that it too lies on its chain's right
      std::reverse(lv.begin(), lv.end());
      std::reverse(le.begin(), le.end());
      if (rv.size() + lv.size() != slots.size() + 4) return CDT_INTERNAL;
      // the outside's twins before the slots are written
      rt.clear(); rc.clear(); lt.clear(); lc.clear();
      for (size_t i = 0; i < re.size(); ++i) { rt.push_back(T[re[i]]); rc.push_back(C[re[i]]); }
      for (size_t i = 0; i < le.size(); ++i) { lt.push_back(T[le[i]]); lc.push_back(C[le[i]]); }
      size_t next = 0;
      i32 right = cavity(rv, rt, rc, &next), left = cavity(lv, lt, lc, &next);
      link(right, left, 1);
      C[left] = 1;
      a = end;
    }
    return CDT_OK;
  }
  //: Longest polygon side of a segment piece that goes in by cavity(); a longer one
  //: goes in by flips (flip_in, whose work grows about linearly on such fans).
  static const size_t CAVITY_MOST = 64;
  std::vector<i32> seen;  // constrain's polygon vertices: stamp when seen
  i32 stamp = 0;
  std::vector<i32> counts;  // canonical()'s, triangles by first corner

  bool crosses(i32 a, i32 b, i32 c, i32 d) const {
    // whether the open segments ab and cd cross (no vertex lies inside either)
    if (c == a || c == b || d == a || d == b) return false;
    i64 o1 = orient(a, b, c), o2 = orient(a, b, d);
    if (!((o1 > 0 && o2 < 0) || (o1 < 0 && o2 > 0))) return false;
    i64 o3 = orient(c, d, a), o4 = orient(c, d, b);
    return (o3 > 0 && o4 < 0) || (o3 < 0 && o4 > 0);
  }

  // flip_in's crossed edges (kept: no allocation per segment): (u, w, a half-edge of
  // u-w when queued, which is still one unless a flip moved the edge to another slot)
  std::vector<i32> queue;

  // The piece a-end of the segment a-b made an edge by flips (Sloan), h the first edge
  // it crosses (first_step's), then Lawson flips around them: the triangulation is
  // constrained Delaunay again.
  Status flip_in(i32 a, i32 b, i32 h, i32 end) {
    queue.clear();
    for (;;) {  // the crossed edges, as constrain's walk found them
      i32 f = T[h];
      i32 u = V[h], w = V[nxt(h)];
      queue.push_back(u);
      queue.push_back(w);
      queue.push_back(h);
      i32 v = V[prv(f)];
      if (v == end) break;
      h = orient(a, b, v) > 0 ? nxt(f) : prv(f);
    }
    // flip each crossing edge whose quadrilateral is strictly convex; a new diagonal
    // that still crosses goes back in the queue
    size_t head = 0;
    // 8 (2k)^2 for k crossed edges, as when an edge took two queue entries (now three)
    i64 crossed = (i64)queue.size() / 3;
    i64 guard = 0, limit = 64 + 32 * crossed * crossed;
    while (head < queue.size()) {
      if (++guard > limit) return CDT_INTERNAL;
      i32 u = queue[head], w = queue[head + 1], e = queue[head + 2];
      head += 3;
      if (!((V[e] == u && V[nxt(e)] == w) || (V[e] == w && V[nxt(e)] == u))) e = find_edge(u, w);
      if (e < 0) return CDT_INTERNAL;
      i32 f = T[e];
      if (f < 0) return CDT_INTERNAL;
      i32 p = V[e], q = V[nxt(e)], c = V[prv(e)], d = V[prv(f)];
      if (orient(p, d, c) > 0 && orient(d, q, c) > 0) {
        flip(e);
        // the edges whose quadrilateral changed, for the Lawson pass (a slot that a
        // later flip refills is pushed again by that flip)
        stack.push_back(e); stack.push_back(nxt(e)); stack.push_back(prv(e));
        stack.push_back(nxt(f)); stack.push_back(prv(f));
        if (crosses(a, end, c, d)) { queue.push_back(d); queue.push_back(c); queue.push_back(e); }
      } else {
        queue.push_back(u);
        queue.push_back(w);
        queue.push_back(e);
      }
      if (head > 4096 && head * 2 > queue.size()) {
        queue.erase(queue.begin(), queue.begin() + head);
        head = 0;
      }
    }
    i32 e = find_edge(a, end);
    if (e < 0) return CDT_INTERNAL;
    mark(e);
    return legalise() ? CDT_OK : CDT_INTERNAL;
  }

  // Incremental use (codec._cdt.Triangulation): the last vertex inserted, where the
  // next point location walk starts; broken after an internal error (a bug), after
  // which insert refuses everything.
  i32 last = 0;
  bool broken = false;

  // insert's checks: the positions of every vertex, and the hull's corners in the
  // order of its edges (made at the first insert; the hull never changes after it)
  Positions positions;
  std::vector<Pt> ring;

  // ring: the hull's edges (those without a twin) followed around, keeping the
  // vertices where it turns
  void hull_ring() {
    std::vector<i32> after(pt.size(), -1);
    i32 start = -1;
    for (i32 e = 0; e < (i32)V.size(); ++e)
      if (T[e] < 0) { after[V[e]] = V[nxt(e)]; start = V[e]; }
    if (start < 0) return;
    std::vector<i32> loop;
    i32 v = start;
    do { loop.push_back(v); v = after[v]; } while (v != start && v >= 0 && loop.size() <= pt.size());
    size_t h = loop.size();
    for (size_t i = 0; i < h; ++i)
      if (orient(loop[(i + h - 1) % h], loop[i], loop[(i + 1) % h]) != 0) ring.push_back(pt[loop[i]]);
  }

  // q inside the hull or on it: on no hull edge's outer side
  bool in_hull(Pt q) const {
    size_t h = ring.size();
    for (size_t i = 0; i < h; ++i) {
      const Pt &a = ring[i], &b = ring[i + 1 == h ? 0 : i + 1];
      if ((i64)(b.x - a.x) * (q.y - a.y) - (i64)(b.y - a.y) * (q.x - a.x) < 0) return false;
    }
    return h > 0;
  }

  // Insert k points (xy, k x 2) inside the hull as vertices pt.size(), pt.size() + 1,
  // ... in their order, with Lawson flips (no segment is flipped): the constrained
  // triangulation of §4.2.5 of all the points. All are checked first (coordinates,
  // inside the hull, no position twice), so that *done counts those before the first
  // refused one (whose status is returned), and only those go in; they go in the order
  // of insertion_order, so that the walks are short whatever order they come in. After
  // CDT_INTERNAL (a bug), *done counts the points that went in, those with vinc set.
  // near (k entries, or null): for each point a vertex near it to start its point
  // location from (refinement knows the triangle each new point falls in), -1 for
  // none; any value is safe (one naming no vertex in the triangulation is ignored).
  // taken (k entries, or null): a point at a position taken (by a vertex, or a point
  // before it) is left out instead of refused, with taken[j] = 1 (0 for the others);
  // those that go in are numbered in their order, and *done counts them.
  Status insert(const i64* xy, i64 k, i64* done, const i64* near = nullptr, uint8_t* taken = nullptr) {
    *done = 0;
    if (taken) std::fill(taken, taken + k, (uint8_t)0);
    if (broken) return CDT_INTERNAL;
    if (V.empty()) return k ? CDT_OUTSIDE : CDT_OK;
    i64 first = (i64)pt.size(), limit = k;
    Status status = CDT_OK;
    auto refuse = [&](i64 j, Status why) {
      if (j < limit) { limit = j; status = why; }
    };
    for (i64 j = 0; j < k; ++j)
      if (xy[2 * j] < 0 || xy[2 * j] > MAX_EXTENT || xy[2 * j + 1] < 0 || xy[2 * j + 1] > MAX_EXTENT) {
        refuse(j, CDT_EXTENT);
        break;
      }
    if (first + limit > MAX_VERTICES) refuse(MAX_VERTICES - first, CDT_MEMORY);
    // in their order: a point at a position taken (by a vertex, or a point before it) or
    // outside the hull is refused, and so are those after it. Checked by a table of the
    // positions and the hull's corners, not by locating each point twice (once before
    // any goes in, once to put it in): the hull does not change, as every point goes in
    // inside it
    if (limit > 0 && ring.empty()) {
      hull_ring();
      for (const Pt& q : pt) positions.add(q);
    }
    i64 left_out = 0;
    for (i64 j = 0; j < limit; ++j) {
      Pt q{(i32)xy[2 * j], (i32)xy[2 * j + 1]};
      if (positions.has(q)) {
        if (taken) { taken[j] = 1; ++left_out; }
        else refuse(j, CDT_DUPLICATE);
      }
      else if (!in_hull(q)) refuse(j, CDT_OUTSIDE);
      else positions.add(q);
    }
    // the near hints of the points that go in, in their order, where some are left out
    std::vector<i64> kept_near;
    for (i64 j = 0; j < limit; ++j) {
      if (taken && taken[j]) continue;
      pt.push_back(Pt{(i32)xy[2 * j], (i32)xy[2 * j + 1]});
      vinc.push_back(-1);
      if (near && left_out) kept_near.push_back(near[j]);
    }
    i64 count = limit - left_out;
    if (near && left_out) near = kept_near.data();
    std::vector<i32> batch((size_t)count);
    for (i64 j = 0; j < count; ++j) batch[j] = (i32)(first + j);
    std::vector<uint64_t> keys = insertion_order(batch);
    Status st = insert_in_order(keys, first + count, near, first);
    if (st != CDT_OK) {
      // a bug: the points that went in (vinc set) are no prefix of the batch, and the
      // others are vertices of no triangle; nothing more is done with this one
      broken = true;
      for (i64 j = first; j < first + count; ++j) *done += vinc[j] >= 0;
      return st;
    }
    *done = count;
    return status;
  }
};

// recycle()'s: from's memory (not its contents) to `to`
template <class A>
inline void keep(A& to, A& from) {
  to = std::move(from);
  to.clear();
}

// Make *cdt a new, empty triangulation that keeps the memory of the arrays that grow
// with the vertices (their capacity, not their contents): an owner that triangulates
// band after band, or file after file (_cdt.Delaunay), touches no fresh pages for them,
// and fresh pages cost a decode more than its flips (each a fault and a zeroed page).
inline void recycle(CDT* cdt) {
  CDT fresh;
  keep(fresh.pt, cdt->pt); keep(fresh.vinc, cdt->vinc);
  keep(fresh.V, cdt->V); keep(fresh.T, cdt->T); keep(fresh.C, cdt->C);
  keep(fresh.fnext, cdt->fnext); keep(fresh.fprev, cdt->fprev); keep(fresh.fedge, cdt->fedge);
  keep(fresh.seen, cdt->seen); keep(fresh.counts, cdt->counts); keep(fresh.queue, cdt->queue);
  keep(fresh.stack, cdt->stack); keep(fresh.slots, cdt->slots); keep(fresh.jobs, cdt->jobs);
  keep(fresh.rv, cdt->rv); keep(fresh.re, cdt->re); keep(fresh.rt, cdt->rt); keep(fresh.rc, cdt->rc);
  keep(fresh.lv, cdt->lv); keep(fresh.le, cdt->le); keep(fresh.lt, cdt->lt); keep(fresh.lc, cdt->lc);
  *cdt = std::move(fresh);
}

// The triangles of `cdt` in canonical order into out (3 per triangle, room for
// cdt.V.size() values; vertex i of cdt is order[i], or i itself when order is null):
// each rotated to start at its smallest index, placed by a counting sort on that index,
// then each run of one first index (a fan of a few) sorted by insertion on the other two.
// Returns the CRC-32 of the list as ATM.md's u32 little-endian values (the decoder
// then makes no u32 copy of it for zlib).
inline uint32_t canonical(CDT& cdt, const i64* order, i64* out) {
  i64 n = (i64)cdt.pt.size(), m = (i64)cdt.V.size() / 3;
  std::vector<i32>& start = cdt.counts;  // (m < 2^31: MAX_VERTICES)
  start.assign(n + 1, 0);
  const i32* V = cdt.V.data();
  for (i64 t = 0; t < m; ++t) {
    i64 a = V[3 * t], b = V[3 * t + 1], c = V[3 * t + 2];
    if (order) { a = order[a]; b = order[b]; c = order[c]; }
    ++start[std::min(a, std::min(b, c)) + 1];
  }
  for (i64 i = 0; i < n; ++i) start[i + 1] += start[i];
  for (i64 t = 0; t < m; ++t) {
    i64 a = V[3 * t], b = V[3 * t + 1], c = V[3 * t + 2];
    if (order) { a = order[a]; b = order[b]; c = order[c]; }
    if (b < a && b < c) { i64 r = a; a = b; b = c; c = r; }
    else if (c < a && c < b) { i64 r = c; c = b; b = a; a = r; }
    i64* o = out + 3 * (i64)start[a]++;
    o[0] = a; o[1] = b; o[2] = c;
  }
  // start[a] is now the end of a's run, which begins where a - 1's ends
  for (i64 a = 0, begin = 0; a < n; begin = start[a++]) {
    for (i64 j = begin + 1; j < start[a]; ++j) {
      i64 b = out[3 * j + 1], c = out[3 * j + 2], k = j;
      for (; k > begin && (out[3 * k - 2] > b || (out[3 * k - 2] == b && out[3 * k - 1] > c)); --k) {
        out[3 * k + 1] = out[3 * k - 2];
        out[3 * k + 2] = out[3 * k - 1];
      }
      out[3 * k + 1] = b; out[3 * k + 2] = c;
    }
  }
  return atmcrc::crc32_low_halves(out, 3 * (size_t)m);
}

// The constrained Delaunay triangulation of ATM.md §4.2.5 of n vertices (xy, n x 2)
// with s segments (seg, s x 2 vertex indices; with `strict`, one passing over a vertex
// is refused, otherwise cut there), into *cdt (empty before). Its vertices are the
// input's in raster order: vertex i of cdt is input vertex (*order)[i], or i itself when
// *order is left empty (the input was in raster order). canonical(*cdt, order or null,
// out) then writes the triangles of §4.2.3's canonical list.
inline Status triangulate(i64 n, const i64* xy, i64 s, const i64* seg, bool strict,
                          CDT* cdt, std::vector<i64>* order, i64* flips) {
  try {
    order->clear();
    if (n == 0) return CDT_OK;
    if (n > MAX_VERTICES) return CDT_MEMORY;
    i64 xmin = xy[0], xmax = xy[0], ymin = xy[1], ymax = xy[1];
    for (i64 i = 1; i < n; ++i) {
      xmin = std::min(xmin, xy[2 * i]); xmax = std::max(xmax, xy[2 * i]);
      ymin = std::min(ymin, xy[2 * i + 1]); ymax = std::max(ymax, xy[2 * i + 1]);
    }
    if (xmax - xmin > MAX_EXTENT || ymax - ymin > MAX_EXTENT) return CDT_EXTENT;
    for (i64 j = 0; j < 2 * s; ++j)
      if (seg[j] < 0 || seg[j] >= n) return CDT_INDEX;
    // raster order: (y, x), relative to the minimum (predicates are unchanged by it);
    // a decoder's vertices come in it already (ATM.md §4.2.2), so no sort and no map
    auto key = [&](i64 i) { return (xy[2 * i + 1] - ymin) * (xmax - xmin + 1) + (xy[2 * i] - xmin); };
    bool sorted = true;
    for (i64 i = 1; i < n && sorted; ++i) sorted = key(i - 1) < key(i);
    std::vector<i32> rank;
    if (!sorted) {
      std::vector<i64> keys(n);
      for (i64 i = 0; i < n; ++i) keys[i] = key(i);
      order->resize(n);
      for (i64 i = 0; i < n; ++i) (*order)[i] = i;
      std::sort(order->begin(), order->end(), [&](i64 a, i64 b) { return keys[a] < keys[b]; });
      for (i64 i = 1; i < n; ++i)
        if (keys[(*order)[i - 1]] == keys[(*order)[i]]) return CDT_DUPLICATE;
      rank.resize(n);
      for (i64 i = 0; i < n; ++i) rank[(*order)[i]] = (i32)i;
    }
    auto at = [&](i64 i) { return sorted ? i : (*order)[i]; };    // cdt vertex -> input
    auto index = [&](i64 i) { return sorted ? (i32)i : rank[i]; };  // input -> cdt vertex
    cdt->strict = strict;
    cdt->narrow = xmax - xmin < (i64(1) << 14) && ymax - ymin < (i64(1) << 14);
    cdt->pt.resize(n);
    for (i64 i = 0; i < n; ++i) {
      cdt->pt[i].x = (i32)(xy[2 * at(i)] - xmin);
      cdt->pt[i].y = (i32)(xy[2 * at(i) + 1] - ymin);
    }
    Status st = cdt->build();
    if (st != CDT_OK) return st;
    if (cdt->V.empty() && strict) {
      // all on one line, in raster order along it: a segment over no vertex joins
      // neighbours in that order
      for (i64 j = 0; j < s; ++j) {
        i64 gap = (i64)index(seg[2 * j]) - (i64)index(seg[2 * j + 1]);
        if (gap > 1 || gap < -1) return CDT_OVER;
      }
    }
    if (!cdt->V.empty() && s > 0) {
      for (i64 j = 0; j < s; ++j) {
        i32 a = index(seg[2 * j]), b = index(seg[2 * j + 1]);
        if (a == b) continue;
        st = cdt->constrain(a, b);
        if (st != CDT_OK) return st;
      }
    }
    *flips = cdt->flips;
    return CDT_OK;
  } catch (const std::bad_alloc&) {
    return CDT_MEMORY;
  }
}

}  // namespace
}  // namespace atmcdt

#endif
