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
def _unit(path: Path) -> str | None:
    """The module map's name of a source file: a top-level module, or its package."""
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    if len(parts) == 1:
        return None  # the package root
    if (ROOT / parts[0] / parts[1]).is_dir():
        return f"{parts[0]}/{parts[1]}/"
    return "/".join(parts) + ".py"


def _import_graph() -> dict[str, set[str]]:
    """Each module's (or package's) imports of other jaxplan modules, from the source."""
    import ast

    graph: dict[str, set[str]] = {}
    for path in (ROOT / "jaxplan").rglob("*.py"):
        unit = _unit(path)
        if unit is None:
            continue
        deps = graph.setdefault(unit, set())
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("jaxplan"):
                names = [f"{node.module}.{a.name}" for a in node.names] + [node.module]
            elif isinstance(node, ast.Import):
                names = [a.name for a in node.names if a.name.startswith("jaxplan")]
            else:
                continue
            for name in names:
                parts = name.split(".")
                for k in range(len(parts), 1, -1):  # the longest prefix that is a file
                    base = ROOT.joinpath(*parts[:k])
                    found = (base.with_suffix(".py") if base.with_suffix(".py").exists()
                             else base / "__init__.py" if (base / "__init__.py").exists()
                             else None)
                    if found:
                        dep = _unit(found)
                        if dep and dep != unit:
                            deps.add(dep)
                        break
    return graph


def test_the_module_map_matches_the_code():
    """docs/DESIGN.md's module map: every module of the package is a row, every row is a
    module, each row's imports are the code's, and they lie above it in the table."""
    text = (ROOT / "docs" / "DESIGN.md").read_text(encoding="utf-8")
    rows = re.findall(r"^\| (jaxplan/\S+) \| .+ \| (.+) \|$", text, re.M)
    listed = [name for name, _ in rows]
    graph = _import_graph()
    assert sorted(listed) == sorted(graph), set(listed) ^ set(graph)
    for k, (name, imports) in enumerate(rows):
        said = {"jaxplan/" + re.sub(r"\s*\(.*\)", "", d).strip()
                for d in imports.split(",") if d.strip() != "-"}
        assert said == graph[name], (name, said ^ graph[name])
        above = set(listed[:k])
        if name == "jaxplan/results.py":  # the one lazy import, named in the table
            above.add("jaxplan/plots/")
        assert said <= above, (name, said - above)


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
