// CPU kernels for the play bank, registered with JAX through the XLA FFI.
//
// One play step is the clamp x_t = max(u_t - r, min(u_t + r, x_{t-1})), evaluated with exactly the
// operations of the pure-JAX scan, so the play outputs agree with it to the last bit. The plays of a
// bank are independent lanes: the inner loops run across plays over contiguous arrays padded to a
// multiple of the vector width, which the compiler turns into SIMD code without branches.
//
// The fused PI output y_t = sum_j w_j x_{t,j} is summed in a fixed order (lane-wise partial sums
// over the vectors of a chunk of plays, then a tree over the lanes, then chunk after chunk), so a
// build gives the same bits on every call. On x86 the lane sums of W consecutive steps are taken
// together by a transpose (horizontal adds with AVX, unpacks with SSE2) instead of one scalar tree
// per step.
//
// Backward pass. Each step of the differentiated forward pass records one bit per play: whether a
// bound moved the state (see CodeBytes for why the direction need not be stored). At a tie (the old
// state equal to a bound) the step counts as held. The adjoint is a reverse recurrence: nu_j
// accumulates the output cotangents of play j over the current run of held steps; at an active
// step it flows to u_t (and with sign +1 on the upper, -1 on the lower bound to r_j) and resets;
// what is left at t = 0 flows to the initial state. On x86 it runs in blocks of W steps: first the
// recurrence over the block (which gives du), then the block's terms of the threshold and weight
// sums, so that neither loop needs more vector registers than there are.
//
// Large outputs are advised onto transparent huge pages before they are written (AdviseHugePages).
//
// Every buffer may carry leading batch dimensions (from vmap); they are flattened into B signals
// and split across threads.

#include <Python.h>

#if defined(__AVX__) || defined(__SSE2__)
#include <immintrin.h>
#endif

#include <algorithm>
#include <atomic>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <functional>
#include <thread>
#include <type_traits>
#include <vector>

#if defined(__linux__)
#include <sys/mman.h>
#endif

#include "xla/ffi/api/ffi.h"

namespace ffi = xla::ffi;

