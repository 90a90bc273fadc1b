"""The shape of the code in ``sb3_emmarl`` and ``wildlife_reserve``, read with ``ast`` (nothing is imported).

- **Positional parameters**: no function other than ``__init__`` (an algorithm's constructor mirrors SB3's, where
  every argument may come by position) takes more than :data:`MAX_POSITIONAL` positional parameters, ``self`` and
  ``cls`` not counted. Further ones are keyword-only, or travel together in a small record (a ``NamedTuple``, which
  numba compiles too).
- **Import cycles**: the graph of the packages' modules has no cycle. An edge ``a -> b`` is an import statement of
  module ``a`` that runs when ``a`` is imported: at module level, in a class body, or under any ``if``/``try`` there,
  ``if TYPE_CHECKING:`` included (a type-only cycle still ties the two modules together). Imports inside a function
  run when it is called and are left out. ``from p import x`` is an edge to ``p.x`` when that is a module, else to
  ``p`` (its ``__init__``). Importing a module also runs its parent packages' ``__init__``, which is not counted as an
  edge: a package that imports (re-exports) its own submodules makes no cycle unless a submodule imports that package
  back by name.
"""

from __future__ import annotations

import ast
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: The packages read, by import name, and their folders.
PACKAGES = {"sb3_emmarl": ROOT / "sb3_emmarl", "wildlife_reserve": ROOT / "envs" / "wildlife_reserve"}
#: The most positional parameters a function other than ``__init__`` takes.
MAX_POSITIONAL = 8


def modules(packages: dict[str, Path]) -> dict[str, Path]:
    """Every module of ``packages`` (import name -> file), packages as their ``__init__.py``."""
    found = {}
    for name, folder in packages.items():
        for path in sorted(folder.rglob("*.py")):
            parts = [name, *path.relative_to(folder).with_suffix("").parts]
            if parts[-1] == "__init__":
                parts.pop()
            found[".".join(parts)] = path
    return found


# ---------------------------------------------------------------------------------------------- positional parameters
def positional_counts(tree: ast.Module) -> Iterator[tuple[str, int, int]]:
    """``(qualified name, line, positional parameters)`` of every function in ``tree`` (``self`` / ``cls`` of a method
    not counted; a ``staticmethod`` has neither)."""
    def visit(node: ast.AST, prefix: str, in_class: bool) -> Iterator[tuple[str, int, int]]:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                names = [arg.arg for arg in child.args.posonlyargs + child.args.args]
                static = any(isinstance(d, ast.Name) and d.id == "staticmethod" for d in child.decorator_list)
                if in_class and not static and names:
                    names = names[1:]
                yield f"{prefix}{child.name}", child.lineno, len(names)
                yield from visit(child, f"{prefix}{child.name}.", False)
            elif isinstance(child, ast.ClassDef):
                yield from visit(child, f"{prefix}{child.name}.", True)
            else:
                yield from visit(child, prefix, in_class)

    yield from visit(tree, "", False)


def test_positional_counts_leave_out_self_and_keyword_only_parameters():
    tree = ast.parse("def f(a, b, /, c, *args, d, e=1, **kw): pass\n"
                     "class C:\n"
                     "    def m(self, a, *, b): pass\n"
                     "    @classmethod\n"
                     "    def k(cls, a, b): pass\n"
                     "    @staticmethod\n"
                     "    def s(a, b): pass\n"
                     "    def g(self):\n"
                     "        def inner(x, y, z): pass\n")
    assert list(positional_counts(tree)) == [("f", 1, 3), ("C.m", 3, 1), ("C.k", 5, 2), ("C.s", 7, 2), ("C.g", 8, 0),
                                             ("C.g.inner", 9, 3)]


def test_no_function_but_a_constructor_takes_more_than_eight_positional_parameters():
    offences = [f"{path.relative_to(ROOT)}:{line} {name} takes {count} positional parameters"
                for path in modules(PACKAGES).values()
                for name, line, count in positional_counts(ast.parse(path.read_text(encoding="utf-8")))
                if count > MAX_POSITIONAL and name.rpartition(".")[2] != "__init__"]
    assert not offences, (f"more than {MAX_POSITIONAL} positional parameters (make the rest keyword-only, or pass a "
                          "record):\n" + "\n".join(offences))


# ---------------------------------------------------------------------------------------------- import cycles
@dataclass(frozen=True)
class Edge:
    """An import of module ``target`` by module ``source`` at ``line``, ``typing_only`` under ``if TYPE_CHECKING:``."""

    source: str
    target: str
    line: int
    typing_only: bool


