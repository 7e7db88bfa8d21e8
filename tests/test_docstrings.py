"""Documentation: every public name is documented, and the command-line help says what it writes.

Public names are `piest_jax.__all__` when it exists, else every name in `dir(piest_jax)` that does
not start with an underscore. A public function or class taking arguments must document them
under **Arguments:** (or, for a class whose fields are its arguments, **Fields:**); a function that
returns something must say what under **Returns:**. Public methods and properties need a docstring
(inherited ones count).
"""

import inspect
import re
import typing

import pytest

import piest_jax
from piest_jax._cli import COMMANDS, build_parser


def _public_names() -> list[str]:
    names = getattr(piest_jax, "__all__", None)
    if names is None:
        names = [n for n in dir(piest_jax) if not n.startswith("_")]
    return sorted(n for n in names if not inspect.ismodule(getattr(piest_jax, n)))


PUBLIC = _public_names()


def _parameters(obj) -> list[str]:
    target = obj.__init__ if inspect.isclass(obj) else obj
    try:
        sig = inspect.signature(target)
    except (TypeError, ValueError):
        return []
    return [p for p in sig.parameters if p not in ("self", "cls")]


def _returns_something(fn) -> bool:
    try:
        hints = typing.get_type_hints(fn)
    except Exception:
        hints = getattr(fn, "__annotations__", {})
    if "return" in hints:
        return hints["return"] is not type(None)
    src = inspect.getsource(fn)
    return re.search(r"^\s+return\s+\S", src, re.M) is not None


def _problems(name: str) -> list[str]:
    obj = getattr(piest_jax, name)
    doc = inspect.getdoc(obj)
    if not doc or not doc.strip():
        return [f"{name}: no docstring"]
    problems = []
    if inspect.isclass(obj):
        is_abstract = name.startswith("Abstract")
        has_fields = "**Fields:**" in doc
        if _parameters(obj) and not is_abstract and not (has_fields or "**Arguments:**" in doc):
            problems.append(f"{name}: class docstring lacks **Arguments:** (or **Fields:**)")
        for attr, member in vars(obj).items():
            if attr.startswith("_") or not (inspect.isfunction(member) or isinstance(member, property)):
                continue
            if not inspect.getdoc(getattr(obj, attr, member)) and not _inherited_doc(obj, attr):
                problems.append(f"{name}.{attr}: no docstring")
    elif callable(obj):
        if _parameters(obj) and "**Arguments:**" not in doc:
            problems.append(f"{name}: docstring lacks **Arguments:**")
        if _returns_something(obj) and "**Returns:**" not in doc:
            problems.append(f"{name}: docstring lacks **Returns:**")
    return problems


def _inherited_doc(cls, attr: str) -> bool:
    for base in cls.__mro__[1:]:
        member = base.__dict__.get(attr)
        if member is not None and inspect.getdoc(member):
            return True
    return False


def test_public_api_is_not_empty():
    assert {"play", "stop", "PIOperator", "inverse"} <= set(PUBLIC)


@pytest.mark.parametrize("name", PUBLIC)
def test_public_name_is_documented(name):
    assert _problems(name) == []


def test_checker_catches_missing_sections():
    def documented(a, b):
        """Add.

        **Arguments:** `a`, `b`.

        **Returns:** the sum.
        """
        return a + b

    def bare(a):
        """Add one."""
        return a + 1

    piest_jax._doc_probe_documented = documented
    piest_jax._doc_probe_bare = bare
    try:
        assert _problems("_doc_probe_documented") == []
        assert _problems("_doc_probe_bare") == [
            "_doc_probe_bare: docstring lacks **Arguments:**",
            "_doc_probe_bare: docstring lacks **Returns:**",
        ]
    finally:
        del piest_jax._doc_probe_documented, piest_jax._doc_probe_bare


def _help(argv, capsys) -> str:
    parser = build_parser()
    with pytest.raises(SystemExit) as exc:
        parser.parse_args(argv)
    assert exc.value.code == 0
    return capsys.readouterr().out


def test_top_level_help_lists_every_command_and_says_where_results_go(capsys):
    text = _help(["--help"], capsys)
    assert "--out" in text and "writes" in text
    for mod in COMMANDS:
        assert mod.NAME in text


@pytest.mark.parametrize("mod", COMMANDS, ids=[m.NAME for m in COMMANDS])
def test_command_help_says_what_it_writes_and_where(mod, capsys):
    text = _help([mod.NAME, "--help"], capsys)
    flat = " ".join(text.split())
    assert re.search(r"\bwrites?\b", flat, re.I), f"`piest {mod.NAME} --help` never says what it writes"
    assert "DIR/" in text, "the written files should be named as DIR/<file>"
    for name in getattr(mod, "OUTPUTS", ()):
        if "{" not in name:
            assert f"DIR/{name}" in text or name in text, f"{name} is written but not mentioned"
    assert "--out" in text and "--force" in text and "--quiet" in text
    assert re.search(rf"example:\s+piest {mod.NAME}\b", text), "the help should show one example"
