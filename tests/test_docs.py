"""The repository documents itself: links resolve, every command-line flag is documented, and
nothing cites a file outside the repository.

- Every relative Markdown link of ``README.md``, ``CHANGELOG.md`` and ``docs/*.md`` names an
  existing file, and its ``#anchor`` an existing heading (GitHub's slug rules).
- Every ``docs/...`` path written anywhere in the repository (code, tests, configs, Markdown)
  exists.
- Every Markdown file a text of the repository names (``ARCHITECTURE.md``, ``data.md#palettes``,
  ``../README.md``) resolves inside the repository, beside the naming file, at the root or in
  ``docs/``, and its ``#anchor`` to a heading; only the names of files the tools write
  (``OUTPUTS``) are not references.
- Every long option of every console script of ``[project.scripts]`` is named in that command's
  section of ``docs/cli.md`` (or on the command's own page). A command added later without a
  section, or a flag added without a line, fails here with the file to edit.
- No file cites the reference notes the project was built from (see ``FORBIDDEN`` below).
"""

from __future__ import annotations

import argparse
import importlib
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
MARKDOWN = [ROOT / "README.md", ROOT / "CHANGELOG.md", *sorted(DOCS.glob("*.md"))]
SKIP_DIRS = {".git", ".venv", "runs", "build", "dist", "__pycache__", ".pytest_cache",
             ".ruff_cache", "node_modules"}  # fmt: skip
TEXT_SUFFIXES = {".py", ".md", ".yaml", ".yml", ".toml", ".txt", ".c", ".cfg", ".ini", ".sh"}
#: Written in two parts so that this file does not cite it either.
FORBIDDEN = "FORMAT" + ".md"
#: Besides its section of docs/cli.md, a command's flags may be named on its own page.
COMMAND_PAGES = {
    "claravid-synth": "data.md",
    "claravid-demo": "data.md",
    "claravid-dsp": "complexity.md",
    "claravid-train": "training.md",
    "claravid-export": "models.md",
    "claravid-eval": "evaluation.md",
    "claravid-predict": "evaluation.md",
}

#: Markdown files the tools write (``claravid-eval``'s report, ``compare``'s table): names of
#: outputs, not references to the repository's documents.
OUTPUTS = {"report.md", "compare.md"}
#: A Markdown file's name in any text: a relative path ending in ``.md``, an optional anchor.
#: Not a suffix alone (``".md"``, ``*.md``) and not part of a URL (those are removed first).
MD_NAME = re.compile(r"(?<![\w.*/-])((?:\.\./|\./)*[\w-]+(?:[./][\w-]+)*\.md)(#[\w-]+)?(?![\w-])")
URL = re.compile(r"[a-z][a-z0-9+.-]*://\S+")
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")
FENCE = re.compile(r"^(```|~~~).*?^\1", re.M | re.S)
DOCS_PATH = re.compile(r"(?<![\w./-])docs/[\w./#-]*[\w/]")


def repository_files() -> list[Path]:
    """The repository's text files, without virtual environments, caches and run outputs."""
    files = []
    for path in ROOT.rglob("*"):
        parts = path.relative_to(ROOT).parts
        if any(p in SKIP_DIRS or p.endswith(".egg-info") for p in parts[:-1]):
            continue
        if path.is_file() and (path.suffix in TEXT_SUFFIXES or path.name == "Makefile"):
            files.append(path)
    return files


def github_slug(heading: str) -> str:
    """The anchor GitHub gives a heading: lower case, punctuation dropped, spaces to hyphens."""
    text = re.sub(r"`|\*|_{2,}", "", heading.strip().lower())
    text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", text)  # a link in a heading: its text
    text = re.sub(r"[^\w\- ]", "", text)
    return text.replace(" ", "-")


def anchors(path: Path) -> set[str]:
    """The anchors of a Markdown file's headings, with GitHub's -1, -2 suffixes for repeats."""
    seen: dict[str, int] = {}
    out = set()
    for line in FENCE.sub("", path.read_text(encoding="utf-8")).splitlines():
        match = re.match(r"^#{1,6}\s+(.*?)\s*#*\s*$", line)
        if not match:
            continue
        slug = github_slug(match.group(1))
        count = seen.get(slug, 0)
        seen[slug] = count + 1
        out.add(slug if count == 0 else f"{slug}-{count}")
    return out


def relative_links(path: Path) -> list[str]:
    """The link targets of a Markdown file outside code blocks, without URLs."""
    text = FENCE.sub("", path.read_text(encoding="utf-8"))
    text = re.sub(r"`[^`\n]*`", "", text)
    targets = [m.group(1) for m in LINK.finditer(text)]
    return [t for t in targets if not re.match(r"^[a-z][a-z0-9+.-]*:", t)]