def _is_type_checking(test: ast.expr) -> bool:
    return (isinstance(test, ast.Name) and test.id == "TYPE_CHECKING") or \
        (isinstance(test, ast.Attribute) and test.attr == "TYPE_CHECKING")


def import_edges(name: str, path: Path, known: dict[str, Path]) -> Iterator[Edge]:
    """The imports of module ``name`` (file ``path``) that run when it is imported, to modules of ``known``."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]

    def owner(dotted: str) -> str | None:  # the deepest module of `known` that `dotted` names
        while dotted and dotted not in known:
            dotted = dotted.rpartition(".")[0]
        return dotted or None

    def targets(node: ast.Import | ast.ImportFrom) -> Iterator[str | None]:
        if isinstance(node, ast.Import):
            yield from (owner(alias.name) for alias in node.names)
            return
        base = node.module or ""
        if node.level:
            parent = package.rsplit(".", node.level - 1)[0] if node.level > 1 else package
            base = f"{parent}.{base}" if base else parent
        for alias in node.names:
            yield f"{base}.{alias.name}" if f"{base}.{alias.name}" in known else owner(base)

    def visit(nodes: list[ast.stmt], typing_only: bool) -> Iterator[Edge]:
        for node in nodes:
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                yield from (Edge(name, target, node.lineno, typing_only) for target in targets(node)
                            if target is not None and target != name)
            elif isinstance(node, ast.If):
                yield from visit(node.body, typing_only or _is_type_checking(node.test))
                yield from visit(node.orelse, typing_only)
            elif isinstance(node, ast.Try):
                for block in (node.body, *(handler.body for handler in node.handlers), node.orelse, node.finalbody):
                    yield from visit(block, typing_only)
            elif isinstance(node, (ast.ClassDef, ast.With)):
                yield from visit(node.body, typing_only)

    yield from visit(ast.parse(path.read_text(encoding="utf-8")).body, False)


def import_cycles(packages: dict[str, Path]) -> list[list[Edge]]:
    """The strongly connected components of more than one module in the import graph of ``packages`` (Tarjan), each
    as the edges inside it, sorted."""
    known = modules(packages)
    graph = {name: list(dict.fromkeys(import_edges(name, path, known))) for name, path in known.items()}
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    components: list[set[str]] = []

    def connect(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        for edge in graph[node]:
            if edge.target not in index:
                connect(edge.target)
                low[node] = min(low[node], low[edge.target])
            elif edge.target in stack:
                low[node] = min(low[node], index[edge.target])
        if low[node] == index[node]:
            component = {stack.pop()}
            while node not in component:
                component.add(stack.pop())
            if len(component) > 1:
                components.append(component)

    for node in graph:
        if node not in index:
            connect(node)
    return [sorted((edge for node in component for edge in graph[node] if edge.target in component),
                   key=lambda edge: (edge.source, edge.line)) for component in components]


def test_the_import_graph_counts_type_only_imports_and_not_a_package_importing_its_submodules(tmp_path):
    package = tmp_path / "pkg"
    (package / "sub").mkdir(parents=True)
    files = {
        "__init__.py": "from pkg.a import A\nfrom pkg import b\n",  # a package re-exporting its submodules: no cycle
        "a.py": "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from pkg.b import B\nA = 1\n",
        "b.py": "from .a import A\nB = 2\ndef later():\n    from pkg.c import C\n",  # in a function: left out
        "c.py": "from pkg.b import B\nC = 3\n",
        "sub/__init__.py": "from .d import D\n",
        "sub/d.py": "import pkg.sub\nD = 4\n",  # a submodule importing its package back: a cycle
    }
    for name, text in files.items():
        (package / name).write_text(text)
    cycles = import_cycles({"pkg": package})
    assert sorted([(e.source, e.target, e.line, e.typing_only) for e in cycle] for cycle in cycles) == [
        [("pkg.a", "pkg.b", 3, True), ("pkg.b", "pkg.a", 1, False)],
        [("pkg.sub", "pkg.sub.d", 1, False), ("pkg.sub.d", "pkg.sub", 1, False)],
    ]


def test_no_import_cycle():
    cycles = import_cycles(PACKAGES)
    lines = [" <-> ".join(sorted({edge.source for edge in cycle})) + ":\n" + "\n".join(
        f"    {edge.source} line {edge.line} imports {edge.target}" + (" (under TYPE_CHECKING)" if edge.typing_only
                                                                       else "") for edge in cycle) for cycle in cycles]
    assert not cycles, "import cycles (move the shared names to the module that owns them):\n" + "\n".join(lines)


# ---------------------------------------------------------------------------------------------- folders
def folder_pairs(packages: dict[str, Path]) -> dict[tuple[str, str], list[Edge]]:
    """The imports from one folder (package) to another, by ``(importing folder, imported folder)``: a module's folder
    is its package (a package's ``__init__`` is its own folder's)."""
    known = modules(packages)

    def folder(name: str) -> str:
        return name if known[name].name == "__init__.py" else name.rpartition(".")[0]

    pairs: dict[tuple[str, str], list[Edge]] = {}
    for name, path in known.items():
        for edge in import_edges(name, path, known):
            if folder(edge.source) != folder(edge.target):
                pairs.setdefault((folder(edge.source), folder(edge.target)), []).append(edge)
    return pairs


def test_folder_pairs_find_a_folder_importing_one_that_imports_it_back(tmp_path):
    package = tmp_path / "pkg"
    for sub in ("low", "high"):
        (package / sub).mkdir(parents=True)
        (package / sub / "__init__.py").write_text("")
    (package / "__init__.py").write_text("")
    (package / "low" / "a.py").write_text("from pkg.high.b import B\nA = 1\n")
    (package / "high" / "b.py").write_text("B = 2\ndef later():\n    from pkg.low.a import A\n")  # in a function
    pairs = folder_pairs({"pkg": package})
    assert set(pairs) == {("pkg.low", "pkg.high")}
    (package / "high" / "c.py").write_text("from pkg.low.a import A\n")
    assert ("pkg.high", "pkg.low") in folder_pairs({"pkg": package})


def test_no_folder_imports_a_folder_that_imports_it_back():
    """The folders form layers (``common/trust`` under everything, ``common/appended`` and ``common/vec_env`` under the
    wrappers and ``common/latent``, the evaluation modules of ``common`` over ``latent``; ``reserve/kernels`` under the
    reserve, ``wildlife_reserve/utils`` under both environments): a folder may be read without the ones above it."""
    pairs = folder_pairs(PACKAGES)
    both = sorted((a, b) for a, b in pairs if (b, a) in pairs and a < b)
    assert not both, "folders importing each other:\n" + "\n".join(
        f"  {a} <-> {b}: {pairs[a, b][0].source} imports {pairs[a, b][0].target}; "
        f"{pairs[b, a][0].source} imports {pairs[b, a][0].target}" for a, b in both)


# ---------------------------------------------------------------------------------------------- long functions
#: The most lines a function's body (its docstring left out) has without a comment saying why it is long.
MAX_BODY_LINES = 60
#: What that comment starts with.
LONG_BECAUSE = "# Long because"
#: Exempt: constructors (an algorithm's mirrors SB3's; a config's checks every field) and the compiled kernels.
CONSTRUCTORS = ("__init__", "__post_init__")


def long_functions(path: Path) -> Iterator[tuple[str, int, int]]:
    """``(name, line, body lines)`` of the functions of ``path`` whose body is longer than :data:`MAX_BODY_LINES` and
    that hold no :data:`LONG_BECAUSE` comment."""
    text = path.read_text(encoding="utf-8")
    lines = text.splitlines()
    for node in ast.walk(ast.parse(text)):
        if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)) or node.name in CONSTRUCTORS:
            continue
        body = node.body
        first = body[0]
        if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant) and isinstance(first.value.value, str) \
                and len(body) > 1:
            first = body[1]
        length = (node.end_lineno or node.lineno) - first.lineno + 1
        if length > MAX_BODY_LINES and not any(line.strip().startswith(LONG_BECAUSE)
                                               for line in lines[node.lineno - 1:node.end_lineno]):
            yield node.name, node.lineno, length


def test_long_functions_are_found_unless_they_say_why(tmp_path):
    body = "\n".join(f"    x{i} = {i}" for i in range(MAX_BODY_LINES + 1))
    path = tmp_path / "m.py"
    path.write_text(f'def f():\n    """Doc."""\n{body}\n\ndef __init__():\n{body}\n')
    assert list(long_functions(path)) == [("f", 1, MAX_BODY_LINES + 1)]
    path.write_text(f'def f():\n    {LONG_BECAUSE} it is SB3\'s.\n{body}\n')
    assert not list(long_functions(path))


def test_no_long_function_without_a_comment_saying_why():
    found = [f"{path.relative_to(ROOT)}:{line} {name} ({length} lines)"
             for folder in PACKAGES.values() for path in sorted(folder.rglob("*.py")) if "kernels" not in path.parts
             for name, line, length in long_functions(path)]
    assert not found, (f"functions over {MAX_BODY_LINES} lines without a '{LONG_BECAUSE} ...' comment (split them, or "
                       "say why they are one piece):\n" + "\n".join(found))
