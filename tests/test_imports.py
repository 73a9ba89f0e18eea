"""Who may import whom: the table of docs/architecture.md ("Packages") is the rule, read from the page,
checked against the imports of the installed package's source; and no import cycle between its modules."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

import online_backlash
from online_backlash._moved import MOVED_MODULES

PACKAGE = Path(online_backlash.__file__).resolve().parent
ARCHITECTURE = Path(__file__).resolve().parents[1] / "docs" / "architecture.md"


def _source_files() -> dict[str, tuple[str, Path]]:
    """Module name -> (its package, its file); ``drivers/`` and ``replay/`` are mapped into
    ``online_backlash`` from the repository's top level, so they are walked from their own paths."""
    import online_backlash.drivers
    import online_backlash.replay

    roots = {"online_backlash": PACKAGE}
    roots.update({p.__name__: Path(p.__path__[0]).resolve() for p in (online_backlash.drivers, online_backlash.replay)})
    modules = {}
    for name, root in roots.items():
        for path in sorted(root.rglob("*.py")):
            package = ".".join((name, *path.relative_to(root).parent.parts))
            modules[package if path.stem == "__init__" else f"{package}.{path.stem}"] = (package, path)
    return modules


MODULES = _source_files()


def _is_type_checking(node: ast.AST) -> bool:
    test = node.test if isinstance(node, ast.If) else None
    return isinstance(test, ast.Name | ast.Attribute) and ast.unparse(test).endswith("TYPE_CHECKING")


def _import_nodes(tree: ast.Module, at_import_time: bool) -> list[ast.Import | ast.ImportFrom]:
    """The import statements of a module: all of them, or those run when it is imported (not inside a
    function, nor under ``if TYPE_CHECKING:``)."""
    found, todo = [], list(tree.body)
    while todo:
        node = todo.pop()
        if isinstance(node, ast.Import | ast.ImportFrom):
            found.append(node)
        elif at_import_time and (isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef | ast.Lambda)):
            continue
        elif at_import_time and _is_type_checking(node):
            continue
        else:
            todo.extend(ast.iter_child_nodes(node))
    return found


def imported_modules(module: str, at_import_time: bool = False) -> set[str]:
    """The modules of ours that ``module`` imports (relative imports resolved; ``from package import name``
    is the submodule when ``name`` is one, else the package)."""
    package, path = MODULES[module]
    out = set()
    for node in _import_nodes(ast.parse(path.read_text(encoding="utf-8")), at_import_time):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
            continue
        base = package.rsplit(".", node.level - 1)[0] if node.level > 1 else package
        source = (f"{base}.{node.module}" if node.module else base) if node.level else node.module or ""
        subs = [f"{source}.{a.name}" for a in node.names]
        out.update(m for m in subs if m in MODULES)
        if any(m not in MODULES for m in subs):
            out.add(source)
    return {m for m in out if m == "online_backlash" or m.startswith("online_backlash.")} - {module}


# -- the rule: docs/architecture.md's table ------------------------------------------------------------------------


def _names(cell: str) -> list[str]:
    """The names in backticks of a table cell, outside parentheses (which say why), ``/`` and ``.py`` dropped."""
    cell = re.sub(r"\([^()]*\)", "", cell)
    return [n.rstrip("/").removesuffix(".py").replace("/", ".") for n in re.findall(r"`([^`]+)`", cell)]


def documented_rules() -> dict[str, tuple[str, ...] | None]:
    """Module or package (``output_columns``, ``history``, ``__init__``) -> what it may import (None: anything)."""
    text = ARCHITECTURE.read_text(encoding="utf-8")
    table = text.split("## Packages", 1)[1].split("\n## ", 1)[0]
    rules: dict[str, tuple[str, ...] | None] = {}
    for line in table.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if len(cells) != 3 or cells[0] in ("package", "---"):
            continue
        layers, allowed = _names(cells[0]), cells[2]
        if allowed == "as their packages":  # modules already in their packages' rows
            continue
        assert layers, f"docs/architecture.md: a row without a module: {line}"
        may = None if allowed == "anything" else () if allowed == "nothing of ours" else tuple(_names(allowed))
        assert may is None or may or allowed == "nothing of ours", f"docs/architecture.md: name the modules: {line}"
        for layer in layers:
            assert layer not in rules, f"docs/architecture.md: {layer} has two rows"
            rules[layer] = may
    return rules


RULES = documented_rules()


def _layer_of(module: str) -> str | None:
    """The row of the table a module of ours falls under: the longest name that is it or holds it."""
    if module == "online_backlash":
        return "__init__"
    name = module.removeprefix("online_backlash.")
    owners = [r for r in RULES if name == r or name.startswith(r + ".")]
    return max(owners, key=len) if owners else None


def test_the_table_is_read():
    assert {
        "stream",
        "output_columns",
        "estimators",
        "history",
        "replay",
        "drivers",
        "codecs",
        "simulation",
        "cli",
    } <= set(RULES)
    assert RULES["physical"] == () and RULES["cli"] is None
    assert RULES["publish"] == ("output_columns", "stream", "history.alarms", "errors")


