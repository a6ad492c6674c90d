// CRC-32 (zlib's crc32) of int64 values taken as u32 little-endian bytes, their low
// halves: the checksum of ATM.md's triangle list, which codec/cdt.hpp's canonical()
// computes over the triangles it has just written, so that the decoder makes no u32
// copy of them for zlib. On x86-64 with PCLMULQDQ, 16 values (64 bytes) a step by
// carry-less multiplication (Gopal et al., "Fast CRC Computation for Generic Polynomials
// Using PCLMULQDQ Instruction", Intel, 2009: folding by x^512 and x^128, then a Barrett
// reduction); elsewhere by tables, 8 bytes a step. Either gives zlib's value.
#ifndef ATM_CRC32_HPP
#define ATM_CRC32_HPP

#include <cstddef>
#include <cstdint>

#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))
#define ATM_CRC32_CLMUL 1
#include <immintrin.h>
#endif

namespace atmcrc {
namespace {

// The reflected polynomial 0xEDB88320's tables: t[0] one byte a step, t[k] the byte
// k places further on (slicing by 8). Built once, then only read.
struct Tables {
  uint32_t t[8][256];
  Tables() {
    for (uint32_t i = 0; i < 256; ++i) {
      uint32_t c = i;
      for (int k = 0; k < 8; ++k) c = (c >> 1) ^ (0xEDB88320u & (0u - (c & 1)));
      t[0][i] = c;
    }
    for (int k = 1; k < 8; ++k)
      for (uint32_t i = 0; i < 256; ++i) t[k][i] = (t[k - 1][i] >> 8) ^ t[0][t[k - 1][i] & 0xFF];
  }
};

inline const Tables& tables() {
  static const Tables once;  // (initialised once, thread-safe since C++11)
  return once;
}

#ifdef ATM_CRC32_CLMUL
inline bool have_clmul() {
  static const bool has = __builtin_cpu_supports("pclmul");
  return has;
}

// Both 64-bit halves of x times their constants in k (low by low, high by high),
// added: x moved forward by the distance k stands for.
__attribute__((target("pclmul"))) inline __m128i fold(__m128i x, __m128i k) {
  return _mm_xor_si128(_mm_clmulepi64_si128(x, k, 0x00), _mm_clmulepi64_si128(x, k, 0x11));
}

// The low halves of p[0 .. 3] as 16 bytes (x86-64 is little-endian).
inline __m128i low4(const int64_t* p) {
  __m128 a = _mm_loadu_ps((const float*)p), b = _mm_loadu_ps((const float*)(p + 2));
  return _mm_castps_si128(_mm_shuffle_ps(a, b, _MM_SHUFFLE(2, 0, 2, 0)));
}

// The register (the running CRC, inverted) after 16 * blocks values (blocks >= 1).
__attribute__((target("pclmul"))) inline uint32_t clmul_blocks(const int64_t* p, size_t blocks, uint32_t reg) {
  __m128i x0 = _mm_xor_si128(low4(p), _mm_cvtsi32_si128((int)reg));
  __m128i x1 = low4(p + 4), x2 = low4(p + 8), x3 = low4(p + 12);
  // x^(512 + 32) and x^(512 - 32) mod P, bit-reflected (Gopal et al.'s k1, k2)
  const __m128i k12 = _mm_set_epi64x(0x01c6e41596LL, 0x0154442bd4LL);
  for (size_t b = 1; b < blocks; ++b) {
    p += 16;
    x0 = _mm_xor_si128(fold(x0, k12), low4(p));
    x1 = _mm_xor_si128(fold(x1, k12), low4(p + 4));
    x2 = _mm_xor_si128(fold(x2, k12), low4(p + 8));
    x3 = _mm_xor_si128(fold(x3, k12), low4(p + 12));
  }
  // the four lanes into one by x^(128 + 32) and x^(128 - 32) mod P (k3, k4)
  const __m128i k34 = _mm_set_epi64x(0x00ccaa009eLL, 0x01751997d0LL);
  __m128i x = _mm_xor_si128(fold(x0, k34), x1);
  x = _mm_xor_si128(fold(x, k34), x2);
  x = _mm_xor_si128(fold(x, k34), x3);
  // 128 bits to 64 (by k4), then to 32 bits' worth by x^64 mod P (k5)
  const __m128i low32 = _mm_setr_epi32(-1, 0, -1, 0);
  x = _mm_xor_si128(_mm_srli_si128(x, 8), _mm_clmulepi64_si128(x, k34, 0x10));
  const __m128i k5 = _mm_set_epi64x(0, 0x0163cd6124LL);
  x = _mm_xor_si128(_mm_clmulepi64_si128(_mm_and_si128(x, low32), k5, 0x00), _mm_srli_si128(x, 4));
  // Barrett reduction by P (0x1db710641) with mu = x^64 / P (0x1f7011641)
  const __m128i poly = _mm_set_epi64x(0x01f7011641LL, 0x01db710641LL);
  __m128i q = _mm_clmulepi64_si128(_mm_and_si128(x, low32), poly, 0x10);
  q = _mm_clmulepi64_si128(_mm_and_si128(q, low32), poly, 0x00);
  x = _mm_xor_si128(x, q);
  return (uint32_t)_mm_cvtsi128_si32(_mm_srli_si128(x, 4));
}
#endif

// zlib.crc32 of the n values p[i] & 0xFFFFFFFF as u32 little-endian bytes.
inline uint32_t crc32_low_halves(const int64_t* p, size_t n) {
  uint32_t reg = 0xFFFFFFFFu;
  size_t i = 0;
#ifdef ATM_CRC32_CLMUL
  if (n >= 16 && have_clmul()) {
    reg = clmul_blocks(p, n / 16, reg);
    i = n / 16 * 16;
  }
#endif
  const uint32_t(*t)[256] = tables().t;
  for (; i + 2 <= n; i += 2) {
    uint32_t a = reg ^ (uint32_t)p[i], b = (uint32_t)p[i + 1];
    reg = t[7][a & 0xFF] ^ t[6][(a >> 8) & 0xFF] ^ t[5][(a >> 16) & 0xFF] ^ t[4][a >> 24] ^
          t[3][b & 0xFF] ^ t[2][(b >> 8) & 0xFF] ^ t[1][(b >> 16) & 0xFF] ^ t[0][b >> 24];
  }
  if (i < n) {
    uint32_t a = reg ^ (uint32_t)p[i];
    reg = t[3][a & 0xFF] ^ t[2][(a >> 8) & 0xFF] ^ t[1][(a >> 16) & 0xFF] ^ t[0][a >> 24];
  }
  return ~reg;
}

}  // namespace
}  // namespace atmcrc

#endif
