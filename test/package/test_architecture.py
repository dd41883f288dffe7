"""The layout keeps its promises: no import cycles, a core that never imports the ROS or
command-line adapters, no private names across modules, no dead code, benchmarks that import
only the package, and every subpackage says what it holds.

These read the source with ``ast`` (nothing is imported), so they are fast and exact.
"""

from __future__ import annotations

import ast
import importlib
import re
from collections import Counter
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
PACKAGE = ROOT / "eit_skin"
#: Modules that sit directly in eit_skin/ (everything else lives in a subpackage).
TOP_LEVEL = {"__init__", "frames", "resources"}


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


MODULES = {module_name(p): p for p in sorted(PACKAGE.rglob("*.py"))}


def eit_imports(path: Path) -> list[tuple[str, str | None, int]]:
    """``(module, imported name or None, line)`` of every eit_skin import outside TYPE_CHECKING."""
    found: list[tuple[str, str | None, int]] = []

    class Visitor(ast.NodeVisitor):
        def visit_If(self, node: ast.If) -> None:
            test = node.test
            name = getattr(test, "id", None) or getattr(test, "attr", None)
            if name == "TYPE_CHECKING":
                for child in node.orelse:
                    self.visit(child)
                return
            self.generic_visit(node)

        def visit_ImportFrom(self, node: ast.ImportFrom) -> None:
            if node.module and node.module.split(".")[0] == "eit_skin":
                for alias in node.names:
                    sub = f"{node.module}.{alias.name}"
                    found.append((sub if sub in MODULES else node.module, alias.name, node.lineno))

        def visit_Import(self, node: ast.Import) -> None:
            for alias in node.names:
                if alias.name.split(".")[0] == "eit_skin":
                    found.append((alias.name, None, node.lineno))

    Visitor().visit(ast.parse(path.read_text(), str(path)))
    return found


def test_no_import_cycles_between_modules():
    graph = {
        name: {target for target, _, _ in eit_imports(path) if target in MODULES and target != name}
        for name, path in MODULES.items()
    }
    state: dict[str, int] = {}  # 1: on the current path, 2: done
    cycles: list[list[str]] = []

    def visit(node: str, trail: list[str]) -> None:
        state[node] = 1
        for target in sorted(graph[node]):
            if state.get(target) == 1:
                cycles.append([*trail[trail.index(target) :], target])
            elif target not in state:
                visit(target, [*trail, target])
        state[node] = 2

    for name in sorted(graph):
        if name not in state:
            visit(name, [name])
    assert not cycles, "import cycles (function-local imports count too):\n" + "\n".join(
        " -> ".join(c) for c in cycles
    )


#: The adapters (ROS, command line, browser designer): the numerical core (every other
#: subpackage) never imports them.
ADAPTERS = ("eit_skin.ros", "eit_skin.cli", "eit_skin.design")


def test_the_core_knows_nothing_of_ros_or_the_command_line():
    offenders = [
        f"{path.relative_to(ROOT)}:{line} imports {target}"
        for name, path in MODULES.items()
        if not name.startswith(ADAPTERS)
        for target, _, line in eit_imports(path)
        if target.startswith(ADAPTERS)
    ]
    assert not offenders, "\n".join(offenders)


#: Rank of every subpackage (docs/architecture.md, "Layers"): a subpackage imports only
#: subpackages of a lower rank, or of its own rank without a cycle between them. The modules
#: directly in eit_skin/ (``frames``, ``resources``) are rank 0.
LAYERS = {
    "patch": 1,  # the schema: outlines, electrodes, protocol, the solver names
    "io": 1,  # recording formats, beside the core
    "fem": 2,
    "hardware": 2,  # boards and byte formats: the patch's protocol and board profiles
    "inverse": 3,
    "pipeline": 4,
    "touch": 5,
    "sim": 5,
    "calibration": 5,
    "ros": 6,
    "cli": 6,
    "design": 6,  # the browser designer: an adapter like cli
}


def subpackage(module: str) -> str:
    """The subpackage of a module name ("" for the modules directly in eit_skin/)."""
    parts = module.split(".")
    return parts[1] if len(parts) > 2 or (len(parts) == 2 and parts[1] in LAYERS) else ""


def subpackage_imports() -> dict[tuple[str, str], list[str]]:
    """``(importer, imported)`` subpackage -> the imports behind that edge (``path:line``)."""
    edges: dict[tuple[str, str], list[str]] = {}
    for name, path in MODULES.items():
        for target, _, line in eit_imports(path):
            a, b = subpackage(name), subpackage(target)
            if a != b:
                edges.setdefault((a, b), []).append(f"{path.relative_to(ROOT)}:{line} {target}")
    return edges


