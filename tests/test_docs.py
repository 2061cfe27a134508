"""The documentation describes the software as it is: every repository path that the docs
and the package's docstrings and comments name exists; the README stays short and keeps
its history out (that lives in `git log`)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md")),
        *sorted((ROOT / "examples").glob("*.md"))]
SOURCES = sorted((ROOT / "jaxplan").rglob("*.py")) + sorted((ROOT / "examples").glob("*.py"))

# a path into the repository: one of its top-level folders, then path characters
REPO_PATH = re.compile(r"(?<![\w./-])((?:jaxplan|docs|experiments|tests|examples)/[\w./-]*\w)")
# a document named without its folder, e.g. "DESIGN.md" for docs/DESIGN.md
BARE_DOC = re.compile(r"(?<![\w./-])([A-Z][A-Z_]+\.md)\b")
PLACEHOLDER = re.compile(r"[A-Z]{3,}|<|\*")  # experiments/paper/NAME.toml, runs/<name>/


def _named_paths(path: Path):
    text = path.read_text(encoding="utf-8")
    for m in REPO_PATH.finditer(text):
        p = m.group(1).rstrip(".")
        if PLACEHOLDER.search(p.split("/", 1)[1]):
            continue
        yield p, text.count("\n", 0, m.start()) + 1
    for m in BARE_DOC.finditer(text):
        if text[max(0, m.start() - 5):m.start()] == "docs/":
            continue
        yield m.group(1), text.count("\n", 0, m.start()) + 1


def _missing(files):
    out = []
    for f in files:
        for p, line in _named_paths(f):
            target = ROOT / p
            if not target.exists():
                out.append(f"{f.relative_to(ROOT)}:{line}: {p}")
    return out


def test_the_path_scanner_finds_a_missing_path(tmp_path):
    doc = tmp_path / "x.md"
    doc.write_text("see jaxplan/no_such_module.py and DESIGN.md, not docs/DESIGN.md\n")
    found = [p for p, _ in _named_paths(doc)]
    assert found == ["jaxplan/no_such_module.py", "DESIGN.md"]


@pytest.mark.parametrize("group", ["docs", "sources"])
def test_every_named_path_exists(group):
    files = DOCS if group == "docs" else SOURCES
    assert files
    missing = _missing(files)
    assert not missing, "\n".join(missing)


def test_readme_is_short_and_has_no_history():
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    assert len(text.splitlines()) < 250
    commit_hash = r"\b(?=[0-9a-f]*[a-f])(?=[0-9a-f]*[0-9])[0-9a-f]{7,40}\b"
    assert not re.search(commit_hash, text), "a commit hash in the README"


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: p.name)
def test_docs_have_no_work_log(doc):
    text = doc.read_text(encoding="utf-8")
    assert "session" not in text.lower()


# ------------------------------------------------------------------ the module map
PACKAGE = ROOT / "jaxplan"
MAX_MODULE_LINES = 600


def _module_of(path: Path, package: Path = PACKAGE) -> str:
    """A source file's name in the graphs: its path from the repository root,
    ``jaxplan/nlp/terms.py``; a package is its ``__init__.py``."""
    return path.relative_to(package.parent).as_posix()


def _resolve(dotted: str, package: Path) -> Path | None:
    """The file that importing ``dotted`` (a name under ``package``) runs last: the
    longest prefix that is a module or a package (``jaxplan.nlp.Weights`` ->
    jaxplan/nlp/__init__.py, ``jaxplan.nlp.terms`` -> jaxplan/nlp/terms.py)."""
    parts = dotted.split(".")
    for k in range(len(parts), 0, -1):
        base = package.parent.joinpath(*parts[:k])
        for found in (base.with_suffix(".py"), base / "__init__.py"):
            if found.is_file():
                return found
    return None


def _imported_names(path: Path, package: Path):
    """The dotted names under ``package`` that ``path`` imports, anywhere in it (inside
    functions too): ``from a.b import c`` names ``a.b.c`` (a module, or a name of a.b)."""
    import ast

    pkg = package.name
    here = path.relative_to(package.parent).with_suffix("").parts
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            yield from (a.name for a in node.names if a.name.split(".")[0] == pkg)
        elif isinstance(node, ast.ImportFrom):
            if node.level:  # relative: from the module's package, up level - 1
                base = here[:len(here) - node.level]
                module = ".".join([*base, *([node.module] if node.module else [])])
            else:
                module = node.module or ""
            if module.split(".")[0] != pkg:
                continue
            for a in node.names:
                yield module if a.name == "*" else f"{module}.{a.name}"


def _module_graph(package: Path = PACKAGE) -> dict[str, set[str]]:
    """Module -> the modules of ``package`` it imports (at module level or inside a
    function), each package's ``__init__.py`` a module of its own.  The package root
    (jaxplan/__init__.py: float64, the CPU devices, the top-level API) is left out: every
    module imports it, and it imports a few modules itself."""
    root = package / "__init__.py"
    graph: dict[str, set[str]] = {}
    for path in sorted(package.rglob("*.py")):
        if path == root:
            continue
        deps = graph.setdefault(_module_of(path, package), set())
        for name in _imported_names(path, package):
            found = _resolve(name, package)
            if found is not None and found not in (root, path):
                deps.add(_module_of(found, package))
    return graph


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The import cycles of ``graph``: each strongly connected set of more than one
    module (A -> B -> A), sorted (Tarjan's algorithm, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out = []
    for start in sorted(graph):
        if start in index:
            continue
        work = [(start, iter(sorted(graph.get(start, ()))))]
        index[start] = low[start] = len(index)
        stack.append(start)
        on_stack.add(start)
        while work:
            node, deps = work[-1]
            for dep in deps:
                if dep not in index:
                    index[dep] = low[dep] = len(index)
                    stack.append(dep)
                    on_stack.add(dep)
                    work.append((dep, iter(sorted(graph.get(dep, ())))))
                    break
                if dep in on_stack:
                    low[node] = min(low[node], index[dep])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[node])
                if low[node] == index[node]:
                    scc = []
                    while True:
                        m = stack.pop()
                        on_stack.discard(m)
                        scc.append(m)
                        if m == node:
                            break
                    if len(scc) > 1:
                        out.append(sorted(scc))
    return sorted(out)


def test_the_cycle_finder_finds_a_cycle():
    acyclic = {"p/__init__.py": {"p/a.py", "p/b.py"}, "p/a.py": {"p/b.py"}, "p/b.py": set(),
               "c.py": {"p/__init__.py", "p/a.py"}}
    assert _cycles(acyclic) == []
    cyclic = {**acyclic, "p/b.py": {"d.py"}, "d.py": {"c.py"}, "e.py": {"f.py"},
              "f.py": {"e.py"}}
    assert _cycles(cyclic) == [["c.py", "d.py", "p/__init__.py", "p/a.py", "p/b.py"],
                               ["e.py", "f.py"]]


def test_the_module_graph_sees_every_import(tmp_path):
    """Imports inside functions and between a package's modules count; a package's
    __init__ importing its own modules is no cycle, one of them importing the
    package's __init__ back is."""
    pkg = tmp_path / "jaxplan"
    (pkg / "sub").mkdir(parents=True)
    files = {
        "__init__.py": "from jaxplan import a\n",
        "a.py": "import jaxplan\nimport numpy\n",
        "b.py": "def f():\n    from jaxplan.sub import helper\n    return helper\n",
        "sub/__init__.py": "from jaxplan.sub.one import helper\n",
        "sub/one.py": "from jaxplan.sub.two import x as helper\nfrom jaxplan import a\n",
        "sub/two.py": "from . import three\nx = 1\n",
        "sub/three.py": "",
    }
    for name, text in files.items():
        (pkg / name).write_text(text)
    graph = _module_graph(pkg)
    assert graph == {"jaxplan/a.py": set(), "jaxplan/b.py": {"jaxplan/sub/__init__.py"},
                     "jaxplan/sub/__init__.py": {"jaxplan/sub/one.py"},
                     "jaxplan/sub/one.py": {"jaxplan/sub/two.py", "jaxplan/a.py"},
                     "jaxplan/sub/two.py": {"jaxplan/sub/three.py"},
                     "jaxplan/sub/three.py": set()}
    assert _cycles(graph) == []
    (pkg / "sub" / "three.py").write_text("def g():\n    import jaxplan.sub\n")
    assert _cycles(_module_graph(pkg)) == [[f"jaxplan/sub/{m}.py"
                                            for m in ("__init__", "one", "three", "two")]]