def test_every_module_is_under_a_row_of_the_table():
    unruled = sorted(m for m in MODULES if _layer_of(m) is None)
    assert not unruled, f"modules no row of docs/architecture.md's table names: {unruled}"


@pytest.mark.parametrize("layer", sorted(RULES))
def test_who_may_import_whom(layer):
    may = RULES[layer]
    if may is None:
        return
    allowed = tuple(f"online_backlash.{m}" for m in may)
    for module in MODULES:
        if _layer_of(module) != layer:
            continue
        for imported in sorted(imported_modules(module)):
            if _layer_of(imported) == layer or any(imported == a or imported.startswith(a + ".") for a in allowed):
                continue
            pytest.fail(f"{module} ({layer}) imports {imported}: docs/architecture.md lets {layer} import only {may}")


def test_the_library_never_imports_the_cli_nor_an_old_name():
    old = set(MOVED_MODULES)  # the old names of moved or renamed modules, kept for users: the library imports none
    for module in MODULES:
        imported = imported_modules(module)
        if not module.startswith("online_backlash.cli"):
            assert not {m for m in imported if m.startswith("online_backlash.cli")}, f"{module} imports the CLI"
        moved = sorted(imported & old)
        assert not moved, f"{module} imports {moved}: import their new names ({[MOVED_MODULES[m] for m in moved]})"


# -- no cycles -----------------------------------------------------------------------------------------------------


def cycles_of(graph: dict[str, set[str]]) -> list[list[str]]:
    """The groups of nodes that reach each other round a cycle (Tarjan's strongly connected components of
    more than one node), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    cycles = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = []
            while True:
                w = stack.pop()
                group.append(w)
                if w == v:
                    break
            if len(group) > 1:
                cycles.append(sorted(group))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return cycles


def import_cycles(at_import_time: bool) -> list[list[str]]:
    """The groups of modules of ours that import each other round a cycle."""
    return cycles_of({m: imported_modules(m, at_import_time) & MODULES.keys() for m in MODULES})


def test_the_cycle_finder_finds_cycles():
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a", "d"}, "d": set(), "e": {"d", "e"}, "f": {"g"}, "g": {"f"}}
    assert sorted(cycles_of(graph)) == [["a", "b", "c"], ["f", "g"]]


def test_no_import_cycle_when_a_module_is_imported():
    assert import_cycles(at_import_time=True) == []


#: cycles closed only by an import inside a function, left for the estimator contract (issue 29 item 2):
#: ``full_engagement._slope`` reads ``batch._direction_guess``, and batch imports full_engagement
LEFT_FOR_LATER = [
    {f"online_backlash.estimators.{m}" for m in ("batch", "full_engagement", "uncertainty")},
]


def test_no_import_cycle_through_imports_in_functions_but_those_left_for_later():
    new = [c for c in import_cycles(at_import_time=False) if not any(set(c) <= known for known in LEFT_FOR_LATER)]
    assert new == []


# -- private names stay in their package ---------------------------------------------------------------------------


def _private_owner(dotted: str) -> str | None:
    """The package that owns ``dotted`` (a module, or a module's name) if a part of it is private (``_x``, not a
    dunder): the package holding its first private part (a private module's package, a private name's module's
    package); None if it is public."""
    parts = dotted.split(".")
    for i, part in enumerate(parts):
        if part.startswith("_") and not part.startswith("__"):
            holder = ".".join(parts[:i])
            return MODULES[holder][0] if holder in MODULES else holder or None
    return None


def private_imports(module: str) -> list[str]:
    """What ``module`` imports (modules and names, relative imports resolved) that is private to a package
    it is not in."""
    package, path = MODULES[module]
    found = []
    for node in _import_nodes(ast.parse(path.read_text(encoding="utf-8")), False):
        if isinstance(node, ast.Import):
            targets = [a.name for a in node.names]
        else:
            base = package.rsplit(".", node.level - 1)[0] if node.level > 1 else package
            source = (f"{base}.{node.module}" if node.module else base) if node.level else node.module or ""
            targets = [f"{source}.{a.name}" for a in node.names]
        for target in targets:
            owner = _private_owner(target)
            if owner and owner.startswith("online_backlash") and not (module + ".").startswith(owner + "."):
                found.append(target)
    return found


def test_the_private_owner_is_the_package_holding_the_name():
    assert _private_owner("online_backlash.estimators._rls_kernels.S") == "online_backlash.estimators"
    assert _private_owner("online_backlash.estimators.batch._start_params") == "online_backlash.estimators"
    assert _private_owner("online_backlash.estimators.base.RecursiveEstimator") is None


@pytest.mark.parametrize("package", ["online_backlash.estimators", "online_backlash.load_aware"])
def test_no_module_outside_a_package_imports_its_private_names(package):
    """A package's private modules and names (``_base``, ``batch._start_params``) are its own: a module outside it
    imports its public ones (``estimators.base``, ``estimators.validation``, ``estimators.layout``)."""
    leaks = {m: names for m in MODULES if (names := [n for n in private_imports(m) if n.startswith(package + ".")])}
    assert not leaks, f"modules outside {package} import its private names: {leaks}"