def broken_links(path: Path) -> list[str]:
    problems = []
    for target in relative_links(path):
        file_part, _, anchor = target.partition("#")
        resolved = (path.parent / file_part).resolve() if file_part else path
        where = f"{path.relative_to(ROOT)}: link {target!r}"
        if not resolved.exists():
            problems.append(f"{where}: no file {file_part}")
        elif anchor and resolved.suffix == ".md" and anchor not in anchors(resolved):
            problems.append(f"{where}: no heading with anchor #{anchor} in {resolved.name}")
    return problems


@pytest.mark.parametrize("path", MARKDOWN, ids=lambda p: str(p.relative_to(ROOT)))
def test_relative_links_resolve(path):
    assert path.is_file()
    assert broken_links(path) == []


def test_docs_paths_mentioned_anywhere_exist():
    missing = []
    for path in repository_files():
        for match in DOCS_PATH.finditer(path.read_text(encoding="utf-8", errors="replace")):
            target, _, anchor = match.group(0).partition("#")
            target = target.rstrip("./")
            if not (ROOT / target).exists():
                missing.append(f"{path.relative_to(ROOT)}: {match.group(0)}")
            elif anchor and target.endswith(".md") and anchor not in anchors(ROOT / target):
                missing.append(f"{path.relative_to(ROOT)}: {match.group(0)} (no such heading)")
    assert missing == [], "references to docs/ files that do not exist"


def unresolved_md_names(path: Path) -> list[str]:
    """The ``*.md`` names in a file that name no file of the repository (or no heading of it).

    A name resolves beside the file, at the repository root, or in ``docs/`` (code cites
    ``evaluation.md`` for ``docs/evaluation.md``); the names in ``OUTPUTS`` are skipped.
    """
    text = URL.sub("", path.read_text(encoding="utf-8", errors="replace"))
    problems = []
    for match in MD_NAME.finditer(text):
        name, anchor = match.group(1), (match.group(2) or "")[1:]
        if Path(name).name in OUTPUTS:
            continue
        found = [
            p
            for p in (path.parent / name, ROOT / name, ROOT / "docs" / name)
            if p.resolve().is_relative_to(ROOT.resolve()) and p.is_file()
        ]
        where = f"{path.relative_to(ROOT)}: {match.group(0)}"
        if not found:
            problems.append(f"{where} (no such file in the repository)")
        elif anchor and not any(anchor in anchors(p) for p in found):
            problems.append(f"{where} (no such heading)")
    return problems


def test_every_markdown_file_named_anywhere_exists():
    """Code, tests, configs and docs cite documents that the repository has."""
    missing = []
    for path in repository_files():
        if path == Path(__file__):  # its checker's own examples are broken on purpose
            continue
        missing += unresolved_md_names(path)
    assert missing == [], "Markdown files named that the repository does not have"


def test_the_markdown_name_checker_catches_what_is_missing(tmp_path, monkeypatch):
    """The check above would pass vacuously if it found no name: one of each kind, on purpose."""
    monkeypatch.setattr(sys.modules[__name__], "ROOT", tmp_path)
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "guide.md").write_text("# Guide\n\n## Two words\n", encoding="utf-8")
    (tmp_path / "README.md").write_text("# Read me\n", encoding="utf-8")
    code = tmp_path / "pkg" / "mod.py"
    code.parent.mkdir()
    docs = "docs"  # not spelled out with the file name: the docs/ path check reads this file
    code.write_text(
        f'"""See ARCHITECTURE.md, guide.md#two-words, {docs}/guide.md#nowhere, ../README.md,\n'
        "../../outside.md, README.md and https://example.org/x/LICENSE.md; writes report.md\n"
        'and every *.md or ".md" file."""\n',
        encoding="utf-8",
    )
    (tmp_path.parent / "outside.md").write_text("# Outside\n", encoding="utf-8")
    problems = unresolved_md_names(code)
    assert [p.split(": ", 1)[1] for p in problems] == [
        "ARCHITECTURE.md (no such file in the repository)",
        f"{docs}/guide.md#nowhere (no such heading)",
        "../../outside.md (no such file in the repository)",
    ]


def test_the_link_checker_catches_a_broken_link(tmp_path, monkeypatch):
    """The checks above would pass vacuously if the parsing found nothing: break one on purpose."""
    monkeypatch.setattr(sys.modules[__name__], "ROOT", tmp_path)
    (tmp_path / "a.md").write_text("# Title\n\n## Two words\n", encoding="utf-8")
    page = tmp_path / "b.md"
    page.write_text(
        "[ok](a.md#two-words) [gone](missing.md) [bad](a.md#nowhere) [web](https://x.org/a)\n"
        "```\n[in code](nothing.md)\n```\n",
        encoding="utf-8",
    )
    problems = broken_links(page)
    assert len(problems) == 2
    assert "no file missing.md" in problems[0]
    assert "#nowhere" in problems[1]


