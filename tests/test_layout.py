"""The package's layout rules, read from the source with ``ast`` (nothing is imported):

- no import cycle among trackfusion modules (every import counts, a function's lazy one too),
  nor between the core packages;
- the core (fusion, registration, track, evaluation) never imports ``pipeline`` or ``report``;
- random draws (``numpy.random``, ``default_rng``, the ``random`` module) only in ``simulation/``;
- no file I/O (``open``, reads and writes of files, ``savefig``, ``yaml.safe_load``) in the
  pure core packages ``fusion/``, ``registration/`` and ``track/``;
- concurrency (``multiprocessing``, ``concurrent.futures``, ``threading``, ``dask``,
  ``distributed``, ``os.fork``) only in the concurrency modules ``forked`` and ``parallel``;
- functions a reader can hold: none over :data:`MAX_LINES` lines (its docstring not counted) or
  :data:`MAX_PARAMETERS` parameters (``self`` / ``cls`` not counted).

The ``ALLOWED_*`` lists name what is still there, each with the reason; they are meant to be
emptied (a listed entry that no longer occurs fails too, so the lists cannot go stale).
"""

from __future__ import annotations

import ast
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent.parent / "trackfusion"
CORE = ("fusion", "registration", "track", "evaluation")
PURE = ("fusion", "registration", "track")

#: import cycles still present (each a frozenset of modules) and why
ALLOWED_CYCLES: dict[frozenset[str], str] = {}

#: (module, imported module) edges that close a cycle between core packages, and why
ALLOWED_PACKAGE_EDGES: dict[tuple[str, str], str] = {}

#: (module, imported module) of a core module importing pipeline or report, and why
ALLOWED_CORE_IMPORTS: dict[tuple[str, str], str] = {}

#: modules outside simulation/ that draw random numbers, and why
ALLOWED_RANDOM: dict[str, str] = {
    "trackfusion.fusion.noise_components": "the Hutchinson redundancy estimate's probe vectors (a fixed seed: "
                                           "the same answer on every run), not simulated data",
}

#: (module, call) of file I/O in the pure core, and why
ALLOWED_IO: dict[tuple[str, str], str] = {}

#: the modules that fork, start pools or threads (every other module calls them)
CONCURRENCY_MODULES = {"trackfusion.forked", "trackfusion.parallel"}

#: modules outside CONCURRENCY_MODULES that start processes or threads themselves, and why
ALLOWED_CONCURRENCY: dict[str, str] = {}

MAX_LINES = 60
MAX_PARAMETERS = 8
#: "module.qualified_name" of functions still over either limit, and why
ALLOWED_LARGE_FUNCTIONS: dict[str, str] = {}

_CONCURRENCY_IMPORTS = ("multiprocessing", "concurrent", "threading", "_thread", "dask", "distributed")
_FORK_CALLS = {"os.fork", "os.forkpty"}

_IO_CALLS = {"open", "read_text", "read_bytes", "write", "write_text", "write_bytes", "savefig", "safe_load",
             "load_yaml", "read_csv_table", "write_csv_table", "atomic_path", "write_text_atomic"}


_GENERATOR_DRAWS = {"normal", "standard_normal", "uniform", "random", "integers", "choice", "poisson", "permutation",
                    "shuffle", "exponential", "multivariate_normal", "binomial", "spawn"}


def _modules() -> dict[str, tuple[Path, bool]]:
    """module name -> (file, is a package)."""
    out = {}
    for p in sorted(PACKAGE.rglob("*.py")):
        parts = list(p.relative_to(PACKAGE.parent).with_suffix("").parts)
        is_pkg = parts[-1] == "__init__"
        out[".".join(parts[:-1] if is_pkg else parts)] = (p, is_pkg)
    return out


MODULES = _modules()


