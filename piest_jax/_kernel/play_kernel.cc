// CPU kernels for the play bank, registered with JAX through the XLA FFI.
//
// One play step is the clamp x_t = max(u_t - r, min(u_t + r, x_{t-1})), evaluated with exactly the
// operations of the pure-JAX scan, so the play outputs agree with it to the last bit. The plays of a
// bank are independent lanes: the inner loops run across plays over contiguous arrays padded to a
// multiple of kLanes, which the compiler turns into SIMD code without branches.
//
// The fused PI output y_t = sum_j w_j x_{t,j} is summed in a fixed order (lane-wise partial sums
// over the vectors of a chunk of plays, then a halving tree, then chunk after chunk), so a build
// gives the same bits on every call.
//
// Backward pass. Each step records which branch was active, as two bit masks per vector of plays
// (bit i of the first byte: lane i was moved by a bound, u + r or u - r; of the second: the bound
// was the lower one, u - r; neither: the state was held). At a tie (the old state equal to a bound)
// the step counts as held. Bit masks keep the residual small (2 bytes per 8 float plays per step)
// and turn back into lane masks with one table lookup each. The adjoint is a reverse recurrence:
// nu_j accumulates the output cotangents of play j over the current run of held steps; at an active
// step it flows to u_t (and with sign +1 on the upper, -1 on the lower bound to r_j) and resets;
// what is left at t = 0 flows to the initial state.
//
// Every buffer may carry leading batch dimensions (from vmap); they are flattened into B signals
// and split across threads.

#include <Python.h>

#if defined(__AVX__) || defined(__SSE2__)
#include <immintrin.h>
#endif

#include <algorithm>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <functional>
#include <thread>
#include <type_traits>
#include <vector>

#include "xla/ffi/api/ffi.h"

namespace ffi = xla::ffi;