def test_the_jaxplan_modules_import_no_cycle():
    """No module of jaxplan imports, through others, a module that imports it (imports
    inside functions included): each module's imports lie below it."""
    cycles = _cycles(_module_graph())
    assert not cycles, "import cycles:\n" + "\n".join(" <-> ".join(c) for c in cycles)


def test_no_module_is_longer_than_600_lines():
    """Module size follows from concept: one that grows past MAX_MODULE_LINES holds more
    than one."""
    long = [f"{_module_of(p)}: {n} lines" for p in sorted(PACKAGE.rglob("*.py"))
            if (n := len(p.read_text(encoding="utf-8").splitlines())) > MAX_MODULE_LINES]
    assert not long, "\n".join(long)


def _map_rows(text: str) -> list[tuple[str, set[str]]]:
    """docs/DESIGN.md's module map: (row's name, the names its imports column gives),
    in table order; names as in the graph (``jaxplan/world.py``, a package as its folder
    ``jaxplan/nlp/``)."""
    rows = re.findall(r"^\| (jaxplan/\S+) \| .+ \| (.+) \|$", text, re.M)
    return [(name, {"jaxplan/" + re.sub(r"\s*\(.*\)", "", d).strip()
                    for d in imports.split(",") if d.strip() != "-"})
            for name, imports in rows]


