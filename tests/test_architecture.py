"""The layering of `drivers`, `calib_free` and `headctl`, checked on their import graph.

The graph is read from the source with `ast`, not by importing: every `import` and
`from ... import` (at module level, inside functions, under `if TYPE_CHECKING:`) and every
`importlib.import_module("literal")` is an edge. `from pkg import name` is an edge to
`pkg.name` when that is a module, else to `pkg`; importing `a.b.c` also imports the packages
`a` and `a.b` (their `__init__`), except those that hold the importing module itself (they are
imported before it in any case). The rules: no circle; `drivers` and `calib_free` import
neither each other nor `headctl`; the service never imports the API, the ROS 2 interface, the
Foxglove view or the CLI, the config none of the last three, the ROS 2 interface and the
Foxglove view not the API; nothing but the CLI imports the CLI; benchmarks never import the
tests. Also: no folder of the three
packages holds more than 15 modules directly, no module has more than 600 lines.
"""
from __future__ import annotations

import ast
import textwrap
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("drivers", "calib_free", "headctl")
SCANNED = (*PACKAGES, "benchmarks")  # benchmarks: for the rule about tests only
MAX_FOLDER_MODULES = 15
MAX_MODULE_LINES = 600

Graph = Mapping[str, Mapping[str, int]]  # module -> {imported module: line of the first import}


@dataclass(frozen=True)
class Rule:
    """Modules under `importer` may not import modules under `imported` (dotted prefixes)."""

    importer: str
    imported: str


FORBIDDEN = (
    Rule("drivers", "calib_free"), Rule("drivers", "headctl"),
    Rule("calib_free", "drivers"), Rule("calib_free", "headctl"),
    Rule("headctl.service", "headctl.api"), Rule("headctl.service", "headctl.ros2"),
    Rule("headctl.config", "headctl.ros2"), Rule("headctl.ros2", "headctl.api"),
    Rule("headctl.service", "headctl.foxglove"), Rule("headctl.config", "headctl.foxglove"),
    Rule("headctl.foxglove", "headctl.api"), Rule("headctl.ros2", "headctl.foxglove"),
    *(Rule(f"headctl.{part}", "headctl.cli")
      for part in ("service", "experiments", "setup", "config", "api", "ros2", "foxglove")),
    Rule("benchmarks", "tests"),
)


def under(module: str, prefix: str) -> bool:
    return module == prefix or module.startswith(prefix + ".")


