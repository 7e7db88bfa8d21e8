"""Build of the optional compiled play kernel; all other metadata lives in pyproject.toml.

The extension is built against the XLA FFI headers shipped with jax (`jax.ffi.include_dir()`). It
is optional: when no C++ compiler is present or the build fails, installation continues and the
package falls back to the pure-JAX scan. Set PIEST_KERNEL_BUILD=0 to skip it, and
PIEST_KERNEL_NATIVE=0 to build without the AVX2/FMA flags chosen when the build machine has them.
"""

import os
import sysconfig

from setuptools import Extension, setup
from setuptools.command.build_ext import build_ext


def _cpu_flags() -> set[str]:
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("flags"):
                    return set(line.split(":", 1)[1].split())
    except OSError:
        pass
    return set()


def _simd_args() -> list[str]:
    if os.environ.get("PIEST_KERNEL_NATIVE", "1") == "0":
        return []
    if sysconfig.get_platform().endswith("x86_64") and {"avx2", "fma"} <= _cpu_flags():
        return ["-mavx2", "-mfma"]
    return []


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
            "piest_jax._kernel._play_kernel",
            sources=["piest_jax/_kernel/play_kernel.cc"],
            include_dirs=[include],
            language="c++",
            extra_compile_args=["-O3", "-std=c++17", "-fvisibility=hidden", "-w", *_simd_args()],
            extra_link_args=["-pthread"],
            optional=True,
        )
    ]


setup(ext_modules=_extensions(), cmdclass={"build_ext": OptionalBuildExt})
