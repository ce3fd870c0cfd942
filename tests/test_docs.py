"""Checks that keep the documentation true.

- Every long option of every command (read from :func:`geoscaler.cli.build_parser`, not from
  help text) is named in ``docs/user-guide.md``, in the section of its command.
- Every relative link and image in ``README.md`` and ``docs/`` points to a file that exists.
  Links that leave the repository (the shared folder beside it) are checked where that folder
  is present and skipped, saying so, where it is not.
- The documentation speaks to users: no "session N" or "issue N" of the project's work history.
- ``docs/architecture.md`` names every module of the package (``geoscaler/**/*.py`` and
  ``app/*.py``, ``__init__.py`` aside), by its path or its dotted name.

Each checker is a plain function, tested on small temporary files to show that it fails when it
should.
"""

from __future__ import annotations

import argparse
import re
from pathlib import Path
from urllib.parse import unquote

import pytest

from geoscaler import __version__
from geoscaler.cli import build_parser, main

ROOT = Path(__file__).resolve().parents[1]
GUIDE = ROOT / "docs" / "user-guide.md"
ARCHITECTURE = ROOT / "docs" / "architecture.md"
CHANGELOG = ROOT / "CHANGELOG.md"


# --- the checkers --------------------------------------------------------------------------

FENCE = re.compile(r"^\s{0,3}(```|~~~)")
HEADING = re.compile(r"^(#{1,6})\s+(.*)$")


def prose_lines(markdown: str) -> list[str]:
    """The lines of ``markdown`` with fenced code blocks blanked (kept as empty lines)."""
    lines, fenced = [], False
    for line in markdown.splitlines():
        if FENCE.match(line):
            fenced = not fenced
            lines.append("")
        else:
            lines.append("" if fenced else line)
    return lines


def long_options(parser: argparse.ArgumentParser) -> list[str]:
    """The long options (``--name``) ``parser`` itself takes, in the order ``--help`` prints."""
    return [s for action in parser._actions for s in action.option_strings if s.startswith("--")]


