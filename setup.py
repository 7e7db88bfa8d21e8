"""Build of the optional compiled play kernel; all other metadata lives in pyproject.toml.

The extension is built against the XLA FFI headers shipped with jax (`jax.ffi.include_dir()`). It
is optional: when no C++ compiler is present or the build fails, installation continues and the
package falls back to the pure-JAX scan. Set PIEST_KERNEL_BUILD=0 to skip it, and
PIEST_KERNEL_NATIVE=0 to build without the AVX2/FMA flags chosen when the build machine has them.
"""

import os
import subprocess
import tempfile

from setuptools import Extension, setup
from setuptools.command.build_ext import build_ext

# AVX2 + FMA are used only when a probe built with those flags runs correctly here, so the flags
# can never yield a kernel that faults on the machine that built it (a CPU or OS without AVX, a
# compiler without the flags, or a non-x86 target all make the probe fail, and the build goes on
# without them).
_SIMD_FLAGS = ["-mavx2", "-mfma"]
_SIMD_PROBE = r"""
#include <immintrin.h>
int main(void) {
  __builtin_cpu_init();
  if (!__builtin_cpu_supports("avx2") || !__builtin_cpu_supports("fma")) return 1;
  volatile float a = 1.5f, b = 2.0f, c = 0.25f;
  volatile int k = 1;
  __m256 x = _mm256_fmadd_ps(_mm256_set1_ps(a), _mm256_set1_ps(b), _mm256_set1_ps(c));
  __m256i i = _mm256_add_epi32(_mm256_set1_epi32(k), _mm256_set1_epi32(2));
  float xs[8];
  int is[8];
  _mm256_storeu_ps(xs, x);
  _mm256_storeu_si256((__m256i *)is, i);
  return xs[7] == 3.25f && is[7] == 3 ? 0 : 1;
}
"""


def _simd_args(compiler) -> list[str]:
    if os.environ.get("PIEST_KERNEL_NATIVE", "1") == "0":
        return []
    try:
        with tempfile.TemporaryDirectory() as tmp:
            src = os.path.join(tmp, "simd_probe.c")
            with open(src, "w") as f:
                f.write(_SIMD_PROBE)
            objects = compiler.compile([src], output_dir=tmp, extra_postargs=_SIMD_FLAGS)
            compiler.link_executable(objects, "simd_probe", output_dir=tmp)
            probe = os.path.join(tmp, "simd_probe")
            ok = subprocess.run([probe], capture_output=True, timeout=30).returncode == 0
    except Exception:  # noqa: BLE001 - any failure means "build without the flags"
        ok = False
    return _SIMD_FLAGS if ok else []


def _jaxlib_version() -> str:
    from importlib.metadata import version

    return version("jaxlib")


def _jax_include() -> str | None:
    try:
        import jax.ffi

        return jax.ffi.include_dir()
    except Exception:
        return None


class OptionalBuildExt(build_ext):
    """build_ext that never fails the install: a broken kernel build only loses the speed-up."""

    def run(self):
        try:
            super().run()
        except Exception as err:  # noqa: BLE001 - any build failure means "no kernel"
            print(f"piest_jax: skipping the compiled play kernel ({err})")

    def build_extension(self, ext):
        ext.extra_compile_args = [*ext.extra_compile_args, *_simd_args(self.compiler)]
        try:
            super().build_extension(ext)
        except Exception as err:  # noqa: BLE001
            print(f"piest_jax: skipping the compiled play kernel ({err})")


def _extensions() -> list[Extension]:
    if os.environ.get("PIEST_KERNEL_BUILD", "1") == "0":
        return []
    include = _jax_include()
    if include is None:
        print("piest_jax: jax FFI headers not found; skipping the compiled play kernel")
        return []
    return [
        Extension(
            "piest_jax._operators.kernel._play_kernel",
            sources=["piest_jax/_operators/kernel/play_kernel.cc"],
            include_dirs=[include],
            # The binding loads the kernel only under this same jaxlib (pip's isolated build can
            # compile against a newer jaxlib than the one installed beside the package).
            define_macros=[("PIEST_JAXLIB_VERSION", f'"{_jaxlib_version()}"')],
            language="c++",
            extra_compile_args=["-O3", "-g0", "-std=c++17", "-fvisibility=hidden", "-w"],
            extra_link_args=["-pthread"],
            optional=True,
        )
    ]


setup(ext_modules=_extensions(), cmdclass={"build_ext": OptionalBuildExt})
