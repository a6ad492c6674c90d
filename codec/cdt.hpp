// The constrained Delaunay triangulation of format version 6 (format_spec/ATM.md
// §4.2.5), built directly: a sweep in raster order with Lawson flips after each
// insertion, then every segment forced in by flips (Sloan's method), then Lawson flips
// with the perturbed rule until every free edge is locally Delaunay. The result is the
// unique triangulation of §4.2.5 whatever the construction, so it equals Triangle
// followed by codec/canonical.py's flip pass. Plain C++ without the Python API, so that
// the Cython wrapper (codec/_cdt.pyx) runs it with the GIL released.
#ifndef ATM_CDT_HPP
#define ATM_CDT_HPP

#include <algorithm>
#include <cstdint>
#include <new>
#include <vector>

namespace atmcdt {

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
};

//: Largest coordinate extent accepted: differences below 2^28 keep incircle's products
//: below 2^114, exact in 128-bit integers (ATM.md §8 needs only 2^20).
const i64 MAX_EXTENT = (i64(1) << 28) - 1;

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

inline i32 nxt(i32 e) { return e % 3 == 2 ? e - 2 : e + 1; }
inline i32 prv(i32 e) { return e % 3 == 0 ? e + 2 : e - 1; }

class CDT {
 public:
  // vertices in raster order (y, then x): the index is the priority of §4.2.5
  std::vector<i64> x, y;
  std::vector<i32> V;     // start vertex of each half-edge; triangle t is 3t..3t+2
  std::vector<i32> T;     // the twin half-edge, -1 on the hull
  std::vector<uint8_t> C; // whether the edge is a segment
  std::vector<i32> vinc;  // one outgoing half-edge of each vertex (-1 before it has one)
  std::vector<i32> hnext, hprev, hedge;  // the hull during the sweep, counterclockwise
  std::vector<i32> stack;
  i64 flips = 0;

  i64 orient(i32 a, i32 b, i32 c) const {
    return (x[b] - x[a]) * (y[c] - y[a]) - (y[b] - y[a]) * (x[c] - x[a]);
  }

