"""Build of the optional compiled play kernel; all other metadata lives in pyproject.toml.

The extension is built against the XLA FFI headers shipped with jax (`jax.ffi.include_dir()`). It
is optional: when no C++ compiler is present or the build fails, installation continues and the
package falls back to the pure-JAX scan. One source gives two modules: `_play_kernel`, for the
baseline of the target (SSE2 on x86-64, so it runs on every CPU of the architecture), and
`_play_kernel_avx2`, with AVX2/FMA, built wherever the compiler accepts those flags; at run time the
binding loads the second on CPUs that have the instructions and the first elsewhere, so one build
(a wheel, a shared environment) is fast on the machine that built it and runs on any other. Set
PIEST_KERNEL_BUILD=0 to skip the kernel, PIEST_KERNEL_NATIVE=0 to build the portable module only.
"""

import os
import tempfile

from setuptools import Extension, setup
from setuptools.command.build_ext import build_ext

_SIMD_FLAGS = ["-mavx2", "-mfma"]
# Whether the compiler targets x86 and knows the flags; the machine that builds need not have the
# instructions, since the module is loaded only where the CPU has them.
_SIMD_PROBE = r"""
#include <immintrin.h>
__m256 f(__m256 a, __m256 b, __m256 c) { return _mm256_fmadd_ps(a, b, c); }
__m256i g(__m256i a, __m256i b) { return _mm256_add_epi32(a, b); }
"""
_AVX2_MODULE = "piest_jax._operators.kernel._play_kernel_avx2"


def _compiles_with_simd(compiler) -> bool:
    try:
        with tempfile.TemporaryDirectory() as tmp:
            src = os.path.join(tmp, "simd_probe.c")
            with open(src, "w") as f:
                f.write(_SIMD_PROBE)
            compiler.compile([src], output_dir=tmp, extra_postargs=_SIMD_FLAGS)
    except Exception:  # noqa: BLE001 - any failure means "no AVX2 module"
        return False
    return True


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
        if ext.name == _AVX2_MODULE:
            if not _compiles_with_simd(self.compiler):
                print("piest_jax: the compiler has no AVX2/FMA flags; building the portable kernel only")
                return
            ext.extra_compile_args = [*ext.extra_compile_args, *_SIMD_FLAGS]
        # Both modules compile the same source: separate object folders keep them apart.
        build_temp = self.build_temp
        self.build_temp = os.path.join(build_temp, ext.name.rsplit(".", 1)[1])
        try:
            super().build_extension(ext)
        except Exception as err:  # noqa: BLE001
            print(f"piest_jax: skipping the compiled play kernel {ext.name} ({err})")
        finally:
            self.build_temp = build_temp


def _extension(name: str, include: str) -> Extension:
    return Extension(
        name,
        sources=["piest_jax/_operators/kernel/play_kernel.cc"],
        include_dirs=[include],
        # The binding loads the kernel only under this same jaxlib (pip's isolated build can
        # compile against a newer jaxlib than the one installed beside the package).
        define_macros=[
            ("PIEST_JAXLIB_VERSION", f'"{_jaxlib_version()}"'),
            ("PIEST_MODULE", name.rsplit(".", 1)[1]),
        ],
        language="c++",
        extra_compile_args=["-O3", "-g0", "-std=c++17", "-fvisibility=hidden", "-w"],
        extra_link_args=["-pthread"],
        optional=True,
    )


def _extensions() -> list[Extension]:
    if os.environ.get("PIEST_KERNEL_BUILD", "1") == "0":
        return []
    include = _jax_include()
    if include is None:
        print("piest_jax: jax FFI headers not found; skipping the compiled play kernel")
        return []
    names = ["piest_jax._operators.kernel._play_kernel"]
    if os.environ.get("PIEST_KERNEL_NATIVE", "1") != "0":
        names.append(_AVX2_MODULE)
    return [_extension(name, include) for name in names]


setup(ext_modules=_extensions(), cmdclass={"build_ext": OptionalBuildExt})