namespace {

// The forward pass runs a chunk of up to kChunk vectors of plays through the whole signal at once,
// with the chunk's states in registers; the backward pass, which keeps three accumulators per
// vector, chunks of up to kChunkBwd.
constexpr int kChunk = 8;
constexpr int kChunkBwd = 4;

// Explicit SIMD through GCC/Clang vector extensions, as wide as the target's registers: 32 bytes
// with AVX, 16 otherwise (SSE2, which every x86-64 CPU has, or NEON). Wider vectors on a target
// without the registers would be split into pairs and passed through memory between functions.
#if defined(__AVX__)
constexpr int kVecBytes = 32;
#else
constexpr int kVecBytes = 16;
#endif
template <typename T>
struct Vec;
template <>
struct Vec<float> {
  typedef float type __attribute__((vector_size(kVecBytes)));
  typedef int32_t mask __attribute__((vector_size(kVecBytes)));
  typedef int32_t lane;
  static constexpr int kWidth = kVecBytes / 4;
};
template <>
struct Vec<double> {
  typedef double type __attribute__((vector_size(kVecBytes)));
  typedef int64_t mask __attribute__((vector_size(kVecBytes)));
  typedef int64_t lane;
  static constexpr int kWidth = kVecBytes / 8;
};

// Play lanes are padded to a multiple of the vector width.
template <typename T>
int64_t Padded(int64_t n) {
  constexpr int64_t W = Vec<T>::kWidth;
  return (n + W - 1) / W * W;
}

// Copies the first `count` (1 <= count <= kWidth) lanes between a vector and memory. Rows of H and
// of its cotangent are n lanes long, so the last vector of a row is usually partial; a switch on
// the (loop-invariant, so well predicted) count gives fixed-size copies instead of a memcpy call.
template <typename T>
inline void StoreLanes(T* dst, const typename Vec<T>::type& v, int64_t count) {
  switch (count) {
#define PIEST_CASE(K) \
  case K:             \
    std::memcpy(dst, &v, K * sizeof(T)); \
    break;
    PIEST_CASE(1) PIEST_CASE(2) PIEST_CASE(3) PIEST_CASE(4)
    PIEST_CASE(5) PIEST_CASE(6) PIEST_CASE(7) PIEST_CASE(8)
#undef PIEST_CASE
    default: break;
  }
}
template <typename T>
inline void LoadLanes(typename Vec<T>::type& v, const T* src, int64_t count) {
  switch (count) {
#define PIEST_CASE(K) \
  case K:             \
    std::memcpy(&v, src, K * sizeof(T)); \
    break;
    PIEST_CASE(1) PIEST_CASE(2) PIEST_CASE(3) PIEST_CASE(4)
    PIEST_CASE(5) PIEST_CASE(6) PIEST_CASE(7) PIEST_CASE(8)
#undef PIEST_CASE
    default: break;
  }
}

// Branch codes: one bit per play and step, set when a bound moved the state (x_t != x_{t-1}), one
// byte per vector of plays (its low kWidth bits). At a tie (the old state equal to a bound) the
// step counts as held. Which bound moved it need not be stored: a play can only be pushed down by
// its upper bound when the input falls (u_t + r < x_{t-1} <= u_{t-1} + r, and rounding is
// monotonic) and up by its lower bound when it rises, so for t >= 1 the sign of u_t - u_{t-1} tells;
// at t = 0 the backward pass compares x0 with u_0 + r itself.
template <typename T>
int64_t CodeBytes(int64_t np) {
  return np / Vec<T>::kWidth;
}

// Lane mask (all ones or zero per lane) -> one bit per lane.
template <typename T>
inline uint8_t ToBits(typename Vec<T>::mask m) {
#if defined(__AVX__)
  if constexpr (sizeof(T) == 4) {
    return static_cast<uint8_t>(_mm256_movemask_ps(reinterpret_cast<__m256>(m)));
  } else {
    return static_cast<uint8_t>(_mm256_movemask_pd(reinterpret_cast<__m256d>(m)));
  }
#elif defined(__SSE2__)
  if constexpr (sizeof(T) == 4) {
    return static_cast<uint8_t>(_mm_movemask_ps(reinterpret_cast<__m128>(m)));
  } else {
    return static_cast<uint8_t>(_mm_movemask_pd(reinterpret_cast<__m128d>(m)));
  }
#else
  uint8_t bits = 0;
  for (int i = 0; i < Vec<T>::kWidth; ++i) bits |= static_cast<uint8_t>(m[i] != 0) << i;
  return bits;
#endif
}

// One bit per lane -> lane mask, by table lookup (a load instead of broadcast, and, compare).
template <typename T>
struct BitTable {
  static constexpr int kWidth = Vec<T>::kWidth;
  using L = typename Vec<T>::lane;
  alignas(32) L lanes[1 << kWidth][kWidth];
  constexpr BitTable() : lanes() {
    for (int bits = 0; bits < (1 << kWidth); ++bits) {
      for (int i = 0; i < kWidth; ++i) lanes[bits][i] = (bits >> i) & 1 ? L(-1) : L(0);
    }
  }
};
template <typename T>
constexpr BitTable<T> kBitTable{};

template <typename T>
inline typename Vec<T>::mask FromBits(uint8_t bits) {
  typename Vec<T>::mask m;
  std::memcpy(&m, kBitTable<T>.lanes[bits], sizeof(m));
  return m;
}

// Horizontal sums. Every sum over the lanes of a vector uses one fixed tree, adjacent pairs first,
// ((s0 + s1) + (s2 + s3)) + ((s4 + s5) + (s6 + s7)), whether it is taken one step at a time (HSum)
// or for kWidth consecutive steps at once (BlockSum: a transpose made of horizontal adds, giving one
// vector of kWidth sums), so y_t does not depend on where t falls in a block.
template <typename T>
inline T HSum(typename Vec<T>::type a) {
  constexpr int W = Vec<T>::kWidth;
  T s[W];
  std::memcpy(s, &a, sizeof(a));
  for (int k = W; k > 1; k /= 2) {
    for (int i = 0; i < k / 2; ++i) s[i] = s[2 * i] + s[2 * i + 1];
  }
  return s[0];
}

#if defined(__AVX__)
constexpr bool kBlockSums = true;

// acc[k] holds the lane-wise partial sums of step k of a block; returns the vector of their sums.
inline Vec<float>::type BlockSum(const Vec<float>::type* acc) {
  __m256 a[8];
  std::memcpy(a, acc, sizeof(a));
  const __m256 t0 = _mm256_hadd_ps(_mm256_hadd_ps(a[0], a[1]), _mm256_hadd_ps(a[2], a[3]));
  const __m256 t1 = _mm256_hadd_ps(_mm256_hadd_ps(a[4], a[5]), _mm256_hadd_ps(a[6], a[7]));
  const __m256 s = _mm256_add_ps(_mm256_permute2f128_ps(t0, t1, 0x20),
                                 _mm256_permute2f128_ps(t0, t1, 0x31));
  return reinterpret_cast<Vec<float>::type>(s);
}
inline Vec<double>::type BlockSum(const Vec<double>::type* acc) {
  __m256d a[4];
  std::memcpy(a, acc, sizeof(a));
  const __m256d t0 = _mm256_hadd_pd(a[0], a[1]), t1 = _mm256_hadd_pd(a[2], a[3]);
  const __m256d s = _mm256_add_pd(_mm256_permute2f128_pd(t0, t1, 0x20),
                                  _mm256_permute2f128_pd(t0, t1, 0x31));
  return reinterpret_cast<Vec<double>::type>(s);
}
#elif defined(__SSE2__)
constexpr bool kBlockSums = true;

// The same sums with SSE2 alone (no horizontal adds): a 4 x 4 transpose by unpacks, then the tree.
inline Vec<float>::type BlockSum(const Vec<float>::type* acc) {
  __m128 a[4];
  std::memcpy(a, acc, sizeof(a));
  const __m128 t0 = _mm_unpacklo_ps(a[0], a[1]), t1 = _mm_unpackhi_ps(a[0], a[1]);
  const __m128 t2 = _mm_unpacklo_ps(a[2], a[3]), t3 = _mm_unpackhi_ps(a[2], a[3]);
  // c_i holds lane i of every step; the sums keep HSum's tree (s0 + s1) + (s2 + s3).
  const __m128 c0 = _mm_movelh_ps(t0, t2), c1 = _mm_movehl_ps(t2, t0);
  const __m128 c2 = _mm_movelh_ps(t1, t3), c3 = _mm_movehl_ps(t3, t1);
  const __m128 s = _mm_add_ps(_mm_add_ps(c0, c1), _mm_add_ps(c2, c3));
  return reinterpret_cast<Vec<float>::type>(s);
}
inline Vec<double>::type BlockSum(const Vec<double>::type* acc) {
  __m128d a[2];
  std::memcpy(a, acc, sizeof(a));
  const __m128d s = _mm_add_pd(_mm_unpacklo_pd(a[0], a[1]), _mm_unpackhi_pd(a[0], a[1]));
  return reinterpret_cast<Vec<double>::type>(s);
}
#else
constexpr bool kBlockSums = false;
template <typename V>
inline V BlockSum(const V* acc) {
  return acc[0];  // not called: without x86 vectors each step is summed on its own
}
#endif

// Runs body(b) for b in [0, batch), on up to hardware_concurrency threads when the work is large.
// Threads take small runs of signals from a shared counter rather than fixed halves, so a core
// that other processes slow down takes fewer signals instead of holding up the whole call. Each
// signal is computed the same way on any thread, so results never depend on the split.
void ParallelFor(int64_t batch, int64_t work_per_item, const std::function<void(int64_t)>& body) {
  int64_t threads = static_cast<int64_t>(std::thread::hardware_concurrency());
  if (const char* env = std::getenv("PIEST_KERNEL_THREADS")) {
    const int64_t v = std::atoll(env);
    if (v > 0) threads = v;
  }
  threads = std::max<int64_t>(1, std::min(threads, batch));
  if (threads == 1 || batch * work_per_item < (int64_t{1} << 16)) {
    for (int64_t b = 0; b < batch; ++b) body(b);
    return;
  }
  const int64_t grain = std::max<int64_t>(1, batch / (8 * threads));
  std::atomic<int64_t> next{0};
  auto run = [&]() {
    for (;;) {
      const int64_t lo = next.fetch_add(grain);
      if (lo >= batch) return;
      const int64_t hi = std::min(batch, lo + grain);
      for (int64_t b = lo; b < hi; ++b) body(b);
    }
  };
  std::vector<std::thread> pool;
  pool.reserve(threads - 1);
  for (int64_t k = 1; k < threads; ++k) pool.emplace_back(run);
  run();
  for (auto& th : pool) th.join();
}

// Asks the kernel to back the 2 MiB-aligned interior of an output buffer with transparent huge
// pages. Large XLA outputs are fresh anonymous mappings on every call, so writing them is dominated
// by page faults: one per 4 KiB page (half a million for a (10^6, 32) float32 bank) instead of one
// per 2 MiB. Where huge pages are off, or the range was already touched, this changes nothing.
void AdviseHugePages(void* data, int64_t bytes) {
#if defined(__linux__) && defined(MADV_HUGEPAGE)
  constexpr uintptr_t kHuge = uintptr_t{1} << 21;
  if (bytes < static_cast<int64_t>(2 * kHuge)) return;
  const uintptr_t begin = reinterpret_cast<uintptr_t>(data);
  const uintptr_t lo = (begin + kHuge - 1) & ~(kHuge - 1);
  const uintptr_t hi = (begin + static_cast<uintptr_t>(bytes)) & ~(kHuge - 1);
  if (hi > lo) madvise(reinterpret_cast<void*>(lo), hi - lo, MADV_HUGEPAGE);
#else
  (void)data;
  (void)bytes;
#endif
}

// The padded per-signal parameter lanes: padding plays have r = 0, w = 0, x0 = 0, so they track
// the input and contribute exactly zero to the fused sum.
template <typename T>
struct Lanes {
  std::vector<T> r, w, x;
  Lanes(const T* r_in, const T* w_in, const T* x0_in, int64_t n, int64_t np)
      : r(np, T(0)), w(np, T(0)), x(np, T(0)) {
    std::copy(r_in, r_in + n, r.begin());
    if (w_in != nullptr) std::copy(w_in, w_in + n, w.begin());
    std::copy(x0_in, x0_in + n, x.begin());
  }
};

// Lane-wise binary operations on vectors of T, by the AVX instruction where there is one.
// Min and Max are a < b ? a : b and a > b ? a : b, the selects of the pure-JAX play step: x86
// MINPS/MAXPS compute exactly these (the second operand on ties), in one short instruction. And
// and AndNot (~a & b) act on the bits; with AVX they stay in the floating-point domain (x86 moves
// data between its integer and floating-point vector units with an extra cycle, and these sit on
// the loop-carried chain of the backward pass).
#if defined(__AVX__)
#define PIEST_VEC_OP(NAME, PS, PD, PORTABLE)                                               \
  template <typename T>                                                                    \
  inline typename Vec<T>::type NAME(typename Vec<T>::type a, typename Vec<T>::type b) {    \
    using V = typename Vec<T>::type;                                                       \
    if constexpr (sizeof(T) == 4) {                                                        \
      return reinterpret_cast<V>(PS(reinterpret_cast<__m256>(a), reinterpret_cast<__m256>(b))); \
    } else {                                                                               \
      return reinterpret_cast<V>(                                                          \
          PD(reinterpret_cast<__m256d>(a), reinterpret_cast<__m256d>(b)));                 \
    }                                                                                      \
  }
#else
#define PIEST_VEC_OP(NAME, PS, PD, PORTABLE)                                               \
  template <typename T>                                                                    \
  inline typename Vec<T>::type NAME(typename Vec<T>::type a, typename Vec<T>::type b) {    \
    using V [[maybe_unused]] = typename Vec<T>::type;                                      \
    using M [[maybe_unused]] = typename Vec<T>::mask;                                      \
    return PORTABLE;                                                                       \
  }
#endif
PIEST_VEC_OP(Min, _mm256_min_ps, _mm256_min_pd, a < b ? a : b)
PIEST_VEC_OP(Max, _mm256_max_ps, _mm256_max_pd, a > b ? a : b)
PIEST_VEC_OP(And, _mm256_and_ps, _mm256_and_pd,
             reinterpret_cast<V>(reinterpret_cast<M>(a) & reinterpret_cast<M>(b)))
PIEST_VEC_OP(AndNot, _mm256_andnot_ps, _mm256_andnot_pd,
             reinterpret_cast<V>(~reinterpret_cast<M>(a) & reinterpret_cast<M>(b)))
#undef PIEST_VEC_OP

// Forward over one chunk of NV vectors of plays starting at play j0. r, w and xs point at the
// chunk's padded lanes; xs holds the states and is updated. h (row stride n), y and codes (row
// stride nc words) are written when kH, kY, kCodes; y is set by the first chunk and accumulated by
// the others. What is written is fixed at compile time, so the states stay in registers.
template <typename T, int NV, bool kH, bool kY, bool kCodes>
void ForwardChunk(const T* u, int64_t len, const T* r, const T* w, T* xs, int64_t j0, int64_t n,
                  int64_t nc, T* h, T* y, bool first, uint8_t* codes) {
  using V = typename Vec<T>::type;
  constexpr int W = Vec<T>::kWidth;
  V rv[NV], wv[NV], x[NV];
  std::memcpy(rv, r, sizeof(rv));
  std::memcpy(wv, w, sizeof(wv));
  std::memcpy(x, xs, sizeof(x));
  const int64_t nh = std::min<int64_t>(NV * W, n - j0);
  // One step: updates the states, writes h and the codes, returns the lane-wise terms of y_t.
  auto step = [&](int64_t t) __attribute__((always_inline)) {
    const T ut = u[t];
    V acc = {};
    for (int v = 0; v < NV; ++v) {
      const V lo = ut - rv[v], hi = ut + rv[v];
      const V next = Max<T>(lo, Min<T>(hi, x[v]));
      if constexpr (kCodes) codes[t * nc + v] = ToBits<T>(next != x[v]);
      x[v] = next;
      if constexpr (kY) acc = v == 0 ? wv[0] * x[0] : acc + wv[v] * x[v];
      if constexpr (kH) {
        StoreLanes<T>(h + t * n + v * W, next, std::min<int64_t>(W, nh - v * W));
      }
    }
    return acc;
  };
  int64_t t = 0;
  if constexpr (kY && kBlockSums) {
    for (; t + W <= len; t += W) {
      V acc[W];
      for (int k = 0; k < W; ++k) acc[k] = step(t + k);
      V s = BlockSum(acc);
      if (!first) {
        V old;
        std::memcpy(&old, y + t, sizeof(V));
        s = old + s;
      }
      std::memcpy(y + t, &s, sizeof(V));
    }
  }
  for (; t < len; ++t) {
    const V acc = step(t);
    if constexpr (kY) {
      const T s = HSum<T>(acc);
      y[t] = first ? s : y[t] + s;
    }
  }
  std::memcpy(xs, x, sizeof(x));
}

template <typename T, bool kH, bool kY, bool kCodes>
void ForwardChunks(const T* u, int64_t len, Lanes<T>& p, int64_t n, T* h, T* y, uint8_t* codes) {
  constexpr int W = Vec<T>::kWidth;
  const int64_t np = static_cast<int64_t>(p.r.size());
  const int64_t nc = CodeBytes<T>(np);
  for (int64_t j0 = 0; j0 < np; j0 += kChunk * W) {
    const int nv = static_cast<int>(std::min<int64_t>(kChunk, (np - j0) / W));
    const bool first = j0 == 0;
    T* hh = kH ? h + j0 : nullptr;
    uint8_t* cc = kCodes ? codes + j0 / W : nullptr;
    const T *r = p.r.data() + j0, *w = p.w.data() + j0;
    T* x = p.x.data() + j0;
#define PIEST_FWD(NV) \
  ForwardChunk<T, NV, kH, kY, kCodes>(u, len, r, w, x, j0, n, nc, hh, y, first, cc)
    switch (nv) {
      case 1: PIEST_FWD(1); break;
      case 2: PIEST_FWD(2); break;
      case 3: PIEST_FWD(3); break;
      case 4: PIEST_FWD(4); break;
      case 5: PIEST_FWD(5); break;
      case 6: PIEST_FWD(6); break;
      case 7: PIEST_FWD(7); break;
      default: PIEST_FWD(8); break;
    }
#undef PIEST_FWD
  }
}

// Exactly one of h (the bank) and y (the fused output) is given; codes is optional.
template <typename T>
void ForwardOne(const T* u, int64_t len, Lanes<T>& p, int64_t n, T* h, T* y, uint8_t* codes) {
  if (h != nullptr) {
    if (codes != nullptr) {
      ForwardChunks<T, true, false, true>(u, len, p, n, h, y, codes);
    } else {
      ForwardChunks<T, true, false, false>(u, len, p, n, h, y, codes);
    }
  } else if (codes != nullptr) {
    ForwardChunks<T, false, true, true>(u, len, p, n, h, y, codes);
  } else {
    ForwardChunks<T, false, true, false>(u, len, p, n, h, y, codes);
  }
}

// Backward over one chunk. kBank: g (t, n) is the cotangent of the regressor (unit weights, no
// dw); otherwise g (t,) is that of the fused output with weights w. Results go to the chunk's lanes
// of dr, dx0 and dw.
template <typename T, int NV, bool kBank>
void BackwardChunk(const T* u, int64_t len, const T* r, const T* w, const T* x0, int64_t j0,
                   int64_t n, int64_t nc, const uint8_t* codes, const T* g, T* du, bool first,
                   T* dr, T* dx0, T* dw) {
  using V = typename Vec<T>::type;
  constexpr int W = Vec<T>::kWidth;
  V wv[NV], nu[NV] = {}, sa[NV] = {}, su[NV] = {};
  std::memcpy(wv, w, sizeof(wv));
  // d x / d r at an active step: +1 on the upper bound, -1 on the lower one. At t = 0 the bound
  // depends on x0 (lane by lane): the lower one unless u_0 + r < x0, the comparison of the forward
  // pass.
  V dxdr0[NV];
  for (int v = 0; v < NV; ++v) {
    V rv, xv;
    std::memcpy(&rv, r + v * W, sizeof(V));
    std::memcpy(&xv, x0 + v * W, sizeof(V));
    dxdr0[v] = ((u[0] + rv) < xv) ? V{} + T(1) : V{} - T(1);
  }
  const int64_t nh = std::min<int64_t>(NV * W, n - j0);
  // One step back in time: moves the cotangent that leaves through an active bound out of nu (a,
  // all of nu or nothing per lane, into as[v]) and returns the lane-wise terms of du_t.
  auto step = [&](int64_t t, V* as) __attribute__((always_inline)) {
    V acc = {};
    for (int v = 0; v < NV; ++v) {
      const V moved = reinterpret_cast<V>(FromBits<T>(codes[t * nc + v]));
      if constexpr (kBank) {
        // Padding lanes get a zero cotangent, so they never contribute.
        V gv = {};
        LoadLanes<T>(gv, g + t * n + v * W, std::min<int64_t>(W, nh - v * W));
        nu[v] += gv;
      } else {
        nu[v] += g[t];
      }
      const V a = And<T>(nu[v], moved);
      nu[v] = AndNot<T>(moved, nu[v]);
      as[v] = a;
      if constexpr (kBank) {
        acc = v == 0 ? a : acc + a;
      } else {
        acc = v == 0 ? wv[0] * a : acc + wv[v] * a;
      }
    }
    return acc;
  };
  // What a step contributes to the parameter sums, given d x / d r (dxdr(v) for vector v) of the
  // states that moved. Kept apart from `step` so that neither loop needs more vector registers
  // than there are (spilled accumulators would put a store and a reload on their chains).
  auto fold = [&](const V* as, T ut, auto dxdr) __attribute__((always_inline)) {
    for (int v = 0; v < NV; ++v) {
      if constexpr (!kBank) su[v] += as[v] * ut;
      // a * (+-1) is exact, so this is the sum of +-a in the same order as a signed add.
      sa[v] += as[v] * dxdr(v);
    }
  };
  // For t >= 1 the bound that moved a state is the lower one exactly when the input rose (see
  // CodeBytes), the same for every play: d x / d r = -1 if u_t > u_{t-1}, else +1. A vector
  // select, not a branch, which the direction of a random input would defeat.
  auto put = [&](int64_t t, T d) { du[t] = first ? d : du[t] + d; };
  auto single = [&](int64_t t) __attribute__((always_inline)) {
    V as[NV];
    put(t, HSum<T>(step(t, as)));
    const V s = (V{} + u[t]) > (V{} + u[t - 1]) ? V{} - T(1) : V{} + T(1);
    fold(as, u[t], [&](int) { return s; });
  };
  // Steps len-1 down to 1: the top (len - 1) % W one at a time, then blocks of W; then t = 0.
  const int64_t blocked = kBlockSums ? (len - 1) / W * W : 0;
  for (int64_t t = len - 1; t > blocked; --t) single(t);
  if constexpr (kBlockSums) {
    for (int64_t t = blocked - W + 1; t >= 1; t -= W) {
      V acc[W], as[W][NV];
#pragma GCC unroll 8
      for (int k = W - 1; k >= 0; --k) acc[k] = step(t + k, as[k]);
      V s = BlockSum(acc);
      if (!first) {
        V old;
        std::memcpy(&old, du + t, sizeof(V));
        s = old + s;
      }
      std::memcpy(du + t, &s, sizeof(V));
      // The signs of the block's steps, all at once.
      V now, before;
      std::memcpy(&now, u + t, sizeof(V));
      std::memcpy(&before, u + t - 1, sizeof(V));
      const V sign = now > before ? V{} - T(1) : V{} + T(1);
      for (int k = W - 1; k >= 0; --k) {
        const V sk = V{} + sign[k];
        fold(as[k], u[t + k], [&](int) { return sk; });
      }
    }
  }
  {
    V as[NV];
    put(0, HSum<T>(step(0, as)));
    fold(as, u[0], [&](int v) { return dxdr0[v]; });
  }
  T nus[NV * W], sas[NV * W], sus[NV * W];
  std::memcpy(nus, nu, sizeof(nus));
  std::memcpy(sas, sa, sizeof(sas));
  std::memcpy(sus, su, sizeof(sus));
  for (int64_t k = 0; k < nh; ++k) {
    dx0[k] = w[k] * nus[k];
    dr[k] = w[k] * sas[k];
    if constexpr (!kBank) dw[k] = sus[k] + r[k] * sas[k] + nus[k] * x0[k];
  }
}

template <typename T, bool kBank>
void BackwardOne(const T* u, int64_t len, const T* r_in, const T* w_in, const T* x0_in, int64_t n,
                 const uint8_t* codes, const T* g, T* du, T* dr, T* dx0, T* dw) {
  constexpr int W = Vec<T>::kWidth;
  const int64_t np = Padded<T>(n);
  const int64_t nc = CodeBytes<T>(np);
  Lanes<T> p(r_in, w_in, x0_in, n, np);
  if constexpr (kBank) std::fill(p.w.begin(), p.w.begin() + n, T(1));
  for (int64_t j0 = 0; j0 < np; j0 += kChunkBwd * W) {
    const int nv = static_cast<int>(std::min<int64_t>(kChunkBwd, (np - j0) / W));
    const bool first = j0 == 0;
    const T *r = p.r.data() + j0, *w = p.w.data() + j0, *x0 = p.x.data() + j0;
    const uint8_t* cc = codes + j0 / W;
    const T* gg = kBank ? g + j0 : g;
    T* dww = kBank ? nullptr : dw + j0;
#define PIEST_BWD(NV)                                                                        \
  BackwardChunk<T, NV, kBank>(u, len, r, w, x0, j0, n, nc, cc, gg, du, first, dr + j0, dx0 + j0, \
                              dww)
    switch (nv) {
      case 1: PIEST_BWD(1); break;
      case 2: PIEST_BWD(2); break;
      case 3: PIEST_BWD(3); break;
      default: PIEST_BWD(4); break;
    }
#undef PIEST_BWD
  }
}

// Forward-mode tangent over one signal along (du, dr, dx0[, dw]): a state a bound moved at step t
// (its code bit) takes the input's tangent du_t -+ dr (-dr on the lower bound, which moved it
// exactly when the input rose; at t = 0 the comparison of x0 with u_0 + r decides, as in the
// backward pass); a held state keeps its tangent. kBank writes dh (len, n); otherwise dy (len,),
// sum_j w_j dx_j + dw_j x_j, with the states x_j run again by the forward recurrence.
template <typename T, bool kBank>
void TangentOne(const T* u, int64_t len, const T* r_in, const T* w_in, const T* x0_in, int64_t n,
                const uint8_t* codes, const T* du, const T* dr_in, const T* dx0_in,
                const T* dw_in, T* dh, T* dy) {
  using V = typename Vec<T>::type;
  using M = typename Vec<T>::mask;
  constexpr int W = Vec<T>::kWidth;
  const int64_t np = Padded<T>(n);
  const int64_t nc = CodeBytes<T>(np);
  const int64_t nv = np / W;
  Lanes<T> p(r_in, w_in, x0_in, n, np);
  Lanes<T> t(dr_in, dw_in, dx0_in, n, np);  // the tangents, padded alike (zero on padding)
  std::vector<V> rv(nv), wv(nv), x(nv), d(nv), drv(nv), dwv(nv), s0(nv);
  std::memcpy(rv.data(), p.r.data(), np * sizeof(T));
  std::memcpy(wv.data(), p.w.data(), np * sizeof(T));
  std::memcpy(x.data(), p.x.data(), np * sizeof(T));
  std::memcpy(drv.data(), t.r.data(), np * sizeof(T));
  std::memcpy(dwv.data(), t.w.data(), np * sizeof(T));
  std::memcpy(d.data(), t.x.data(), np * sizeof(T));
  for (int64_t v = 0; v < nv; ++v) s0[v] = ((u[0] + rv[v]) < x[v]) ? V{} + T(1) : V{} - T(1);
  for (int64_t k = 0; k < len; ++k) {
    const T ut = u[k];
    const V s = k == 0 ? V{} : (ut > u[k - 1] ? V{} - T(1) : V{} + T(1));
    V acc = {};
    for (int64_t v = 0; v < nv; ++v) {
      const M moved = FromBits<T>(codes[k * nc + v]);
      const V cand = du[k] + (k == 0 ? s0[v] : s) * drv[v];
      d[v] = reinterpret_cast<V>((moved & reinterpret_cast<M>(cand)) | (~moved & reinterpret_cast<M>(d[v])));
      if constexpr (kBank) {
        StoreLanes<T>(dh + k * n + v * W, d[v], std::min<int64_t>(W, n - v * W));
      } else {
        x[v] = Max<T>(ut - rv[v], Min<T>(ut + rv[v], x[v]));
        acc += wv[v] * d[v] + dwv[v] * x[v];
      }
    }
    if constexpr (!kBank) dy[k] = HSum<T>(acc);
  }
}

template <typename B>
int64_t Last(const B& buf) {
  auto d = buf.dimensions();
  return d.size() == 0 ? 1 : d[d.size() - 1];
}

template <ffi::DataType DT>
using Buf = ffi::Buffer<DT>;
template <ffi::DataType DT>
using Res = ffi::ResultBuffer<DT>;
using Codes = ffi::Buffer<ffi::U8>;
using CodesRes = ffi::ResultBuffer<ffi::U8>;

template <ffi::DataType DT>
ffi::Error CheckShapes(const Buf<DT>& u, const Buf<DT>& r, int64_t* batch, int64_t* len,
                       int64_t* n) {
  *len = Last(u);
  *n = Last(r);
  if (*len < 1 || *n < 1) return ffi::Error::InvalidArgument("play kernel: empty signal or bank");
  *batch = static_cast<int64_t>(u.element_count()) / *len;
  if (static_cast<int64_t>(r.element_count()) != *batch * *n) {
    return ffi::Error::InvalidArgument("play kernel: batch dimensions of u and r differ");
  }
  return ffi::Error::Success();
}

template <ffi::DataType DT>
ffi::Error BankFwd(Buf<DT> u, Buf<DT> r, Buf<DT> x0, Res<DT> h, uint8_t* codes) {
  using T = ffi::NativeType<DT>;
  int64_t batch, len, n;
  if (auto e = CheckShapes<DT>(u, r, &batch, &len, &n); e.failure()) return e;
  const int64_t np = Padded<T>(n);
  AdviseHugePages(h->typed_data(), h->size_bytes());
  if (codes != nullptr) AdviseHugePages(codes, batch * len * CodeBytes<T>(np));
  ParallelFor(batch, len * np, [&](int64_t b) {
    Lanes<T> p(r.typed_data() + b * n, nullptr, x0.typed_data() + b * n, n, np);
    ForwardOne<T>(u.typed_data() + b * len, len, p, n, h->typed_data() + b * len * n, nullptr,
                  codes != nullptr ? codes + b * len * CodeBytes<T>(np) : nullptr);
  });
  return ffi::Error::Success();
}

template <ffi::DataType DT>
ffi::Error PiFwd(Buf<DT> u, Buf<DT> r, Buf<DT> x0, Buf<DT> w, Res<DT> y, uint8_t* codes) {
  using T = ffi::NativeType<DT>;
  int64_t batch, len, n;
  if (auto e = CheckShapes<DT>(u, r, &batch, &len, &n); e.failure()) return e;
  const int64_t np = Padded<T>(n);
  AdviseHugePages(y->typed_data(), y->size_bytes());
  if (codes != nullptr) AdviseHugePages(codes, batch * len * CodeBytes<T>(np));
  ParallelFor(batch, len * np, [&](int64_t b) {
    Lanes<T> p(r.typed_data() + b * n, w.typed_data() + b * n, x0.typed_data() + b * n, n, np);
    ForwardOne<T>(u.typed_data() + b * len, len, p, n, nullptr, y->typed_data() + b * len,
                  codes != nullptr ? codes + b * len * CodeBytes<T>(np) : nullptr);
  });
  return ffi::Error::Success();
}

template <ffi::DataType DT>
ffi::Error BankFwdPlain(Buf<DT> u, Buf<DT> r, Buf<DT> x0, Res<DT> h) {
  return BankFwd<DT>(u, r, x0, h, nullptr);
}
template <ffi::DataType DT>
ffi::Error BankFwdCodes(Buf<DT> u, Buf<DT> r, Buf<DT> x0, Res<DT> h, CodesRes codes) {
  return BankFwd<DT>(u, r, x0, h, codes->typed_data());
}
template <ffi::DataType DT>
ffi::Error PiFwdPlain(Buf<DT> u, Buf<DT> r, Buf<DT> x0, Buf<DT> w, Res<DT> y) {
  return PiFwd<DT>(u, r, x0, w, y, nullptr);
}
template <ffi::DataType DT>
ffi::Error PiFwdCodes(Buf<DT> u, Buf<DT> r, Buf<DT> x0, Buf<DT> w, Res<DT> y, CodesRes codes) {
  return PiFwd<DT>(u, r, x0, w, y, codes->typed_data());
}

template <ffi::DataType DT>
ffi::Error BankBwd(Buf<DT> u, Buf<DT> r, Buf<DT> x0, Codes codes, Buf<DT> gh, Res<DT> du,
                   Res<DT> dr, Res<DT> dx0) {
  using T = ffi::NativeType<DT>;
  int64_t batch, len, n;
  if (auto e = CheckShapes<DT>(u, r, &batch, &len, &n); e.failure()) return e;
  const int64_t np = Padded<T>(n);
  AdviseHugePages(du->typed_data(), du->size_bytes());
  ParallelFor(batch, len * np, [&](int64_t b) {
    BackwardOne<T, true>(u.typed_data() + b * len, len, r.typed_data() + b * n, nullptr,
                         x0.typed_data() + b * n, n,
                         codes.typed_data() + b * len * CodeBytes<T>(np),
                         gh.typed_data() + b * len * n, du->typed_data() + b * len,
                         dr->typed_data() + b * n, dx0->typed_data() + b * n, nullptr);
  });
  return ffi::Error::Success();
}

template <ffi::DataType DT>
ffi::Error PiBwd(Buf<DT> u, Buf<DT> r, Buf<DT> x0, Buf<DT> w, Codes codes, Buf<DT> gy, Res<DT> du,
                 Res<DT> dr, Res<DT> dx0, Res<DT> dw) {
  using T = ffi::NativeType<DT>;
  int64_t batch, len, n;
  if (auto e = CheckShapes<DT>(u, r, &batch, &len, &n); e.failure()) return e;
  const int64_t np = Padded<T>(n);
  AdviseHugePages(du->typed_data(), du->size_bytes());
  ParallelFor(batch, len * np, [&](int64_t b) {
    BackwardOne<T, false>(u.typed_data() + b * len, len, r.typed_data() + b * n,
                          w.typed_data() + b * n, x0.typed_data() + b * n, n,
                          codes.typed_data() + b * len * CodeBytes<T>(np),
                          gy.typed_data() + b * len, du->typed_data() + b * len,
                          dr->typed_data() + b * n, dx0->typed_data() + b * n,
                          dw->typed_data() + b * n);
  });
  return ffi::Error::Success();
}

template <ffi::DataType DT>
ffi::Error BankTan(Buf<DT> u, Buf<DT> r, Buf<DT> x0, Codes codes, Buf<DT> du, Buf<DT> dr,
                   Buf<DT> dx0, Res<DT> dh) {
  using T = ffi::NativeType<DT>;
  int64_t batch, len, n;
  if (auto e = CheckShapes<DT>(u, r, &batch, &len, &n); e.failure()) return e;
  const int64_t np = Padded<T>(n);
  AdviseHugePages(dh->typed_data(), dh->size_bytes());
  ParallelFor(batch, len * np, [&](int64_t b) {
    TangentOne<T, true>(u.typed_data() + b * len, len, r.typed_data() + b * n, nullptr,
                        x0.typed_data() + b * n, n, codes.typed_data() + b * len * CodeBytes<T>(np),
                        du.typed_data() + b * len, dr.typed_data() + b * n,
                        dx0.typed_data() + b * n, nullptr, dh->typed_data() + b * len * n, nullptr);
  });
  return ffi::Error::Success();
}

template <ffi::DataType DT>
ffi::Error PiTan(Buf<DT> u, Buf<DT> r, Buf<DT> x0, Buf<DT> w, Codes codes, Buf<DT> du, Buf<DT> dr,
                 Buf<DT> dx0, Buf<DT> dw, Res<DT> dy) {
  using T = ffi::NativeType<DT>;
  int64_t batch, len, n;
  if (auto e = CheckShapes<DT>(u, r, &batch, &len, &n); e.failure()) return e;
  const int64_t np = Padded<T>(n);
  ParallelFor(batch, len * np, [&](int64_t b) {
    TangentOne<T, false>(u.typed_data() + b * len, len, r.typed_data() + b * n,
                         w.typed_data() + b * n, x0.typed_data() + b * n, n,
                         codes.typed_data() + b * len * CodeBytes<T>(np), du.typed_data() + b * len,
                         dr.typed_data() + b * n, dx0.typed_data() + b * n,
                         dw.typed_data() + b * n, nullptr, dy->typed_data() + b * len);
  });
  return ffi::Error::Success();
}

}  // namespace

