// ATM_INLINE: a function the compiler must inline, for the kernels' small helpers that
// -O2's inlining limits leave as calls in a large translation unit (cdt.hpp's
// predicates, _elements' row walk). Plain preprocessor, for C and C++ alike; a C file
// writes `static ATM_INLINE`.
#ifndef ATM_INLINE_HPP
#define ATM_INLINE_HPP
#if defined(__GNUC__) || defined(__clang__)
#define ATM_INLINE __attribute__((always_inline)) inline
#elif defined(_MSC_VER)
#define ATM_INLINE __forceinline
#else
#define ATM_INLINE inline
#endif
#endif
