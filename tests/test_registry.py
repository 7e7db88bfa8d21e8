"""Registries by discovery: a module holding a concrete subclass is all it takes to register it."""

import importlib
import textwrap

import pytest

from piest_jax._registry import discover


def _package(monkeypatch, tmp_path, name, modules):
    """Write a package of `modules` (name -> source) under tmp_path and import it."""
    root = tmp_path / name
    root.mkdir()
    (root / "__init__.py").write_text("")
    for mod, body in modules.items():
        (root / f"{mod}.py").write_text(textwrap.dedent(body))
    monkeypatch.syspath_prepend(str(tmp_path))
    importlib.invalidate_caches()
    return importlib.import_module(name)


BASE = """
class Base:
    pass
"""


def test_discovery_finds_each_module_and_orders_by_listed(tmp_path, monkeypatch):
    pkg = _package(
        monkeypatch,
        tmp_path,
        "reg_ok",
        {
            "base": BASE,
            "zeta": "from .base import Base\nclass Zeta(Base):\n    listed = 0\n",
            "alpha": "from .base import Base\nclass Alpha(Base):\n    listed = 2\n",
            # Importing another module's class does not register it twice.
            "mid": "from .base import Base\nfrom .zeta import Zeta\nclass Mid(Base):\n    listed = 1\n",
        },
    )
    base = importlib.import_module("reg_ok.base").Base
    found = discover(pkg.__name__, pkg.__path__, base)
    assert [type(x).__name__ for x in found] == ["Zeta", "Mid", "Alpha"]


def test_discovery_refuses_a_shared_or_missing_number(tmp_path, monkeypatch):
    pkg = _package(
        monkeypatch,
        tmp_path,
        "reg_dup",
        {
            "base": BASE,
            "a": "from .base import Base\nclass A(Base):\n    listed = 3\n",
            "b": "from .base import Base\nclass B(Base):\n    listed = 3\n",
        },
    )
    base = importlib.import_module("reg_dup.base").Base
    with pytest.raises(TypeError, match="B and A in reg_dup share the `listed` number 3"):
        discover(pkg.__name__, pkg.__path__, base)
    pkg = _package(
        monkeypatch,
        tmp_path,
        "reg_missing",
        {"base": BASE, "c": "from .base import Base\nclass C(Base):\n    pass\n"},
    )
    base = importlib.import_module("reg_missing.base").Base
    with pytest.raises(TypeError, match="C in reg_missing does not state its `listed` number"):
        discover(pkg.__name__, pkg.__path__, base)


def test_a_new_input_family_is_one_module(tmp_path, monkeypatch):
    # What adding a family takes: one module with a final subclass; the registry finds it.
    body = """
        import jax.numpy as jnp
        from piest_jax._excitation.family import AbstractInputFamily, common

        class Square(AbstractInputFamily):
            name = "square"
            listed = 10

            def n_uniforms(self, T):
                return 4

            def input(self, v, t, r):
                a, f, o, p = common(v, r[-1])
                return o + a * jnp.sign(jnp.sin(2 * jnp.pi * f * t + p))
        """
    pkg = _package(monkeypatch, tmp_path, "more_families", {"square": body})
    from piest_jax._excitation.family import AbstractInputFamily

    (found,) = discover(pkg.__name__, pkg.__path__, AbstractInputFamily)
    assert found.name == "square" and found.n_uniforms(100) == 4