def _imports(name: str) -> set[str]:
    """trackfusion modules ``name`` imports anywhere in its file (``from pkg import sub``: the submodule)."""
    path, is_pkg = MODULES[name]
    pkg = name if is_pkg else name.rpartition(".")[0]
    found = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            found.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = pkg.split(".")[: len(pkg.split(".")) - node.level + 1]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            found.update(f"{mod}.{a.name}" if f"{mod}.{a.name}" in MODULES else mod for a in node.names)
    return {m for m in found if m in MODULES and m != name}


GRAPH = {m: _imports(m) for m in MODULES}


def _cycles(graph: dict[str, set[str]]) -> list[frozenset[str]]:
    """Strongly connected components of more than one module (Tarjan, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out = []
    for root in graph:
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            v, children = work[-1]
            w = next(children, None)
            if w is not None:
                if w not in index:
                    index[w] = low[w] = len(index)
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted(graph[w]))))
                elif w in on_stack:
                    low[v] = min(low[v], index[w])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                comp = set()
                while True:
                    w = stack.pop()
                    on_stack.discard(w)
                    comp.add(w)
                    if w == v:
                        break
                if len(comp) > 1:
                    out.append(frozenset(comp))
    return out


def _package(module: str) -> str:
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else ""


def _dotted(node: ast.AST) -> str:
    """``a.b.c`` of a Name / Attribute chain ('' for anything else)."""
    parts = []
    while isinstance(node, ast.Attribute):
        parts.append(node.attr)
        node = node.value
    if isinstance(node, ast.Name):
        parts.append(node.id)
        return ".".join(reversed(parts))
    return ""


def _calls(module: str) -> list[ast.Call]:
    return [n for n in ast.walk(ast.parse(MODULES[module][0].read_text(encoding="utf-8"))) if isinstance(n, ast.Call)]


def _draws_random(module: str) -> bool:
    tree = ast.parse(MODULES[module][0].read_text(encoding="utf-8"))
    if any(isinstance(n, ast.Import) and any(a.name == "random" for a in n.names) for n in ast.walk(tree)):
        return True
    for call in _calls(module):
        name = _dotted(call.func)
        if name.endswith("default_rng") or ".random." in f".{name}" and name.split(".")[0] in ("np", "numpy"):
            return True
        receiver, _, method = name.rpartition(".")
        if receiver.rpartition(".")[2].endswith("rng") and method in _GENERATOR_DRAWS:  # a Generator passed in
            return True
    return False


def _io_calls(module: str) -> set[str]:
    out = set()
    for call in _calls(module):
        f = call.func
        name = f.id if isinstance(f, ast.Name) else f.attr if isinstance(f, ast.Attribute) else ""
        if name in _IO_CALLS:
            out.add(name)
    return out


def _concurrency(module: str) -> set[str]:
    """What of :data:`_CONCURRENCY_IMPORTS` ``module`` imports (anywhere in its file), and its
    ``os.fork`` calls."""
    found = set()
    for node in ast.walk(ast.parse(MODULES[module][0].read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and not node.level:
            names = [node.module or ""] + ([f"{node.module}.{a.name}" for a in node.names] if node.module == "os" else [])
        elif isinstance(node, ast.Call):
            names = [_dotted(node.func)]
        else:
            continue
        found.update(n for n in names if n.split(".")[0] in _CONCURRENCY_IMPORTS or n in _FORK_CALLS)
    return found


def test_the_cycle_finder_finds_a_cycle():
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert _cycles(graph) == [frozenset({"a", "b", "c"})]
    assert _cycles({"a": {"b"}, "b": set()}) == []


def test_the_import_reader_resolves_relative_and_lazy_imports():
    assert "trackfusion.simulation.noise" in GRAPH["trackfusion.simulation.aiding"]  # from . import noise
    assert "trackfusion.registration.polar" in GRAPH["trackfusion.simulation.aiding"]  # from ..registration.polar
    assert "trackfusion.simulation.scenarios" in GRAPH["trackfusion.cli"]  # inside a function


def test_no_import_cycles():
    found = set(_cycles(GRAPH))
    assert found - set(ALLOWED_CYCLES) == set(), "import cycles: " + "; ".join(
        " <-> ".join(sorted(c)) for c in found - set(ALLOWED_CYCLES))
    assert set(ALLOWED_CYCLES) - found == set(), "gone, remove from ALLOWED_CYCLES"


def test_no_cycles_between_core_packages():
    edges = {(m, i) for m, imports in GRAPH.items() for i in imports
             if _package(m) in CORE and _package(i) in CORE and _package(m) != _package(i)}
    packages = {}
    for m, i in edges - set(ALLOWED_PACKAGE_EDGES):
        packages.setdefault(_package(m), set()).add(_package(i))
    graph = {p: packages.get(p, set()) for p in CORE}
    assert _cycles(graph) == [], sorted(edges - set(ALLOWED_PACKAGE_EDGES))
    assert set(ALLOWED_PACKAGE_EDGES) <= edges, "gone, remove from ALLOWED_PACKAGE_EDGES"


def test_the_core_never_imports_pipeline_or_report():
    found = {(m, i) for m, imports in GRAPH.items() if _package(m) in CORE
             for i in imports if i == "trackfusion.pipeline" or _package(i) == "report"}
    assert found == set(ALLOWED_CORE_IMPORTS)


def test_random_draws_only_in_simulation():
    found = {m for m in MODULES if _package(m) != "simulation" and _draws_random(m)}
    assert found == set(ALLOWED_RANDOM)
    assert _draws_random("trackfusion.simulation.noise")  # the check sees a draw where there is one


def test_no_file_io_in_the_pure_core():
    found = {(m, c) for m in MODULES if _package(m) in PURE for c in _io_calls(m)}
    assert found == set(ALLOWED_IO)
    assert "read_text" in _io_calls("trackfusion.geometry_inputs")  # the check sees I/O where there is some


def test_concurrency_only_in_the_concurrency_modules():
    found = {m for m in MODULES if _concurrency(m)}
    assert found - CONCURRENCY_MODULES == set(ALLOWED_CONCURRENCY), {m: sorted(_concurrency(m)) for m in found - CONCURRENCY_MODULES}
    assert CONCURRENCY_MODULES <= found  # the check sees them where they are
    assert "os.fork" in _concurrency("trackfusion.forked")


def _function_sizes(source: str) -> dict[str, tuple[int, int]]:
    """``qualified name -> (lines without the docstring, parameters without self / cls)`` of
    every function and method in ``source``."""
    out = {}

    def visit(node: ast.AST, prefix: str) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                a = child.args
                params = [*a.posonlyargs, *a.args, *a.kwonlyargs, *filter(None, (a.vararg, a.kwarg))]
                n_params = len(params) - (1 if params and params[0].arg in ("self", "cls") and a.args else 0)
                lines = child.end_lineno - child.lineno + 1
                first = child.body[0]
                if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant) and isinstance(first.value.value, str):
                    lines -= first.end_lineno - first.lineno + 1
                out[prefix + child.name] = (lines, n_params)
                visit(child, prefix + child.name + ".")
            elif isinstance(child, ast.ClassDef):
                visit(child, prefix + child.name + ".")

    visit(ast.parse(source), "")
    return out


def test_the_size_reader_counts_lines_and_parameters():
    source = ("class C:\n    def f(self, a, *b, c, **d):\n        \"\"\"doc\n        more\"\"\"\n"
              "        def g(x):\n            return x\n        return g(a)\n\n"
              "def h(p, q=1):\n    return p\n")
    assert _function_sizes(source) == {"C.f": (4, 4), "C.f.g": (2, 1), "h": (2, 2)}


def test_functions_a_reader_can_hold():
    found = {f"{m}.{name}": size for m in MODULES
             for name, size in _function_sizes(MODULES[m][0].read_text(encoding="utf-8")).items()
             if size[0] > MAX_LINES or size[1] > MAX_PARAMETERS}
    assert set(found) == set(ALLOWED_LARGE_FUNCTIONS), {k: f"{v[0]} lines, {v[1]} parameters" for k, v in found.items()
                                                        if k not in ALLOWED_LARGE_FUNCTIONS}