  // The exact sign of incircle(a, b, c, d) (ATM.md §4.2.5).
  int incircle(i32 a, i32 b, i32 c, i32 d) const {
    i64 adx = x[a] - x[d], ady = y[a] - y[d];
    i64 bdx = x[b] - x[d], bdy = y[b] - y[d];
    i64 cdx = x[c] - x[d], cdy = y[c] - y[d];
    i64 m = std::max(std::max(std::max(adx < 0 ? -adx : adx, ady < 0 ? -ady : ady),
                              std::max(bdx < 0 ? -bdx : bdx, bdy < 0 ? -bdy : bdy)),
                     std::max(cdx < 0 ? -cdx : cdx, cdy < 0 ? -cdy : cdy));
    if (m < (i64(1) << 14)) {
      // differences below 2^14: lifts and minors below 2^29, products below 2^58,
      // their sum below 2^60: exact in int64
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
  bool illegal(i32 e) const {
    i32 f = T[e];
    i32 a = V[e], b = V[nxt(e)], c = V[prv(e)], d = V[prv(f)];
    int s = incircle(a, b, c, d);
    return s > 0 || (s == 0 && std::min(a, b) < std::min(c, d));
  }

  i32 add_triangle(i32 a, i32 b, i32 c) {
    i32 t = (i32)V.size();
    V.push_back(a); V.push_back(b); V.push_back(c);
    T.push_back(-1); T.push_back(-1); T.push_back(-1);
    C.push_back(0); C.push_back(0); C.push_back(0);
    vinc[a] = t; vinc[b] = t + 1; vinc[c] = t + 2;
    return t;
  }

  void link(i32 s, i32 t, uint8_t c) {
    T[s] = t;
    C[s] = c;
    if (t >= 0) T[t] = s;
    else hedge[V[s]] = s;  // a hull edge moved to another slot
  }

  // Replace edge ab of (a, b, c) and (b, a, d) by cd: (d, c, a) in e's triangle and
  // (c, d, b) in its twin's, e and its twin the new edge dc / cd.
  void flip(i32 e) {
    i32 f = T[e], e1 = nxt(e), e2 = prv(e), f1 = nxt(f), f2 = prv(f);
    i32 a = V[e], b = V[f], c = V[e2], d = V[f2];
    i32 te1 = T[e1], te2 = T[e2], tf1 = T[f1], tf2 = T[f2];
    uint8_t ce1 = C[e1], ce2 = C[e2], cf1 = C[f1], cf2 = C[f2];
    V[e] = d; V[e1] = c; V[e2] = a;
    V[f] = c; V[f1] = d; V[f2] = b;
    link(e1, te2, ce2);
    link(e2, tf1, cf1);
    link(f1, tf2, cf2);
    link(f2, te1, ce1);
    T[e] = f; T[f] = e; C[e] = C[f] = 0;
    vinc[a] = e2; vinc[b] = f2; vinc[c] = e1; vinc[d] = e;
    ++flips;
  }

  // Lawson flips until no half-edge on the stack (or moved by a flip) is illegal.
  void legalise() {
    while (!stack.empty()) {
      i32 e = stack.back();
      stack.pop_back();
      if (T[e] < 0 || C[e] || !illegal(e)) continue;
      i32 f = T[e];
      flip(e);
      stack.push_back(nxt(e)); stack.push_back(prv(e));
      stack.push_back(nxt(f)); stack.push_back(prv(f));
    }
  }

  void push_all() {
    for (i32 e = 0; e < (i32)V.size(); ++e)
      if (T[e] > e && !C[e]) stack.push_back(e);
  }

  // The Delaunay triangulation of the vertices (already in raster order, distinct).
  Status sweep() {
    i32 n = (i32)x.size();
    vinc.assign(n, -1);
    hnext.assign(n, -1); hprev.assign(n, -1); hedge.assign(n, -1);
    V.reserve(6 * (size_t)n); T.reserve(6 * (size_t)n); C.reserve(6 * (size_t)n);
    if (n < 3) return CDT_OK;
    i32 k = 2;
    while (k < n && orient(0, 1, k) == 0) ++k;
    if (k == n) return CDT_OK;  // all on one line: no triangles
    // the first k points lie on a line in order; point k sees all of them
    if (orient(0, 1, k) > 0) {
      for (i32 j = 0; j + 1 < k; ++j) {
        i32 t = add_triangle(j, j + 1, k);
        if (j) { T[t + 2] = t - 2; T[t - 2] = t + 2; }  // k-j with triangle j-1's j-k
        hnext[j] = j + 1; hprev[j + 1] = j; hedge[j] = t;
      }
      hnext[k - 1] = k; hprev[k] = k - 1; hedge[k - 1] = 3 * (k - 2) + 1;
      hnext[k] = 0; hprev[0] = k; hedge[k] = 2;
    } else {
      for (i32 j = 0; j + 1 < k; ++j) {
        i32 t = add_triangle(j + 1, j, k);
        if (j) { T[t + 1] = t - 1; T[t - 1] = t + 1; }  // j-k with triangle j-1's k-j
        hnext[j + 1] = j; hprev[j] = j + 1; hedge[j + 1] = t;
      }
      hnext[0] = k; hprev[k] = 0; hedge[0] = 1;
      hnext[k] = k - 1; hprev[k - 1] = k; hedge[k] = 3 * (k - 2) + 2;
    }
    push_all();
    legalise();
    for (i32 p = k + 1; p < n; ++p) {
      // the last point is the raster-order maximum so far, a hull vertex, and p sees it
      // (the hull lies before it in raster order, the segment to p after): the edges p
      // sees are a run of the hull through it
      i32 q = p - 1, s = q, t = q;
      while (orient(t, hnext[t], p) < 0) t = hnext[t];
      while (orient(hprev[s], s, p) < 0) s = hprev[s];
      if (s == t) return CDT_INTERNAL;
      i32 first = -1, last = -1;
      for (i32 u = s; u != t;) {
        i32 w = hnext[u], he = hedge[u];
        i32 tri = add_triangle(u, p, w);  // u-p, p-w, w-u
        T[tri + 2] = he; T[he] = tri + 2;
        if (last >= 0) { T[tri] = last + 1; T[last + 1] = tri; }
        else first = tri;
        stack.push_back(tri + 2);
        stack.push_back(tri);
        last = tri;
        u = w;
      }
      hnext[s] = p; hprev[p] = s; hnext[p] = t; hprev[t] = p;
      hedge[s] = first; hedge[p] = last + 1;
      legalise();
    }
    return CDT_OK;
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

  bool crosses(i32 a, i32 b, i32 c, i32 d) const {
    // whether the open segments ab and cd cross (no vertex lies inside either)
    if (c == a || c == b || d == a || d == b) return false;
    i64 o1 = orient(a, b, c), o2 = orient(a, b, d);
    if (!((o1 > 0 && o2 < 0) || (o1 < 0 && o2 > 0))) return false;
    i64 o3 = orient(c, d, a), o4 = orient(c, d, b);
    return (o3 > 0 && o4 < 0) || (o3 < 0 && o4 > 0);
  }

  // From vertex a towards b: the first edge the segment crosses, as a half-edge on
  // a's side, or (through `on`) the neighbour of a on the segment, or an existing edge.
  // Returns 0 for a crossed edge in *h, 1 for a vertex on it in *on (*h the edge a-on
  // as a half-edge, or -1), -1 if nothing fits.
  int first_step(i32 a, i32 b, i32* h, i32* on) const {
    i32 start = vinc[a], e = start;
    i64 bx = x[b] - x[a], by = y[b] - y[a];
    // every outgoing half-edge of a, counterclockwise then clockwise from vinc
    for (int pass = 0; pass < 2; ++pass) {
      e = start;
      for (;;) {
        i32 u = V[nxt(e)], w = V[prv(e)];
        for (int side = 0; side < 2; ++side) {
          i32 v = side ? w : u;
          i64 o = orient(a, b, v);
          if (o == 0 && (x[v] - x[a]) * bx + (y[v] - y[a]) * by > 0) {
            *on = v;
            *h = side ? prv(e) : e;
            return 1;
          }
        }
        if (orient(a, u, b) > 0 && orient(a, b, w) > 0) {
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

  // Make the segment a-b an edge (cutting it at the vertices on it).
  Status constrain(i32 a, i32 b) {
    std::vector<i32> queue;
    while (a != b) {
      i32 h = -1, on = -1;
      int r = first_step(a, b, &h, &on);
      if (r < 0) return CDT_INTERNAL;
      if (r == 1) {
        mark(h);
        a = on;
        continue;
      }
      // walk across the triangles the segment enters, to b or a vertex on it
      queue.clear();
      i32 end = -1;
      for (;;) {
        if (C[h]) return CDT_CROSSING;
        i32 f = T[h];
        if (f < 0) return CDT_INTERNAL;
        i32 u = V[h], w = V[nxt(h)];
        queue.push_back(u);
        queue.push_back(w);
        i32 v = V[prv(f)];
        if (v == b) { end = b; break; }
        i64 ov = orient(a, b, v);
        if (ov == 0) { end = v; break; }
        i64 ou = orient(a, b, u);
        // triangle f is w-u, u-v, v-w: leave through the side whose ends differ
        h = ((ov > 0) == (ou > 0)) ? prv(f) : nxt(f);
      }
      // Sloan: flip each crossing edge whose quadrilateral is strictly convex; a new
      // diagonal that still crosses goes back in the queue
      size_t head = 0;
      i64 guard = 0, limit = 64 + 8 * (i64)queue.size() * (i64)queue.size();
      while (head < queue.size()) {
        if (++guard > limit) return CDT_INTERNAL;
        i32 u = queue[head], w = queue[head + 1];
        head += 2;
        i32 e = find_edge(u, w);
        if (e < 0) return CDT_INTERNAL;
        i32 f = T[e];
        if (f < 0) return CDT_INTERNAL;
        i32 p = V[e], q = V[nxt(e)], c = V[prv(e)], d = V[prv(f)];
        if (orient(p, d, c) > 0 && orient(d, q, c) > 0) {
          flip(e);
          if (crosses(a, end, c, d)) { queue.push_back(d); queue.push_back(c); }
        } else {
          queue.push_back(u);
          queue.push_back(w);
        }
        if (head > 4096 && head * 2 > queue.size()) {
          queue.erase(queue.begin(), queue.begin() + head);
          head = 0;
        }
      }
      i32 e = find_edge(a, end);
      if (e < 0) return CDT_INTERNAL;
      mark(e);
      a = end;
    }
    return CDT_OK;
  }
};

// Triangulate n vertices (xy, n x 2) with s segments (seg, s x 2 vertex indices):
// the triangles of ATM.md §4.2.5 in canonical order (§4.2.3: each rotated to start at
// its smallest index, rows sorted) into *out (3 per triangle).
inline Status triangulate(i64 n, const i64* xy, i64 s, const i64* seg,
                          std::vector<i64>* out, i64* flips) {
  try {
    out->clear();
    std::vector<i64> order(n);
    for (i64 i = 0; i < n; ++i) order[i] = i;
    if (n == 0) return CDT_OK;
    i64 xmin = xy[0], xmax = xy[0], ymin = xy[1], ymax = xy[1];
    for (i64 i = 1; i < n; ++i) {
      xmin = std::min(xmin, xy[2 * i]); xmax = std::max(xmax, xy[2 * i]);
      ymin = std::min(ymin, xy[2 * i + 1]); ymax = std::max(ymax, xy[2 * i + 1]);
    }
    if (xmax - xmin > MAX_EXTENT || ymax - ymin > MAX_EXTENT) return CDT_EXTENT;
    for (i64 j = 0; j < 2 * s; ++j)
      if (seg[j] < 0 || seg[j] >= n) return CDT_INDEX;
    // raster order: (y, x), relative to the minimum (predicates are unchanged by it)
    i64 w = xmax - xmin + 1;
    std::vector<i64> key(n);
    for (i64 i = 0; i < n; ++i) key[i] = (xy[2 * i + 1] - ymin) * w + (xy[2 * i] - xmin);
    bool sorted = true;
    for (i64 i = 1; i < n && sorted; ++i) sorted = key[i - 1] < key[i];
    if (!sorted) {
      std::sort(order.begin(), order.end(), [&](i64 a, i64 b) { return key[a] < key[b]; });
      for (i64 i = 1; i < n; ++i)
        if (key[order[i - 1]] == key[order[i]]) return CDT_DUPLICATE;
    }
    CDT cdt;
    cdt.x.resize(n); cdt.y.resize(n);
    std::vector<i32> rank(n);
    for (i64 i = 0; i < n; ++i) {
      cdt.x[i] = xy[2 * order[i]] - xmin;
      cdt.y[i] = xy[2 * order[i] + 1] - ymin;
      rank[order[i]] = (i32)i;
    }
    Status st = cdt.sweep();
    if (st != CDT_OK) return st;
    if (!cdt.V.empty() && s > 0) {
      i64 before = cdt.flips;
      for (i64 j = 0; j < s; ++j) {
        i32 a = rank[seg[2 * j]], b = rank[seg[2 * j + 1]];
        if (a == b) continue;
        st = cdt.constrain(a, b);
        if (st != CDT_OK) return st;
      }
      if (cdt.flips != before) {
        cdt.push_all();
        cdt.legalise();
      }
    }
    *flips = cdt.flips;
    // canonical order, in the caller's vertex numbers
    i64 m = (i64)cdt.V.size() / 3;
    out->resize(3 * m);
    std::vector<i64> tri(3 * m);
    for (i64 t = 0; t < m; ++t) {
      i64 a = order[cdt.V[3 * t]], b = order[cdt.V[3 * t + 1]], c = order[cdt.V[3 * t + 2]];
      if (b < a && b < c) { i64 r = a; a = b; b = c; c = r; }
      else if (c < a && c < b) { i64 r = c; c = b; b = a; a = r; }
      tri[3 * t] = a; tri[3 * t + 1] = b; tri[3 * t + 2] = c;
    }
    std::vector<i64> idx(m);
    for (i64 t = 0; t < m; ++t) idx[t] = t;
    std::sort(idx.begin(), idx.end(), [&](i64 p, i64 q) {
      const i64* u = &tri[3 * p];
      const i64* v = &tri[3 * q];
      if (u[0] != v[0]) return u[0] < v[0];
      if (u[1] != v[1]) return u[1] < v[1];
      return u[2] < v[2];
    });
    for (i64 t = 0; t < m; ++t)
      for (int j = 0; j < 3; ++j) (*out)[3 * t + j] = tri[3 * idx[t] + j];
    return CDT_OK;
  } catch (const std::bad_alloc&) {
    return CDT_MEMORY;
  }
}

}  // namespace atmcdt

#endif