#define PIEST_HANDLERS(SUFFIX, DT)                                                          \
  XLA_FFI_DEFINE_HANDLER_SYMBOL(BankFwd##SUFFIX, BankFwdPlain<DT>,                          \
                                ffi::Ffi::Bind()                                            \
                                    .Arg<Buf<DT>>()                                         \
                                    .Arg<Buf<DT>>()                                         \
                                    .Arg<Buf<DT>>()                                         \
                                    .Ret<Buf<DT>>());                                       \
  XLA_FFI_DEFINE_HANDLER_SYMBOL(BankFwdRes##SUFFIX, BankFwdCodes<DT>,                       \
                                ffi::Ffi::Bind()                                            \
                                    .Arg<Buf<DT>>()                                         \
                                    .Arg<Buf<DT>>()                                         \
                                    .Arg<Buf<DT>>()                                         \
                                    .Ret<Buf<DT>>()                                         \
                                    .Ret<Codes>());                                         \
  XLA_FFI_DEFINE_HANDLER_SYMBOL(PiFwd##SUFFIX, PiFwdPlain<DT>,                              \
                                ffi::Ffi::Bind()                                            \
                                    .Arg<Buf<DT>>()                                         \
                                    .Arg<Buf<DT>>()                                         \
                                    .Arg<Buf<DT>>()                                         \
                                    .Arg<Buf<DT>>()                                         \
                                    .Ret<Buf<DT>>());                                       \
  XLA_FFI_DEFINE_HANDLER_SYMBOL(PiFwdRes##SUFFIX, PiFwdCodes<DT>,                           \
                                ffi::Ffi::Bind()                                            \
                                    .Arg<Buf<DT>>()                                         \
                                    .Arg<Buf<DT>>()                                         \
                                    .Arg<Buf<DT>>()                                         \
                                    .Arg<Buf<DT>>()                                         \
                                    .Ret<Buf<DT>>()                                         \
                                    .Ret<Codes>());                                         \
  XLA_FFI_DEFINE_HANDLER_SYMBOL(BankBwd##SUFFIX, BankBwd<DT>,                               \
                                ffi::Ffi::Bind()                                            \
                                    .Arg<Buf<DT>>()                                         \
                                    .Arg<Buf<DT>>()                                         \
                                    .Arg<Buf<DT>>()                                         \
                                    .Arg<Codes>()                                           \
                                    .Arg<Buf<DT>>()                                         \
                                    .Ret<Buf<DT>>()                                         \
                                    .Ret<Buf<DT>>()                                         \
                                    .Ret<Buf<DT>>());                                       \
  XLA_FFI_DEFINE_HANDLER_SYMBOL(PiBwd##SUFFIX, PiBwd<DT>,                                   \
                                ffi::Ffi::Bind()                                            \
                                    .Arg<Buf<DT>>()                                         \
                                    .Arg<Buf<DT>>()                                         \
                                    .Arg<Buf<DT>>()                                         \
                                    .Arg<Buf<DT>>()                                         \
                                    .Arg<Codes>()                                           \
                                    .Arg<Buf<DT>>()                                         \
                                    .Ret<Buf<DT>>()                                         \
                                    .Ret<Buf<DT>>()                                         \
                                    .Ret<Buf<DT>>()                                         \
                                    .Ret<Buf<DT>>());                                       \
  XLA_FFI_DEFINE_HANDLER_SYMBOL(BankTan##SUFFIX, BankTan<DT>,                               \
                                ffi::Ffi::Bind()                                            \
                                    .Arg<Buf<DT>>()                                         \
                                    .Arg<Buf<DT>>()                                         \
                                    .Arg<Buf<DT>>()                                         \
                                    .Arg<Codes>()                                           \
                                    .Arg<Buf<DT>>()                                         \
                                    .Arg<Buf<DT>>()                                         \
                                    .Arg<Buf<DT>>()                                         \
                                    .Ret<Buf<DT>>());                                       \
  XLA_FFI_DEFINE_HANDLER_SYMBOL(PiTan##SUFFIX, PiTan<DT>,                                   \
                                ffi::Ffi::Bind()                                            \
                                    .Arg<Buf<DT>>()                                         \
                                    .Arg<Buf<DT>>()                                         \
                                    .Arg<Buf<DT>>()                                         \
                                    .Arg<Buf<DT>>()                                         \
                                    .Arg<Codes>()                                           \
                                    .Arg<Buf<DT>>()                                         \
                                    .Arg<Buf<DT>>()                                         \
                                    .Arg<Buf<DT>>()                                         \
                                    .Arg<Buf<DT>>()                                         \
                                    .Ret<Buf<DT>>());

