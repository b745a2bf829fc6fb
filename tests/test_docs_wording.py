"""What users and readers meet says what the code does, not how its development was organised.

No issue references ("issue 3", "the issue's", "#12"), "scratch merge" or "acceptance" in the
README and the guides, the ``--help`` of every command, code comments and docstrings; and the
layout table of ``docs/develop.md`` names every module.
"""
from __future__ import annotations

import ast
import io
import re
import tokenize
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PACKAGES = ["motorsim", "identify", "scenarios", "hardware", "motorid"]

LEFTOVERS = re.compile(
    r"\bissues?\b"                     # "issue 6", "issue-3", "the bound", "the estimators issue"
    r"|(?<![\w:&#/{])#\d+\b"           # "#12" (not "{crc:#06x}")
    r"|\bscratch[-\s]+merge"
    r"|\bacceptance\b",
    re.IGNORECASE)


def _docs() -> list[Path]:
    site = [p for p in sorted((ROOT / "docs").rglob("*")) if p.suffix in (".md", ".py", ".rst")
            and not {"auto_examples", "generated", "_build"} & set(p.parts)]
    return [ROOT / "README.md", *site, *sorted((ROOT / "hardware").rglob("*.md"))]


def _python_files() -> list[Path]:
    """The packages and the tests, except this file (whose patterns name what they look for)."""
    return [p for d in (*PACKAGES, "tests") for p in sorted((ROOT / d).rglob("*.py"))
            if p.resolve() != Path(__file__).resolve()]


def _python_text(path: Path) -> list[tuple[int, str]]:
    """(line, text) of every comment and docstring of a Python file."""
    source = path.read_text(encoding="utf-8")
    out = [(tok.start[0], tok.string) for tok in tokenize.generate_tokens(io.StringIO(source).readline)
           if tok.type == tokenize.COMMENT]
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            doc = ast.get_docstring(node, clean=False)
            if doc is not None:
                first = node.body[0].lineno
                out += [(first + i, line) for i, line in enumerate(doc.splitlines())]
    return out


def _c_text(path: Path) -> list[tuple[int, str]]:
    """(line, text) of every ``//`` and ``/* */`` comment of a C, C++ or Arduino file."""
    source = path.read_text(encoding="utf-8")
    out = []
    for match in re.finditer(r"//[^\n]*|/\*.*?\*/", source, re.DOTALL):
        first = source.count("\n", 0, match.start()) + 1
        out += [(first + i, line) for i, line in enumerate(match.group().splitlines())]
    return out


def _hash_comment_text(path: Path) -> list[tuple[int, str]]:
    """(line, text) after ``#`` in a Makefile, shell script or TOML file."""
    lines = path.read_text(encoding="utf-8").splitlines()
    return [(i, line.partition("#")[2]) for i, line in enumerate(lines, 1) if "#" in line]


def _sources() -> list[tuple[str, list[tuple[int, str]]]]:
    """Every text checked here, as (where, [(line, text), ...])."""
    out = [(p.relative_to(ROOT).as_posix(), list(enumerate(p.read_text(encoding="utf-8").splitlines(), 1)))
           for p in _docs()]
    out += [(p.relative_to(ROOT).as_posix(), _python_text(p)) for p in _python_files()]
    c_files = [p for d in PACKAGES for ext in ("*.c", "*.h", "*.cpp", "*.ino") for p in sorted((ROOT / d).rglob(ext))]
    out += [(p.relative_to(ROOT).as_posix(), _c_text(p)) for p in c_files if "build" not in p.parts]
    hash_files = [ROOT / "Makefile", ROOT / ".ci" / "run", ROOT / "pyproject.toml",
                  *(ROOT / "hardware").rglob("*.mk"), *(ROOT / "scenarios").rglob("*.toml")]
    out += [(p.relative_to(ROOT).as_posix(), _hash_comment_text(p)) for p in hash_files if p.is_file()]
    return out


def _hits(where: str, lines: list[tuple[int, str]]) -> list[str]:
    return [f"{where}:{n}: {m.group()!r} in {text.strip()[:100]!r}"
            for n, text in lines for m in LEFTOVERS.finditer(text)]


def test_no_development_wording_in_docs_comments_and_docstrings():
    hits = [hit for where, lines in _sources() for hit in _hits(where, lines)]
    assert not hits, "development leftovers:\n" + "\n".join(hits)


def test_no_development_wording_in_help_texts(motorid_commands):
    hits = []
    for path, parser in motorid_commands.items():
        text = parser.format_help().splitlines()
        hits += _hits(" ".join(("motorid", *path, "--help")), list(enumerate(text, 1)))
    assert not hits, "development leftovers:\n" + "\n".join(hits)


def _modules() -> list[Path]:
    return [p.relative_to(ROOT) for d in PACKAGES for p in sorted((ROOT / d).rglob("*.py"))]


def _section(path: Path, heading: str) -> str:
    text = path.read_text(encoding="utf-8")
    match = re.search(rf"^## {re.escape(heading)}\n(.*?)(?=^## |\Z)", text, re.MULTILINE | re.DOTALL)
    assert match, f"{path.name} has no section '## {heading}'"
    return match.group(1)


def test_the_developer_guide_layout_names_every_module():
    layout = _section(ROOT / "docs" / "develop.md", "Layout")
    missing = [m.as_posix() for m in _modules()
               if f"`{(m.parent.as_posix() + '/') if m.name == '__init__.py' else m.as_posix()}`" not in layout]
    assert not missing, f"docs/develop.md, Layout: no line for {missing}"