def layer_violations(edges: dict[tuple[str, str], list[str]]) -> list[str]:
    """Imports that look up (to a higher rank), and cycles between subpackages of one rank."""
    rank = {"": 0, **LAYERS}
    found = [
        f"{a} (rank {rank[a]}) imports {b} (rank {rank[b]}): {where[0]}"
        for (a, b), where in sorted(edges.items())
        if rank[b] > rank[a]
    ]
    sideways = {(a, b) for a, b in edges if rank[a] == rank[b]}

    def reaches(start: str, goal: str, seen: set[str]) -> bool:
        return any(
            b == goal or (b not in seen and reaches(b, goal, seen | {b}))
            for a, b in sideways
            if a == start
        )

    found += [
        f"{a} imports {b} ({edges[a, b][0]}), which imports {a} back"
        for a, b in sorted(sideways)
        if reaches(b, a, {b})
    ]
    return found


def test_subpackages_only_look_down():
    assert set(LAYERS) == {p.parent.name for p in PACKAGE.glob("*/__init__.py")}
    violations = layer_violations(subpackage_imports())
    assert not violations, "\n".join(violations)


def test_a_schema_that_imports_a_solver_is_a_violation():
    # the cycle the layering removed: patch.model named the methods from inverse.methods
    edges = {**subpackage_imports(), ("patch", "inverse"): ["eit_skin/patch/model.py:29"]}
    assert layer_violations(edges) == [
        "patch (rank 1) imports inverse (rank 3): eit_skin/patch/model.py:29"
    ]
    # sideways imports of one rank may not close a cycle, however long
    ring = {("touch", "sim"): ["a"], ("sim", "calibration"): ["b"], ("calibration", "touch"): ["c"]}
    assert layer_violations(ring) == [
        "calibration imports touch (c), which imports calibration back",
        "sim imports calibration (b), which imports sim back",
        "touch imports sim (a), which imports touch back",
    ]


def python_files() -> list[Path]:
    return [*PACKAGE.rglob("*.py"), *(ROOT / "test").rglob("*.py"), *(ROOT / "bench").rglob("*.py")]


def test_no_private_name_is_imported_from_another_module():
    offenders = [
        f"{path.relative_to(ROOT)}:{line} imports {name} from {target}"
        for path in python_files()
        for target, name, line in eit_imports(path)
        if name and name.startswith("_") and not name.startswith("__")
    ]
    assert not offenders, "\n".join(offenders)


def test_benchmarks_import_only_the_package():
    offenders = []
    for path in sorted((ROOT / "bench").rglob("*.py")):
        text = path.read_text()
        tree = ast.parse(text)
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and (node.module or "").split(".")[0] == "test":
                offenders.append(f"{path.name}:{node.lineno} imports {node.module}")
            if isinstance(node, ast.Import) and any(
                a.name.split(".")[0] == "test" for a in node.names
            ):
                offenders.append(f"{path.name}:{node.lineno} imports test")
        if "sys.path" in text:
            offenders.append(f"{path.name} changes sys.path")
    assert not offenders, "\n".join(offenders)


def top_level_names(path: Path) -> list[tuple[str, int]]:
    names = []
    for node in ast.parse(path.read_text()).body:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            names.append((node.name, node.lineno))
        elif isinstance(node, ast.Assign):
            names += [(t.id, node.lineno) for t in node.targets if isinstance(t, ast.Name)]
        elif isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            names.append((node.target.id, node.lineno))
    return [(n, line) for n, line in names if not (n.startswith("__") and n.endswith("__"))]


def test_no_dead_code():
    """Every name defined at the top of a package module is used by some other Python code."""
    sources = {p: p.read_text() for p in [*python_files(), *(ROOT / "launch").glob("*.py")]}
    sources[ROOT / "setup.py"] = (ROOT / "setup.py").read_text()
    # whole-word occurrences of every identifier, counted once over all sources (a regex
    # scan of every source per name took most of a minute)
    words = Counter(word for text in sources.values() for word in re.findall(r"\w+", text))
    unused = []
    for path in MODULES.values():
        for name, line in top_level_names(path):
            uses = words[name] - 1
            if uses <= 0:
                unused.append(f"{path.relative_to(ROOT)}:{line} {name}")
    assert not unused, "defined but never used:\n" + "\n".join(unused)


def test_modules_live_in_subpackages_that_describe_themselves():
    stray = [p.name for p in PACKAGE.glob("*.py") if p.stem not in TOP_LEVEL]
    assert not stray, f"modules outside a subpackage: {stray}"
    for init in sorted(PACKAGE.glob("*/__init__.py")):
        doc = ast.get_docstring(ast.parse(init.read_text()))
        assert doc and len(doc) > 60, f"{init.relative_to(ROOT)} does not say what it holds"
        modules = {p.stem for p in init.parent.glob("*.py")} - {"__init__"}
        mentioned = set(re.findall(r"``(\w+)``", doc))
        assert modules <= mentioned, f"{init.relative_to(ROOT)} does not name {modules - mentioned}"