def test_github_slugs():
    assert github_slug("Any per-image metric: `--scores`") == "any-per-image-metric---scores"
    assert github_slug("Beyond one machine: Slurm") == "beyond-one-machine-slurm"
    assert github_slug("`report.json`") == "reportjson"


def console_scripts() -> dict[str, str]:
    """``[project.scripts]`` of pyproject.toml (read by hand: tomllib needs Python 3.11)."""
    text = (ROOT / "pyproject.toml").read_text(encoding="utf-8")
    section = re.search(r"^\[project\.scripts\]\s*$(.*?)(?=^\[|\Z)", text, re.M | re.S)
    assert section, "pyproject.toml has no [project.scripts]"
    return dict(re.findall(r'^\s*"?([\w.-]+)"?\s*=\s*"([^"]+)"', section.group(1), re.M))


def long_flags_of_parser(parser: argparse.ArgumentParser) -> set[str]:
    return {
        option
        for action in parser._actions
        for option in action.option_strings
        if option.startswith("--") and option != "--help"
    }


def long_flags_of_help(text: str) -> set[str]:
    """The long options of an argparse ``--help`` text (its option lines, not its prose)."""
    flags = set()
    for line in text.splitlines():
        stripped = line.lstrip()
        if stripped.startswith("-"):  # an option line: "-o OUT, --output OUT  help..."
            head = re.split(r"\s{2,}", stripped, maxsplit=1)[0]
            flags.update(re.findall(r"(?<![\w-])--[a-z0-9][\w-]*", head))
    flags.discard("--help")
    return flags


def command_flags(command: str, target: str) -> set[str]:
    """The long options of a console script: from its module's ``build_parser`` when it has
    one, else from its ``--help`` run in a subprocess."""
    module_name, _, function = target.partition(":")
    module = importlib.import_module(module_name)
    build = getattr(module, "build_parser", None)
    if callable(build):
        return long_flags_of_parser(build())
    run = subprocess.run(
        [sys.executable, "-c", f"import sys; from {module_name} import {function}; "
         f"sys.exit({function}(['--help']))"],
        capture_output=True, text=True, timeout=120, cwd=ROOT,
    )  # fmt: skip
    assert run.returncode == 0, f"{command} --help failed:\n{run.stderr}"
    return long_flags_of_help(run.stdout)


def cli_section(command: str) -> str | None:
    """The text of ``## <command>`` in docs/cli.md, up to the next heading of that level."""
    text = (DOCS / "cli.md").read_text(encoding="utf-8")
    match = re.search(
        rf"^##\s+`?{re.escape(command)}`?\s*$(.*?)(?=^##\s|\Z)", text, flags=re.M | re.S
    )
    return match.group(1) if match else None


def named(flag: str, text: str) -> bool:
    return re.search(rf"(?<![\w-]){re.escape(flag)}(?![\w-])", text) is not None


@pytest.mark.parametrize("command", sorted(console_scripts()))
def test_every_flag_is_documented(command):
    flags = command_flags(command, console_scripts()[command])
    assert flags, f"no flags parsed for {command}: the parsing is broken"
    section = cli_section(command)
    assert section is not None, (
        f"{command} has no section in docs/cli.md: add '## {command}' with a table of its flags "
        f"({', '.join(sorted(flags))})"
    )
    page = COMMAND_PAGES.get(command)
    page_text = (DOCS / page).read_text(encoding="utf-8") if page else ""
    missing = sorted(f for f in flags if not named(f, section) and not named(f, page_text))
    assert missing == [], (
        f"{command}: flag(s) {', '.join(missing)} not documented: add them to the "
        f"'## {command}' section of docs/cli.md" + (f" (or to docs/{page})" if page else "")
    )


def test_help_parsing_matches_the_parser():
    """The subprocess path reads the same flags as the parser path (claravid-dsp has both)."""
    from claravid.dsp.cli import build_parser

    parser = build_parser()
    assert long_flags_of_help(parser.format_help()) == long_flags_of_parser(parser)


def test_nothing_cites_files_outside_the_repository():
    citing = [
        str(path.relative_to(ROOT))
        for path in repository_files()
        if FORBIDDEN in path.read_text(encoding="utf-8", errors="replace")
    ]
    assert citing == [], f"these files cite {FORBIDDEN}, which is not in the repository"