PIEST_HANDLERS(F32, ffi::F32)
PIEST_HANDLERS(F64, ffi::F64)

namespace {

struct Entry {
  const char* name;
  XLA_FFI_Handler* handler;
};

const Entry kEntries[] = {
    {"piest_bank_fwd_f32", BankFwdF32},     {"piest_bank_fwd_res_f32", BankFwdResF32},
    {"piest_pi_fwd_f32", PiFwdF32},         {"piest_pi_fwd_res_f32", PiFwdResF32},
    {"piest_bank_bwd_f32", BankBwdF32},     {"piest_pi_bwd_f32", PiBwdF32},
    {"piest_bank_fwd_f64", BankFwdF64},     {"piest_bank_fwd_res_f64", BankFwdResF64},
    {"piest_pi_fwd_f64", PiFwdF64},         {"piest_pi_fwd_res_f64", PiFwdResF64},
    {"piest_bank_bwd_f64", BankBwdF64},     {"piest_pi_bwd_f64", PiBwdF64},
    {"piest_bank_tangent_f32", BankTanF32}, {"piest_pi_tangent_f32", PiTanF32},
    {"piest_bank_tangent_f64", BankTanF64}, {"piest_pi_tangent_f64", PiTanF64},
};

PyObject* Registrations(PyObject*, PyObject*) {
  PyObject* out = PyDict_New();
  if (out == nullptr) return nullptr;
  for (const Entry& e : kEntries) {
    PyObject* cap = PyCapsule_New(reinterpret_cast<void*>(e.handler), nullptr, nullptr);
    if (cap == nullptr || PyDict_SetItemString(out, e.name, cap) != 0) {
      Py_XDECREF(cap);
      Py_DECREF(out);
      return nullptr;
    }
    Py_DECREF(cap);
  }
  return out;
}

// Bytes of branch codes per step for n plays of a dtype of `itemsize` bytes.
PyObject* CodeBytes_(PyObject*, PyObject* args) {
  long long n, itemsize;
  if (!PyArg_ParseTuple(args, "LL", &n, &itemsize)) return nullptr;
  if (n < 1 || (itemsize != 4 && itemsize != 8)) {
    PyErr_SetString(PyExc_ValueError, "code_bytes needs n >= 1 and an itemsize of 4 or 8");
    return nullptr;
  }
  return PyLong_FromLongLong(itemsize == 4 ? CodeBytes<float>(Padded<float>(n)) : CodeBytes<double>(Padded<double>(n)));
}

// The instruction-set extensions the kernels were compiled for (/proc/cpuinfo names), so that a
// binary moved to a CPU without them is refused before any kernel runs.
PyObject* Isa(PyObject*, PyObject*) {
#if defined(__AVX2__) && defined(__FMA__)
  return Py_BuildValue("(ss)", "avx2", "fma");
#elif defined(__AVX__)
  return Py_BuildValue("(s)", "avx");
#else
  return PyTuple_New(0);
#endif
}

// Whether this CPU (and the OS, which must save the wide registers) supports an extension, from
// CPUID where the compiler offers it; the binding asks the portable module before it loads the AVX2
// one. Elsewhere nothing is claimed.
PyObject* CpuHas(PyObject*, PyObject* args) {
  const char* name = nullptr;
  if (!PyArg_ParseTuple(args, "s", &name)) return nullptr;
  long has = 0;
#if (defined(__x86_64__) || defined(__i386__)) && (defined(__GNUC__) || defined(__clang__))
  __builtin_cpu_init();
  if (std::strcmp(name, "avx2") == 0) has = __builtin_cpu_supports("avx2");
  else if (std::strcmp(name, "fma") == 0) has = __builtin_cpu_supports("fma");
  else if (std::strcmp(name, "avx") == 0) has = __builtin_cpu_supports("avx");
#endif
  return PyBool_FromLong(has != 0);
}

// The jaxlib whose FFI headers the kernels were compiled against (setup.py defines it): the
// binding refuses the kernels under another jaxlib, whose runtime may not match those headers.
#ifndef PIEST_JAXLIB_VERSION
#define PIEST_JAXLIB_VERSION "unknown"
#endif
PyObject* BuiltWith(PyObject*, PyObject*) { return PyUnicode_FromString(PIEST_JAXLIB_VERSION); }

PyMethodDef kMethods[] = {
    {"registrations", Registrations, METH_NOARGS, "FFI handler capsules by target name."},
    {"code_bytes", CodeBytes_, METH_VARARGS, "Bytes of branch codes per step: (n, itemsize)."},
    {"isa", Isa, METH_NOARGS, "The instruction-set extensions the kernels need."},
    {"cpu_has", CpuHas, METH_VARARGS, "Whether this CPU supports an extension (avx, avx2, fma)."},
    {"built_with", BuiltWith, METH_NOARGS, "The jaxlib version the kernels were compiled against."},
    {nullptr, nullptr, 0, nullptr},
};

// One source, two extension modules (setup.py): _play_kernel, built for the baseline of the target
// (SSE2 on x86-64), and _play_kernel_avx2, built with AVX2 and FMA; the binding loads the second
// where the CPU has those instructions and the first elsewhere.
#ifndef PIEST_MODULE
#define PIEST_MODULE _play_kernel
#endif
#define PIEST_STR_(x) #x
#define PIEST_STR(x) PIEST_STR_(x)
#define PIEST_INIT_(x) PyInit_##x
#define PIEST_INIT(x) PIEST_INIT_(x)

PyModuleDef kModule = {PyModuleDef_HEAD_INIT, PIEST_STR(PIEST_MODULE), "CPU play-bank kernels.", -1,
                       kMethods};

}  // namespace

PyMODINIT_FUNC PIEST_INIT(PIEST_MODULE)(void) { return PyModule_Create(&kModule); }