@pytest.mark.parametrize("init", sorted(PACKAGE.glob("*/__init__.py")), ids=lambda p: p.parent.name)
def test_re_exported_names_resolve(init):
    package = importlib.import_module(module_name(init))
    for name in getattr(package, "__all__", []):
        assert getattr(package, name) is not None, f"{package.__name__}.{name}"


#: Folders of test/ that are not a subpackage of eit_skin (test/README.md): the repository as
#: a whole, several nodes or commands at once, and the shared helpers.
TEST_FOLDERS = {"package", "integration", "support"}


def test_tests_are_laid_out_like_the_package():
    """test/<subpackage>/test_<module>*.py for a module of eit_skin/<subpackage>/; directly in
    test/ only the tests of eit_skin/'s top-level modules; every folder a package (no clash
    between equal basenames in two folders)."""
    tests = ROOT / "test"
    folders = {
        p.name for p in tests.iterdir() if p.is_dir() and p.name not in {"data", "__pycache__"}
    }
    assert folders - TEST_FOLDERS <= set(LAYERS), (
        f"test/ folders for no subpackage: {folders - TEST_FOLDERS - set(LAYERS)}"
    )
    missing_init = [f for f in sorted(folders) if not (tests / f / "__init__.py").exists()]
    assert not missing_init, f"test/ folders without __init__.py: {missing_init}"
    stray = [
        p.name
        for p in sorted(tests.glob("test_*.py"))
        if p.stem.removeprefix("test_") not in TOP_LEVEL
    ]
    assert not stray, f"test files to place in test/<subpackage>/ (test/README.md): {stray}"
    helpers = [
        p.relative_to(ROOT)
        for p in tests.rglob("*.py")
        if p.parent.name != "support" and not p.name.startswith(("test_", "__init__", "conftest"))
    ]
    assert not helpers, f"shared helpers belong in test/support/: {helpers}"


#: Issue 36's size goals: no module over 600 lines, no function over 80 lines except a
#: documented kernel, at most 25 functions with more than 5 parameters (self and cls not
#: counted, keyword-only ones counted).
MODULE_LINES, FUNCTION_LINES, PARAMETERS = 600, 80, 5
#: Modules over the limit being split (none since the one-frame-path work, issue 36 item 1).
MODULES_BEING_SPLIT: set[str] = set()
#: Today's counts: the tests fail when a change adds to them (lower them as they fall).
MOST_LONG_FUNCTIONS, MOST_WIDE_FUNCTIONS = 0, 24


def code_sizes() -> dict[str, list[str]]:
    """Modules over :data:`MODULE_LINES` lines, functions over :data:`FUNCTION_LINES` lines
    and functions with more than :data:`PARAMETERS` parameters in eit_skin/, as
    ``path[:line name] (count)`` strings."""
    sizes: dict[str, list[str]] = {"modules": [], "long functions": [], "wide functions": []}
    for path in MODULES.values():
        text = path.read_text()
        where = str(path.relative_to(ROOT))
        if len(text.splitlines()) > MODULE_LINES:
            sizes["modules"].append(f"{where} ({len(text.splitlines())})")
        for node in ast.walk(ast.parse(text)):
            if not isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                continue
            a = node.args
            names = [p.arg for p in [*a.posonlyargs, *a.args, *a.kwonlyargs]]
            n_parameters = len([n for n in names if n not in ("self", "cls")])
            n_lines = node.end_lineno - node.lineno + 1
            if n_lines > FUNCTION_LINES:
                sizes["long functions"].append(f"{where}:{node.lineno} {node.name} ({n_lines})")
            if n_parameters > PARAMETERS:
                sizes["wide functions"].append(
                    f"{where}:{node.lineno} {node.name} ({n_parameters})"
                )
    return sizes


def test_no_module_over_600_lines():
    over = [m for m in code_sizes()["modules"] if m.split(" ")[0] not in MODULES_BEING_SPLIT]
    assert not over, f"modules over {MODULE_LINES} lines: {over}"


def test_long_and_wide_functions_do_not_grow_in_number():
    sizes = code_sizes()
    long, wide = sizes["long functions"], sizes["wide functions"]
    assert len(long) <= MOST_LONG_FUNCTIONS, "\n".join(long)
    assert len(wide) <= MOST_WIDE_FUNCTIONS, "\n".join(wide)


if __name__ == "__main__":  # python -m test.package.test_architecture: the counts, listed
    for kind, found in code_sizes().items():
        print(f"{kind}: {len(found)}", *found, sep="\n  ")