namespace {

// Play lanes are padded to a multiple of kLanes; a chunk of up to kChunk vectors is run through the
// whole signal at once.
constexpr int64_t kLanes = 8;
constexpr int kChunk = 4;

int64_t Padded(int64_t n) { return (n + kLanes - 1) / kLanes * kLanes; }

// Explicit SIMD through GCC/Clang vector extensions: 32-byte vectors (two SSE registers on
// machines without AVX), so the state of a chunk of plays stays in registers for the whole signal.
template <typename T>
struct Vec;
template <>
struct Vec<float> {
  typedef float type __attribute__((vector_size(32)));
  typedef int32_t mask __attribute__((vector_size(32)));
  static constexpr int kWidth = 8;
};
template <>
struct Vec<double> {
  typedef double type __attribute__((vector_size(32)));
  typedef int64_t mask __attribute__((vector_size(32)));
  static constexpr int kWidth = 4;
};

// Bytes of branch codes per step for np padded plays: two bit masks per vector.
template <typename T>
int64_t CodeBytes(int64_t np) {
  return 2 * np / Vec<T>::kWidth;
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
  __m128 half[2];
  std::memcpy(half, &m, sizeof(m));
  if constexpr (sizeof(T) == 4) {
    return static_cast<uint8_t>(_mm_movemask_ps(half[0]) | (_mm_movemask_ps(half[1]) << 4));
  } else {
    return static_cast<uint8_t>(_mm_movemask_pd(_mm_castps_pd(half[0])) |
                                (_mm_movemask_pd(_mm_castps_pd(half[1])) << 2));
  }
#else
  uint8_t bits = 0;
  for (int i = 0; i < Vec<T>::kWidth; ++i) bits |= static_cast<uint8_t>(m[i] != 0) << i;
  return bits;
#endif
}

// One bit per lane -> lane mask, by table lookup (one load instead of broadcast, and, compare).
// kSign selects a table whose set lanes hold only the sign bit (to flip signs with an xor).
template <typename T, bool kSign>
struct BitTable {
  static constexpr int kWidth = Vec<T>::kWidth;
  using Lane = typename std::conditional<sizeof(T) == 4, int32_t, int64_t>::type;
  static constexpr Lane kSet =
      kSign ? static_cast<Lane>(Lane(1) << (8 * sizeof(Lane) - 1)) : Lane(-1);
  alignas(32) Lane lanes[1 << kWidth][kWidth];
  constexpr BitTable() : lanes() {
    for (int bits = 0; bits < (1 << kWidth); ++bits) {
      for (int i = 0; i < kWidth; ++i) lanes[bits][i] = (bits >> i) & 1 ? kSet : Lane(0);
    }
  }
};
template <typename T, bool kSign>
constexpr BitTable<T, kSign> kBitTable{};

template <typename T, bool kSign = false>
inline typename Vec<T>::mask FromBits(uint8_t bits) {
  typename Vec<T>::mask m;
  std::memcpy(&m, kBitTable<T, kSign>.lanes[bits], sizeof(m));
  return m;
}

// Horizontal sum in a fixed halving order.
template <typename T>
inline T HSum(typename Vec<T>::type a) {
  constexpr int W = Vec<T>::kWidth;
  T s[W];
  std::memcpy(s, &a, sizeof(a));
  for (int k = W / 2; k > 0; k /= 2) {
    for (int i = 0; i < k; ++i) s[i] += s[i + k];
  }
  return s[0];
}

// Runs body(b) for b in [0, batch), on up to hardware_concurrency threads when the work is large.
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
  std::vector<std::thread> pool;
  pool.reserve(threads - 1);
  auto run = [&](int64_t k) {
    const int64_t lo = batch * k / threads, hi = batch * (k + 1) / threads;
    for (int64_t b = lo; b < hi; ++b) body(b);
  };
  for (int64_t k = 1; k < threads; ++k) pool.emplace_back(run, k);
  run(0);
  for (auto& th : pool) th.join();
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

// min(a, b) as a < b ? a : b and max(a, b) as a > b ? a : b, the selects of the pure-JAX play step.
// x86 MINPS/MAXPS compute exactly these (the second operand on ties), in one short instruction.
template <typename T>
inline typename Vec<T>::type Min(typename Vec<T>::type a, typename Vec<T>::type b) {
#if defined(__AVX__)
  if constexpr (sizeof(T) == 4) {
    return reinterpret_cast<typename Vec<T>::type>(
        _mm256_min_ps(reinterpret_cast<__m256>(a), reinterpret_cast<__m256>(b)));
  } else {
    return reinterpret_cast<typename Vec<T>::type>(
        _mm256_min_pd(reinterpret_cast<__m256d>(a), reinterpret_cast<__m256d>(b)));
  }
#else
  return a < b ? a : b;
#endif
}
template <typename T>
inline typename Vec<T>::type Max(typename Vec<T>::type a, typename Vec<T>::type b) {
#if defined(__AVX__)
  if constexpr (sizeof(T) == 4) {
    return reinterpret_cast<typename Vec<T>::type>(
        _mm256_max_ps(reinterpret_cast<__m256>(a), reinterpret_cast<__m256>(b)));
  } else {
    return reinterpret_cast<typename Vec<T>::type>(
        _mm256_max_pd(reinterpret_cast<__m256d>(a), reinterpret_cast<__m256d>(b)));
  }
#else
  return a > b ? a : b;
#endif
}

// Forward over one chunk of NV vectors of plays starting at play j0. r, w and x point at the chunk's
// padded lanes; x holds the states and is updated. h (row stride n), y and codes (row stride nc)
// are written when kH, kY, kCodes; y is set by the first chunk and accumulated by the others.
// What is written is fixed at compile time, so the states stay in registers for the whole signal.
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
  for (int64_t t = 0; t < len; ++t) {
    const T ut = u[t];
    V acc;
    for (int v = 0; v < NV; ++v) {
      const V lo = ut - rv[v], hi = ut + rv[v];
      const V m = Min<T>(hi, x[v]);
      if constexpr (kCodes) {
        const uint8_t lower = ToBits<T>(lo > m);
        codes[t * nc + 2 * v] = ToBits<T>(hi < x[v]) | lower;
        codes[t * nc + 2 * v + 1] = lower;
      }
      x[v] = Max<T>(lo, m);
      if constexpr (kY) acc = v == 0 ? wv[0] * x[0] : acc + wv[v] * x[v];
      if constexpr (kH) {
        const V xv = x[v];
        const int64_t count = std::min<int64_t>(W, nh - v * W);
        if (count == W) {
          std::memcpy(h + t * n + v * W, &xv, sizeof(V));
        } else if (count > 0) {
          std::memcpy(h + t * n + v * W, &xv, count * sizeof(T));
        }
      }
    }
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
    uint8_t* cc = kCodes ? codes + 2 * (j0 / W) : nullptr;
    const T *r = p.r.data() + j0, *w = p.w.data() + j0;
    T* x = p.x.data() + j0;
#define PIEST_FWD(NV) \
  ForwardChunk<T, NV, kH, kY, kCodes>(u, len, r, w, x, j0, n, nc, hh, y, first, cc)
    switch (nv) {
      case 1: PIEST_FWD(1); break;
      case 2: PIEST_FWD(2); break;
      case 3: PIEST_FWD(3); break;
      default: PIEST_FWD(4); break;
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
  using M = typename Vec<T>::mask;
  constexpr int W = Vec<T>::kWidth;
  V wv[NV], nu[NV] = {}, sa[NV] = {}, su[NV] = {};
  std::memcpy(wv, w, sizeof(wv));
  const int64_t nh = std::min<int64_t>(NV * W, n - j0);
  for (int64_t t = len - 1; t >= 0; --t) {
    const T ut = u[t];
    V acc;
    for (int v = 0; v < NV; ++v) {
      const M moved = FromBits<T>(codes[t * nc + 2 * v]);
      const M lower_sign = FromBits<T, true>(codes[t * nc + 2 * v + 1]);
      if constexpr (kBank) {
        // Padding lanes get a zero cotangent, so they never contribute.
        V gv = {};
        const int64_t count = std::min<int64_t>(W, nh - v * W);
        if (count == W) {
          std::memcpy(&gv, g + t * n + v * W, sizeof(V));
        } else if (count > 0) {
          std::memcpy(&gv, g + t * n + v * W, count * sizeof(T));
        }
        nu[v] += gv;
      } else {
        nu[v] += g[t];
      }
      const M nu_bits = reinterpret_cast<M>(nu[v]);
      // a: the cotangent that leaves through an active bound (all of nu, or nothing when held).
      const M a_bits = nu_bits & moved;
      const V a = reinterpret_cast<V>(a_bits);
      if constexpr (kBank) {
        acc = v == 0 ? a : acc + a;
      } else {
        acc = v == 0 ? wv[0] * a : acc + wv[v] * a;
        su[v] += a * ut;
      }
      // d x / d r is +1 on the upper bound and -1 on the lower one: flip the sign there.
      sa[v] += reinterpret_cast<V>(a_bits ^ lower_sign);
      nu[v] = reinterpret_cast<V>(nu_bits & ~moved);
    }
    const T d = HSum<T>(acc);
    du[t] = first ? d : du[t] + d;
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

// The fused backward keeps three accumulators per vector (nu, sa, su); chunks of kChunkFusedBwd
// vectors keep them all in the 16 vector registers of AVX2.
constexpr int kChunkFusedBwd = 4;

template <typename T, bool kBank>
void BackwardOne(const T* u, int64_t len, const T* r_in, const T* w_in, const T* x0_in, int64_t n,
                 const uint8_t* codes, const T* g, T* du, T* dr, T* dx0, T* dw) {
  constexpr int W = Vec<T>::kWidth;
  constexpr int kC = kBank ? kChunk : kChunkFusedBwd;
  const int64_t np = Padded(n);
  const int64_t nc = CodeBytes<T>(np);
  Lanes<T> p(r_in, w_in, x0_in, n, np);
  if constexpr (kBank) std::fill(p.w.begin(), p.w.begin() + n, T(1));
  for (int64_t j0 = 0; j0 < np; j0 += kC * W) {
    const int nv = static_cast<int>(std::min<int64_t>(kC, (np - j0) / W));
    const bool first = j0 == 0;
    const T *r = p.r.data() + j0, *w = p.w.data() + j0, *x0 = p.x.data() + j0;
    const uint8_t* cc = codes + 2 * (j0 / W);
    const T* gg = kBank ? g + j0 : g;
    T* dww = kBank ? nullptr : dw + j0;
#define PIEST_BWD(NV)                                                                        \
  BackwardChunk<T, (NV <= kC ? NV : kC), kBank>(u, len, r, w, x0, j0, n, nc, cc, gg, du, first, \
                                                dr + j0, dx0 + j0, dww)
    switch (nv) {
      case 1: PIEST_BWD(1); break;
      case 2: PIEST_BWD(2); break;
      case 3: PIEST_BWD(3); break;
      default: PIEST_BWD(4); break;
    }
#undef PIEST_BWD
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
  const int64_t np = Padded(n);
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
  const int64_t np = Padded(n);
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
  const int64_t np = Padded(n);
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
  const int64_t np = Padded(n);
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

PyObject* Lanes_(PyObject*, PyObject*) { return PyLong_FromLongLong(kLanes); }

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

PyMethodDef kMethods[] = {
    {"registrations", Registrations, METH_NOARGS, "FFI handler capsules by target name."},
    {"lanes", Lanes_, METH_NOARGS, "The padding width of the play lanes."},
    {"isa", Isa, METH_NOARGS, "The instruction-set extensions the kernels need."},
    {nullptr, nullptr, 0, nullptr},
};

PyModuleDef kModule = {PyModuleDef_HEAD_INIT, "_play_kernel", "CPU play-bank kernels.", -1,
                       kMethods};

}  // namespace

PyMODINIT_FUNC PyInit__play_kernel(void) { return PyModule_Create(&kModule); }