def subcommands(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    """``{name: parser}`` of every subcommand of ``parser``."""
    commands: dict[str, argparse.ArgumentParser] = {}
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            commands.update(action.choices)
    return commands


def command_section(markdown: str, command: str) -> str:
    """The text of every section whose heading names `` `geoscaler COMMAND` ``, each up to the
    next heading of the same or a higher level ('' when there is none)."""
    named = re.compile(rf"`geoscaler {re.escape(command)}`")
    lines = markdown.splitlines()
    headings = [(i, HEADING.match(line)) for i, line in enumerate(prose_lines(markdown))]
    headings = [(i, len(m.group(1)), m.group(2)) for i, m in headings if m]
    parts = []
    for n, (start, level, title) in enumerate(headings):
        if not named.search(title):
            continue
        end = next((i for i, lv, _ in headings[n + 1 :] if lv <= level), len(lines))
        parts.append("\n".join(lines[start:end]))
    return "\n".join(parts)


def names_option(text: str, option: str) -> bool:
    """Whether ``text`` names ``option`` as a whole word (``--scale`` is not ``--scale-x``)."""
    return re.search(rf"(?<![\w-]){re.escape(option)}(?![\w-])", text) is not None


def missing_options(parser: argparse.ArgumentParser, guide: str) -> list[str]:
    """``"COMMAND --option"`` for each long option the guide does not name: the program's own
    options anywhere in the guide, each command's in that command's section (``--help``, which
    every command has, anywhere)."""
    missing = [f"geoscaler {o}" for o in long_options(parser) if not names_option(guide, o)]
    for name, command in subcommands(parser).items():
        section = command_section(guide, name)
        if not section:
            missing.append(f"{name}: no section names `geoscaler {name}`")
        for option in long_options(command):
            text = guide if option == "--help" else section
            if not names_option(text, option):
                missing.append(f"{name} {option}")
    return missing


INLINE_CODE = re.compile(r"(`+)(?:(?!\1).)+?\1")
LINK = re.compile(r"!?\[(?:[^\[\]]|\[[^\[\]]*\])*\]\(\s*<?([^()\s<>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
REFERENCE = re.compile(r"^\s{0,3}\[[^\]]+\]:\s*<?([^\s<>]+)>?")
HTML = re.compile(r"<(?:img|a|source)\b[^>]*?\b(?:src|href)\s*=\s*[\"']([^\"']+)[\"']", re.I)
SCHEME = re.compile(r"^[a-zA-Z][a-zA-Z0-9+.-]*:")


def link_targets(markdown: str) -> list[str]:
    """Every link and image target of ``markdown`` (inline, reference definitions, HTML ``src``
    and ``href``), outside code blocks and code spans."""
    targets = []
    for line in prose_lines(markdown):
        if line.startswith(("    ", "\t")) and not line.lstrip().startswith(("-", "*", "|")):
            continue  # an indented code block (list continuations are left alone)
        line = INLINE_CODE.sub("", line)
        targets += LINK.findall(line) + HTML.findall(line)
        reference = REFERENCE.match(line)
        if reference:
            targets.append(reference.group(1))
    return targets


def local_path(target: str) -> str | None:
    """The file path a link target names, or None for web links, mail and anchors."""
    if SCHEME.match(target) or target.startswith(("#", "//")):
        return None
    path = unquote(target.split("#", 1)[0].split("?", 1)[0])
    return path or None


def check_links(document: Path, root: Path) -> tuple[list[str], list[tuple[str, bool]]]:
    """Relative links of ``document``: (the targets inside ``root`` that do not exist,
    [(target, exists)] for the targets outside ``root``)."""
    broken, outside = [], []
    root = root.resolve()
    for target in link_targets(document.read_text(encoding="utf-8")):
        path = local_path(target)
        if path is None:
            continue
        resolved = (root / path.lstrip("/")) if path.startswith("/") else document.parent / path
        resolved = resolved.resolve()
        if resolved == root or root in resolved.parents:
            if not resolved.exists():
                broken.append(target)
        else:
            outside.append((target, resolved.exists()))
    return broken, outside


WORK_HISTORY = re.compile(r"session [0-9]+|issue #?[0-9]+", re.IGNORECASE)


def work_history(paths: list[Path], root: Path) -> list[str]:
    """``"path:line: phrase"`` for every "session N" or "issue N" in ``paths``."""
    hits = []
    for path in paths:
        for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
            hits += [
                f"{path.relative_to(root)}:{number}: {m.group(0)}"
                for m in WORK_HISTORY.finditer(line)
            ]
    return hits


def package_modules(root: Path) -> list[Path]:
    """The package's modules under ``root``: ``geoscaler/**/*.py`` and ``app/*.py`` (installed as
    ``geoscaler.app``), ``__init__.py`` files aside."""
    found = sorted((root / "geoscaler").rglob("*.py")) + sorted((root / "app").glob("*.py"))
    return [path for path in found if path.name != "__init__.py"]


def module_names(path: Path, root: Path) -> tuple[str, str]:
    """(path name, dotted name) of a module: ``geoscaler/io/gltf.py``, ``geoscaler.io.gltf``;
    ``app/main.py``, ``geoscaler.app.main``."""
    relative = path.relative_to(root)
    parts = relative.with_suffix("").parts
    dotted = ".".join(("geoscaler", *parts) if parts[0] == "app" else parts)
    return relative.as_posix(), dotted


def unlisted_modules(modules: list[Path], page: str, root: Path) -> list[str]:
    """The path names of ``modules`` that ``page`` names neither by path nor by dotted name, each
    as a whole name (``geoscaler.io.gltf`` is not named by ``geoscaler.io.gltf_check``)."""
    missing = []
    for path in modules:
        names = module_names(path, root)
        if not any(re.search(rf"(?<![\w./-]){re.escape(name)}(?![\w-])", page) for name in names):
            missing.append(names[0])
    return missing


def docs_files() -> list[Path]:
    """The project's documentation pages (README.md aside): docs/ and the changelog."""
    return sorted((ROOT / "docs").rglob("*.md")) + [CHANGELOG]


# --- the documentation as it stands -------------------------------------------------------


def test_guide_names_every_option():
    missing = missing_options(build_parser(), GUIDE.read_text(encoding="utf-8"))
    assert not missing, f"options missing from docs/user-guide.md: {missing}"


@pytest.mark.parametrize(
    "document",
    [ROOT / "README.md", *docs_files()],
    ids=lambda p: str(p.relative_to(ROOT)),
)
def test_relative_links_resolve(document):
    broken, _ = check_links(document, ROOT)
    assert not broken, f"{document.relative_to(ROOT)}: links to missing files: {broken}"


def test_links_outside_the_repository():
    """Links that leave the repository (to the shared folder beside it) hold where it exists."""
    outside = {
        (str(document.relative_to(ROOT)), target): exists
        for document in [ROOT / "README.md", *docs_files()]
        for target, exists in check_links(document, ROOT)[1]
    }
    absent = [f"{doc}: {target}" for (doc, target), exists in outside.items() if not exists]
    if absent:
        pytest.skip(f"outside the repository and absent on this machine, not checked: {absent}")


def test_docs_speak_to_users():
    hits = work_history(docs_files(), ROOT)
    assert not hits, f"work history in the documentation: {hits}"


def test_readme_and_code_speak_to_users():
    code = sorted((ROOT / "geoscaler").rglob("*.py")) + sorted((ROOT / "app").rglob("*.py"))
    hits = work_history([ROOT / "README.md", *code], ROOT)
    assert not hits, f"work history in README.md or code: {hits}"


def test_architecture_page_names_every_module():
    modules = package_modules(ROOT)
    assert len(modules) > 50  # the walk found the package
    missing = unlisted_modules(modules, ARCHITECTURE.read_text(encoding="utf-8"), ROOT)
    assert not missing, f"modules missing from docs/architecture.md: {missing}"


def test_version_flag(capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["--version"])
    assert exit_info.value.code == 0
    assert capsys.readouterr().out.strip() == f"geoscaler {__version__}"


def test_version_agrees_with_the_package_and_the_changelog():
    pyproject = (ROOT / "pyproject.toml").read_text(encoding="utf-8")  # no tomllib on 3.10
    assert re.findall(r'^version = "([^"]+)"', pyproject, re.M) == [__version__]
    headings = re.findall(r"^## \[([^\]]+)\]", CHANGELOG.read_text(encoding="utf-8"), re.M)
    assert headings[:2] == ["Unreleased", __version__]


# --- the checkers fail when they should ----------------------------------------------------


def test_an_option_removed_from_the_guide_is_caught(tmp_path):
    copy = tmp_path / "user-guide.md"
    guide = GUIDE.read_text(encoding="utf-8")
    copy.write_text(re.sub(r"(?<![\w-])--power-of-two(?![\w-])", "", guide), encoding="utf-8")
    missing = missing_options(build_parser(), copy.read_text(encoding="utf-8"))
    assert missing == ["downsample --power-of-two", "batch --power-of-two"]


def test_an_option_outside_its_commands_section_is_caught():
    parser = argparse.ArgumentParser(prog="geoscaler")
    commands = parser.add_subparsers(dest="command")
    commands.add_parser("info").add_argument("--json", action="store_true")
    commands.add_parser("render").add_argument("--view", type=int)
    commands.add_parser("demo")
    guide = (
        "# Guide\n`--help` everywhere.\n"
        "## `geoscaler info`\n`--json` prints JSON. `--viewer` is another word.\n"
        "### Details\n```\n## `geoscaler render` in a code block is no heading\n```\n"
        "## `geoscaler render`\nRenders.\n"
        "## Elsewhere\n`--view 7` names a view, but not in render's section.\n"
    )
    assert missing_options(parser, guide) == [
        "render --view",
        "demo: no section names `geoscaler demo`",
    ]
    assert "--json" in command_section(guide, "info")
    assert "Details" in command_section(guide, "info")  # a subsection belongs to its section


def test_a_broken_link_is_caught(tmp_path):
    repo = tmp_path / "repo"
    (repo / "docs" / "pictures").mkdir(parents=True)
    (repo / "docs" / "guide.md").write_text("# Guide\n", encoding="utf-8")
    (repo / "docs" / "pictures" / "app.png").write_bytes(b"")
    (tmp_path / "shared.md").write_text("beside the repository\n", encoding="utf-8")
    page = repo / "docs" / "page.md"
    page.write_text(
        "See [the guide](guide.md#install), ![app](pictures/app.png) and\n"
        '![gone](pictures/gone.png "a title"), [also gone](../missing%20file.md),\n'
        "[web](https://example.com/x.md), [mail](mailto:a@b.c), [anchor](#top),\n"
        "[shared](../../shared.md), [shared, absent](../../nowhere.md),\n"
        '<img src="pictures/none.png">, `[code span](nope.md)`\n'
        "```\n[fenced](nope.md)\n```\n"
        "[ref]: pictures/ref.png\n",
        encoding="utf-8",
    )
    broken, outside = check_links(page, repo)
    assert broken == [
        "pictures/gone.png",
        "../missing%20file.md",
        "pictures/none.png",
        "pictures/ref.png",
    ]
    assert outside == [("../../shared.md", True), ("../../nowhere.md", False)]


def test_work_history_is_caught(tmp_path):
    page = tmp_path / "page.md"
    page.write_text(
        "Measured in Session 16.\nFixes issue #17 and Issue 3.\nSessions and issues in "
        "general are fine, as is version 16.\n",
        encoding="utf-8",
    )
    assert work_history([page], tmp_path) == [
        "page.md:1: Session 16",
        "page.md:2: issue #17",
        "page.md:2: Issue 3",
    ]


def test_a_module_missing_from_the_architecture_page_is_caught(tmp_path):
    files = [
        "geoscaler/__init__.py",
        "geoscaler/clock.py",
        "geoscaler/io/__init__.py",
        "geoscaler/io/gltf.py",
        "geoscaler/io/gltf_check.py",
        "geoscaler/render/texture.py",
        "app/__init__.py",
        "app/main.py",
        "app/views.py",
        "tests/test_clock.py",
    ]
    for name in files:
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text("", encoding="utf-8")
    modules = package_modules(tmp_path)
    assert [module_names(m, tmp_path) for m in modules] == [
        ("geoscaler/clock.py", "geoscaler.clock"),
        ("geoscaler/io/gltf.py", "geoscaler.io.gltf"),
        ("geoscaler/io/gltf_check.py", "geoscaler.io.gltf_check"),
        ("geoscaler/render/texture.py", "geoscaler.render.texture"),
        ("app/main.py", "geoscaler.app.main"),
        ("app/views.py", "geoscaler.app.views"),
    ]
    page = (
        "# Architecture\n- `geoscaler/clock.py`: the clock.\n"
        "- `geoscaler.io.gltf_check`: checks (a longer name names no shorter module).\n"
        "- `geoscaler.render.texture.MipTexture`: an attribute names its module.\n"
        "- `app/main.py` and `geoscaler.app.views`.\n"
        "- `mygeoscaler/io/gltf.py` and `geoscaler/io/gltf.pyc` are other files.\n"
    )
    assert unlisted_modules(modules, page, tmp_path) == ["geoscaler/io/gltf.py"]
    page += "- `geoscaler/io/gltf.py`: the reader.\n"
    assert unlisted_modules(modules, page, tmp_path) == []