def _map_problems(rows: list[tuple[str, set[str]]], graph: dict[str, set[str]]) -> list[str]:
    """What is wrong with a module map (``rows``: :func:`_map_rows`) against the module
    graph: a row may name a module (``jaxplan/nlp/terms.py``) or a package
    (``jaxplan/nlp/``: every module in it that no row of its own names); each module
    belongs to exactly one row; a row's imports are the modules its modules import, by
    their rows, other than its own; each lies above it in the table."""
    names = [name for name, _ in rows]
    problems = [f"{n}: listed twice" for n in sorted({n for n in names if names.count(n) > 1})]
    packages = {m.removesuffix("__init__.py") for m in graph if m.endswith("/__init__.py")}
    problems += [f"{n}: no such module or package" for n in names
                 if n not in graph and n not in packages]

    def row_of(module: str) -> str | None:
        if module in names:
            return module
        folder = module.rsplit("/", 1)[0] + "/"
        while folder.count("/") > 1:  # the nearest enclosing package that has a row
            if folder in names:
                return folder
            folder = folder.rstrip("/").rsplit("/", 1)[0] + "/"
        return None

    rows_graph: dict[str, set[str]] = {n: set() for n in names}
    for module, deps in graph.items():
        row = row_of(module)
        if row is None:
            problems.append(f"{module}: in no row")
            continue
        rows_graph[row] |= {r for d in deps if (r := row_of(d)) not in (None, row)}
    for k, (name, said) in enumerate(rows):
        code = rows_graph.get(name, set())
        if said != code:
            problems.append(f"{name}: the table says {sorted(said - code)} that the code does "
                            f"not import, the code imports {sorted(code - said)} not said")
        if said - set(names[:k]):
            problems.append(f"{name}: imports {sorted(said - set(names[:k]))} not above it")
    return problems


