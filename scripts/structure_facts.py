"""Facts about the package's structure: import loops, imports that run back up the layers, the largest files
and the longest functions, and imports of the package's own modules hidden inside functions.

    python scripts/structure_facts.py                    # summary of src/gazereg
    python scripts/structure_facts.py --src src/OTHER    # another package (layers checked only for gazereg)
    python scripts/structure_facts.py --json

Every import counts, at module level or inside a function: a lazy import hides a loop, it does not remove
it. So do string imports, which load a module by name when they run: `import_module("gazereg.x")` (or
`importlib.import_module`) with a literal name, and a `"gazereg.x:function"` literal (a subcommand table, a
registry entry); each is an edge of the graph like an import statement, reported by count. A string naming a
module the package does not have is reported as dangling. `LAYERS` orders the packages from the core up; a
module may import its own layer or lower ones. tests/test_structure.py asserts the facts this prints.
"""

from __future__ import annotations

import argparse
import ast
import json
import re
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]

LAYERS: tuple[tuple[str, ...], ...] = (
    ("runtime",),
    ("losses", "patches", "metrics", "heatmaps", "aggregation", "attention"),
    ("data",),
    ("gaze",),
    ("viz",),
    ("envs",),
    ("policies",),
    ("training",),
    ("evaluation",),
    ("integrations",),
    ("report",),
    ("experiment",),
    ("cli", "__init__"),
)
"""lowest first: shared infrastructure, the core (torch + numpy), then the data flow: demos -> store -> priors
(and pictures of them) -> simulation -> policy -> training -> evaluation -> report -> the experiment"""

MAX_FILE_LINES = 400
MAX_FUNCTION_LINES = 60


def module_name(path: Path, src: Path) -> str:
    parts = list(path.relative_to(src.parent).with_suffix("").parts)
    if parts[-1] == "__init__" and len(parts) > 1:
        parts = parts[:-1]
    return ".".join(parts)


def string_imports_of(tree: ast.AST, package: str) -> tuple[list[str], int]:
    """(the package's own modules that `tree` loads by name, the number of `import_module` calls whose name is
    computed): the literal argument of every `import_module("...")` call and the module part of every
    `"package.module:function"` string literal. A computed name (`import_module(table[name])`) is counted, not
    followed: the table's values are plain strings, indistinguishable from any other."""
    entry = re.compile(rf"{re.escape(package)}(\.\w+)*:\w+(\.\w+)*")
    found: list[str] = []
    computed = 0
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and node.args:
            func, arg = node.func, node.args[0]
            name = func.id if isinstance(func, ast.Name) else getattr(func, "attr", None)
            if name != "import_module":
                continue
            if isinstance(arg, ast.Constant) and isinstance(arg.value, str):
                found += [arg.value] if arg.value.split(".")[0] == package else []
            else:
                computed += 1
        elif isinstance(node, ast.Constant) and isinstance(node.value, str) and entry.fullmatch(node.value):
            found.append(node.value.partition(":")[0])
    return found, computed


def imports_of(tree: ast.AST, module: str, is_package: bool, package: str) -> list[tuple[str, bool]]:
    """(imported module, inside a function?) for every import statement of the package's own modules."""
    found: list[tuple[str, bool]] = []

    def visit(node: ast.AST, in_function: bool) -> None:
        for child in ast.iter_child_nodes(node):
            inner = in_function or isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef)
            if isinstance(child, ast.Import):
                found.extend((a.name, inner) for a in child.names if a.name.split(".")[0] == package)
            elif isinstance(child, ast.ImportFrom):
                base = child.module or ""
                if child.level:
                    anchor = module.split(".")
                    anchor = anchor if is_package else anchor[:-1]
                    anchor = anchor[: len(anchor) - (child.level - 1)]
                    base = ".".join([*anchor, base] if base else anchor)
                if base.split(".")[0] == package:
                    found.extend((f"{base}.{a.name}", inner) for a in child.names)
            visit(child, inner)

    visit(tree, False)
    return found


def resolve(name: str, modules: set[str]) -> str | None:
    """The longest known module that `name` (a module or a name inside one) refers to."""
    while name and name not in modules:
        name = name.rpartition(".")[0]
    return name or None


