"""Registries filled by discovery: a package whose every module holds concrete subclasses of a base.

The named effects of the diagnosis (`_diagnosis/effects/`) and the Monte Carlo input families
(`_excitation/families/`) are registered this way, so adding one is adding one module: no list to
edit elsewhere. Each class states its `listed` position, which fixes the order the registry lists
them in (and so the indices that reports record): a new one takes the next free number.
"""

import importlib
import pkgutil
from collections.abc import Iterable


def discover(package: str, path: Iterable[str], base: type) -> tuple:
    """One instance of every concrete subclass of `base` defined in the modules of a package.

    **Arguments:** `package`, the package's dotted name; `path`, its `__path__`; `base`, the
    abstract class whose subclasses are collected (those whose own module is one of the package's).

    **Returns:** the instances, ordered by their class's `listed` number.
    """
    found = []
    for info in sorted(pkgutil.iter_modules(path), key=lambda m: m.name):
        module = importlib.import_module(f"{package}.{info.name}")
        for obj in vars(module).values():
            if (
                isinstance(obj, type)
                and issubclass(obj, base)
                and obj is not base
                and obj.__module__ == module.__name__
            ):
                found.append(obj())
    numbers: dict[int, str] = {}
    for item in found:
        n = getattr(type(item), "listed", None)
        if not isinstance(n, int):
            raise TypeError(f"{type(item).__name__} in {package} does not state its `listed` number")
        if n in numbers:
            raise TypeError(f"{type(item).__name__} and {numbers[n]} in {package} share the `listed` number {n}")
        numbers[n] = type(item).__name__
    return tuple(sorted(found, key=lambda item: type(item).listed))