def test_the_module_map_check_takes_packages_and_their_modules():
    graph = {"jaxplan/a.py": set(), "jaxplan/p/__init__.py": {"jaxplan/p/x.py"},
             "jaxplan/p/x.py": {"jaxplan/a.py", "jaxplan/p/y.py"},
             "jaxplan/p/y.py": {"jaxplan/a.py"}, "jaxplan/b.py": {"jaxplan/p/__init__.py"}}
    whole = [("jaxplan/a.py", set()), ("jaxplan/p/", {"jaxplan/a.py"}),
             ("jaxplan/b.py", {"jaxplan/p/"})]
    assert _map_problems(whole, graph) == []
    split = [("jaxplan/a.py", set()), ("jaxplan/p/y.py", {"jaxplan/a.py"}),
             ("jaxplan/p/", {"jaxplan/a.py", "jaxplan/p/y.py"}), ("jaxplan/b.py", {"jaxplan/p/"})]
    assert _map_problems(split, graph) == []
    assert _map_problems([*split[:1], *split[2:], split[1]], graph) == [
        "jaxplan/p/: imports ['jaxplan/p/y.py'] not above it"]
    assert _map_problems(split[:3], graph) == ["jaxplan/b.py: in no row"]
    wrong = [*split[:3], ("jaxplan/b.py", {"jaxplan/a.py"}), ("jaxplan/q/", set())]
    assert _map_problems(wrong, graph) == [
        "jaxplan/q/: no such module or package",
        "jaxplan/b.py: the table says ['jaxplan/a.py'] that the code does not import, the "
        "code imports ['jaxplan/p/'] not said"]


def test_the_module_map_matches_the_code():
    """docs/DESIGN.md's module map: every module of the package is in a row (its own, or
    its package's), every row is a module or a package, each row's imports are the
    code's, and they lie above it in the table."""
    rows = _map_rows((ROOT / "docs" / "DESIGN.md").read_text(encoding="utf-8"))
    assert rows
    problems = _map_problems(rows, _module_graph())
    assert not problems, "\n".join(problems)


def test_every_python_name_the_docs_give_exists():
    """Dotted names such as `jaxplan.solve.solve_batch` in the docs import and resolve."""
    import importlib

    missing = []
    for doc in DOCS:
        for m in re.finditer(r"\bjaxplan(?:\.[A-Za-z_]\w*)+", doc.read_text(encoding="utf-8")):
            parts = m.group(0).split(".")
            for k in range(len(parts), 0, -1):  # the longest importable prefix
                try:
                    obj = importlib.import_module(".".join(parts[:k]))
                    break
                except ImportError:
                    continue
            for attr in parts[k:]:
                if not hasattr(obj, attr):
                    missing.append(f"{doc.relative_to(ROOT)}: {m.group(0)}")
                    break
                obj = getattr(obj, attr)
    assert not missing, "\n".join(missing)


def _key_table(text: str, section: str) -> dict[str, str]:
    """docs/DESIGN.md's table of a config section (`[planner]`, `[sim]`, ...): key ->
    its default cell."""
    start = text.index(f"`[{section}]`")
    rows = {}
    for line in text[start:].split("\n")[1:]:
        if line.startswith("`[") or line.startswith("#"):
            break
        m = re.match(r"^\| (\w+) \| (.+?) \| .+ \|$", line)
        if m and m.group(1) != "key":
            rows[m.group(1)] = m.group(2)
    return rows


@pytest.mark.parametrize("section,model", [("planner", "PlannerConfig"), ("sim", "SimConfig"),
                                           ("faults", "FaultsConfig")])
def test_the_config_tables_give_the_schemas_keys_and_defaults(section, model):
    """Every key of the section's schema model has a row in docs/DESIGN.md, every row is
    a key, and each default the table gives is the schema's (the schema holds the
    defaults; the page must not drift from it)."""
    import dataclasses
    import tomllib

    from jaxplan.config import schema

    fields = {f.name: f.default for f in dataclasses.fields(getattr(schema, model))}
    table = _key_table((ROOT / "docs" / "DESIGN.md").read_text(encoding="utf-8"), section)
    assert set(table) == set(fields), (sorted(set(fields) - set(table)),
                                       sorted(set(table) - set(fields)))
    for key, cell in table.items():
        value = tomllib.loads(f"x = {cell}")["x"]
        assert value == fields[key], f"[{section}] {key}: the page says {cell}, the schema " \
                                     f"{fields[key]!r}"