def loops(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected groups of more than one module (Tarjan's algorithm)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []

    def strong(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in graph.get(v, ()):
            if w not in index:
                strong(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = []
            while True:
                w = stack.pop()
                on.discard(w)
                group.append(w)
                if w == v:
                    break
            if len(group) > 1:
                out.append(sorted(group))

    for v in sorted(graph):
        if v not in index:
            strong(v)
    return out


def top_of(module: str) -> str:
    """The unit of LAYERS a module belongs to: the longest entry its dotted path starts with, else its
    first-level part."""
    rel = module.split(".", 1)[1] if "." in module else "__init__"
    units = [u for names in LAYERS for u in names if rel == u or rel.startswith(u + ".")]
    return max(units, key=len) if units else rel.split(".")[0]


def layer_of(module: str) -> int | None:
    top = top_of(module)
    for i, names in enumerate(LAYERS):
        if top in names:
            return i
    return None


def function_lengths(tree: ast.AST, module: str) -> list[tuple[str, int]]:
    out = []
    for node in ast.walk(tree):
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
            out.append((f"{module}.{node.name}", node.end_lineno - node.lineno + 1))
    return out


def analyse(src: Path, top: int = 8) -> dict[str, Any]:
    package = src.name
    files = sorted(src.rglob("*.py"))
    names = {module_name(f, src): f for f in files}
    graph: dict[str, set[str]] = {m: set() for m in names}
    inner_imports = 0
    strings: list[str] = []
    dangling: list[str] = []
    computed: list[str] = []
    lengths: list[tuple[str, int]] = []
    sizes: list[tuple[str, int]] = []
    for mod, path in names.items():
        text = path.read_text()
        tree = ast.parse(text)
        sizes.append((str(path.relative_to(src.parent)), len(text.splitlines())))
        lengths.extend(function_lengths(tree, mod))
        for target, inner in imports_of(tree, mod, path.name == "__init__.py", package):
            dep = resolve(target, set(names))
            if dep is None or dep == mod:
                continue
            graph[mod].add(dep)
            inner_imports += inner
        targets, n_computed = string_imports_of(tree, package)
        computed += [mod] * n_computed
        for target in targets:
            if target not in names:
                dangling.append(f"{mod} -> {target}")
            elif target != mod:
                graph[mod].add(target)
                strings.append(f"{mod} -> {target}")
    back = []
    if package == "gazereg":
        for mod, deps in graph.items():
            for dep in deps:
                a, b = layer_of(mod), layer_of(dep)
                if a is not None and b is not None and b > a:
                    back.append(f"{mod} -> {dep}")
    sizes.sort(key=lambda x: -x[1])
    lengths.sort(key=lambda x: -x[1])
    packages: dict[str, set[str]] = {}
    for mod, deps in graph.items():
        for dep in deps:
            a, b = top_of(mod), top_of(dep)
            if a != b:
                packages.setdefault(a, set()).add(b)
    return {
        "modules": len(names),
        "package_loops": loops(packages),
        "lines": sum(n for _, n in sizes),
        "loops": loops(graph),
        "back_arrows": sorted(back),
        "unlayered": sorted(m for m in names if package == "gazereg" and layer_of(m) is None),
        "function_level_imports": inner_imports,
        "string_imports": len(strings),
        "string_import_edges": sorted(set(strings)),
        "dangling_string_imports": sorted(dangling),
        "computed_string_imports": sorted(computed),
        "max_file_lines": MAX_FILE_LINES,
        "max_function_lines": MAX_FUNCTION_LINES,
        "largest_files": sizes[:top],
        "long_files": [s for s in sizes if s[1] > MAX_FILE_LINES],
        "longest_functions": lengths[:top],
        "long_functions": [f for f in lengths if f[1] > MAX_FUNCTION_LINES],
    }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--src", type=Path, default=ROOT / "src" / "gazereg")
    ap.add_argument("--json", action="store_true")
    ap.add_argument("--top", type=int, default=8)
    args = ap.parse_args(argv)
    facts = analyse(args.src, top=args.top)
    if args.json:
        print(json.dumps(facts, indent=2))
        return 0
    print(f"modules: {facts['modules']}, lines: {facts['lines']}")
    print(f"import loops (groups of modules that import each other): {len(facts['loops'])}")
    for group in facts["loops"]:
        print(f"  - {' <-> '.join(group)}")
    print(f"loops between the layers' units (first-level parts): {len(facts['package_loops'])}")
    for group in facts["package_loops"]:
        print(f"  - {' <-> '.join(group)}")
    print(f"imports up the layers: {len(facts['back_arrows'])}")
    for arrow in facts["back_arrows"]:
        print(f"  - {arrow}")
    if facts["unlayered"]:
        print(f"modules in no layer: {', '.join(facts['unlayered'])}")
    print(f"imports of the package's own modules inside functions: {facts['function_level_imports']}")
    edges = facts["string_import_edges"]
    print(f'string imports (import_module, "module:function"): {facts["string_imports"]}, {len(edges)} edges')
    for arrow in facts["dangling_string_imports"]:
        print(f"  - names no module: {arrow}")
    computed = facts["computed_string_imports"]
    where = ", ".join(sorted(set(computed)))
    print(f"import_module calls with a computed name (counted, not followed): {len(computed)} ({where})")
    print(f"files over {facts['max_file_lines']} lines: {len(facts['long_files'])}; largest:")
    for path, n in facts["largest_files"]:
        print(f"  {n:5d}  {path}")
    print(f"functions over {facts['max_function_lines']} lines: {len(facts['long_functions'])}; longest:")
    for name, n in facts["longest_functions"]:
        print(f"  {n:5d}  {name}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