def find_modules(root: Path, packages: Iterable[str]) -> dict[str, Path]:
    """Dotted module name -> source file, for every `.py` file of `packages` under `root`."""
    modules: dict[str, Path] = {}
    for package in packages:
        for path in sorted((root / package).rglob("*.py")):
            parts = path.relative_to(root).with_suffix("").parts
            modules[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return modules


def imported_names(tree: ast.AST, package: str) -> Iterator[tuple[str, str | None, int]]:
    """(module, name or None, line) of each import in `tree`; `package` resolves relative ones."""
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield alias.name, None, node.lineno
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[: len(package.split(".")) - (node.level - 1)]
                base = ".".join([*anchor, *([base] if base else [])])
            for alias in node.names:
                yield base, alias.name, node.lineno
        elif (isinstance(node, ast.Call) and node.args and isinstance(node.args[0], ast.Constant)
              and isinstance(node.args[0].value, str) and not node.args[0].value.startswith(".")
              and ((isinstance(node.func, ast.Attribute) and node.func.attr == "import_module")
                   or (isinstance(node.func, ast.Name) and node.func.id in ("import_module", "__import__")))):
            yield node.args[0].value, None, node.lineno


def import_graph(root: Path, packages: Iterable[str]) -> Graph:
    """Each module's imports: modules of `packages` by their own name, others (numpy, tests) as
    written."""
    modules = find_modules(root, packages)

    def resolve(name: str) -> str:
        probe = name
        while probe and probe not in modules:
            probe = probe.rpartition(".")[0]
        return probe or name

    graph: dict[str, dict[str, int]] = {}
    for module, path in modules.items():
        package = module if path.name == "__init__.py" else module.rpartition(".")[0]
        own = {".".join(module.split(".")[:i]) for i in range(1, module.count(".") + 2)}
        edges: dict[str, int] = {}
        for base, name, line in imported_names(ast.parse(path.read_text(), str(path)), package):
            target = f"{base}.{name}" if name and f"{base}.{name}" in modules else resolve(base)
            parts = target.split(".")
            for i in range(1, len(parts) + 1):
                implied = ".".join(parts[:i])
                if (implied == target or implied in modules) and implied not in own:
                    edges[implied] = min(line, edges.get(implied, line))
        graph[module] = edges
    return graph


def circles(graph: Graph) -> list[list[str]]:
    """The strongly connected components of more than one module, each sorted (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in graph.get(v, {}):
            if w not in graph:
                continue  # outside the scanned packages: imports nothing we know of
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return sorted(found)


def forbidden_imports(graph: Graph, rules: Iterable[Rule] = FORBIDDEN) -> list[tuple[str, str, int]]:
    """(importer, imported, line) breaking a rule; a package implied by a reported submodule
    of it (`a` by `a.b`) is left out."""
    rules = tuple(rules)
    found = []
    for importer, edges in sorted(graph.items()):
        bad = {t: line for t, line in edges.items()
               if any(under(importer, r.importer) and under(t, r.imported) for r in rules)}
        found += [(importer, t, line) for t, line in sorted(bad.items())
                  if not any(other != t and under(other, t) for other in bad)]
    return found


def crowded_folders(root: Path, packages: Iterable[str], limit: int = MAX_FOLDER_MODULES) -> list[str]:
    """Folders with more than `limit` modules directly in them (`__init__.py` not counted)."""
    found = []
    for package in packages:
        for folder in sorted({p.parent for p in (root / package).rglob("*.py")}):
            count = sum(1 for p in folder.glob("*.py") if p.name != "__init__.py")
            if count > limit:
                found.append(f"{folder.relative_to(root)}: {count} modules")
    return found


def long_modules(root: Path, packages: Iterable[str], limit: int = MAX_MODULE_LINES) -> list[str]:
    found = []
    for path in find_modules(root, packages).values():
        lines = len(path.read_text().splitlines())
        if lines > limit:
            found.append(f"{path.relative_to(root)}: {lines} lines")
    return found


def describe_circle(graph: Graph, component: list[str], modules: Mapping[str, Path]) -> str:
    """The circle's modules, then each import between them with its file and line."""
    members = set(component)
    edges = [f"    {a} -> {b} ({modules[a].relative_to(ROOT)}:{line})"
             for a in component for b, line in sorted(graph[a].items()) if b in members]
    return "  " + " <-> ".join(component) + "\n" + "\n".join(edges)


def test_no_import_circles() -> None:
    graph = import_graph(ROOT, SCANNED)
    found = circles(graph)
    modules = find_modules(ROOT, SCANNED)
    assert not found, "import circles:\n" + "\n".join(describe_circle(graph, c, modules) for c in found)


def test_layers_import_only_what_they_may() -> None:
    found = forbidden_imports(import_graph(ROOT, SCANNED))
    modules = find_modules(ROOT, SCANNED)
    assert not found, "forbidden imports:\n" + "\n".join(
        f"  {a} -> {b} ({modules[a].relative_to(ROOT)}:{line})" for a, b, line in found)


def test_no_folder_holds_more_than_15_modules() -> None:
    assert not (found := crowded_folders(ROOT, PACKAGES)), "crowded folders:\n  " + "\n  ".join(found)


def test_no_module_is_longer_than_600_lines() -> None:
    assert not (found := long_modules(ROOT, PACKAGES)), "long modules:\n  " + "\n  ".join(found)


def test_the_graph_holds_every_module_and_its_imports() -> None:
    graph = import_graph(ROOT, PACKAGES)
    assert set(graph) == set(find_modules(ROOT, PACKAGES)) and len(graph) > 50
    assert "headctl.service.daemon" in graph["headctl.cli.service"]


# The checker on a tree made for it: it must find exactly what was put there.

def write_tree(root: Path, files: Mapping[str, str]) -> None:
    for name, text in files.items():
        path = root / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(textwrap.dedent(text))


def test_the_checker_reports_a_circle_and_a_forbidden_import(tmp_path: Path) -> None:
    write_tree(tmp_path, {
        "drivers/__init__.py": "",
        "drivers/bus/__init__.py": "",
        "drivers/bus/a.py": "from . import b\nVALUE = 1\n",
        "drivers/bus/b.py": "def later():\n    import drivers.bus.a\n",
        "drivers/free.py": "from drivers.bus.a import VALUE\nimport numpy\n",
        "calib_free/__init__.py": "",
        "calib_free/c.py": "import importlib\nimportlib.import_module('drivers.free')\n",
        "headctl/__init__.py": "",
        "headctl/ok.py": "from calib_free import c\nfrom drivers.bus import a\n",
        "benchmarks/__init__.py": "",
        "benchmarks/bench.py": "from tests.support import helper\n",
    })
    graph = import_graph(tmp_path, (*PACKAGES, "benchmarks"))
    assert graph["drivers.bus.a"] == {"drivers.bus.b": 1}  # its own packages are not edges
    assert graph["drivers.free"] == {"drivers.bus": 1, "drivers.bus.a": 1, "numpy": 2}
    assert graph["headctl.ok"] == {"calib_free": 1, "calib_free.c": 1, "drivers": 2, "drivers.bus": 2,
                                   "drivers.bus.a": 2}
    assert circles(graph) == [["drivers.bus.a", "drivers.bus.b"]]
    assert forbidden_imports(graph) == [("benchmarks.bench", "tests.support", 1),
                                        ("calib_free.c", "drivers.free", 2)]


def test_the_checker_reports_crowded_folders_and_long_modules(tmp_path: Path) -> None:
    write_tree(tmp_path, {f"headctl/many/m{i}.py": "" for i in range(16)}
               | {f"headctl/few/m{i}.py": "" for i in range(15)}
               | {"drivers/__init__.py": "", "drivers/long.py": "x = 1\n" * 601, "drivers/fits.py": "x = 1\n" * 600,
                  "calib_free/__init__.py": ""})
    assert crowded_folders(tmp_path, PACKAGES) == ["headctl/many: 16 modules"]
    assert long_modules(tmp_path, PACKAGES) == ["drivers/long.py: 601 lines"]
