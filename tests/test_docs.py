"""The README is a front door and docs/ the rest (issue 28): links resolve, every `tmoc`
command in the pages parses with the real argument parser, and the ones that take
seconds run.

Commands come from fenced shell blocks and from inline code spans that start with `tmoc `
and hold no placeholder (NAME, DIR, `[...]`, `a|b`, `...`). Runs, experiments and the
server are parsed, not run here: the quick start's run is `.ci/run`'s, the server's and a
one-episode run's are tests/installed's.
"""
from __future__ import annotations

import re
from pathlib import Path

import pytest

from coordinator.cli import build_parser, main
from sim_workers.domains import names

from tests.deploy.test_deploy_files import code_blocks, tmoc_commands

REPO = Path(__file__).resolve().parents[1]
PAGES = [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]
QUICK = {"domains", "plan"}                   # commands that finish in a second or two


def slug(heading: str) -> str:
    """GitHub's anchor of a heading."""
    s = heading.strip().lower()
    s = re.sub(r"[^\w\- ]", "", s)
    return s.replace(" ", "-")


def anchors(page: Path) -> set[str]:
    text = re.sub(r"```.*?```", "", page.read_text(), flags=re.S)
    return {slug(m) for m in re.findall(r"^#+ (.+)$", text, re.M)}


def inline_commands(text: str) -> list[list[str]]:
    out = []
    for span in re.findall(r"`(tmoc [^`]+)`", text):
        span = " ".join(span.split())
        if re.search(r"\[|\||\.\.\.|/|\b[A-Z]{1,}\b", span):
            continue                          # a syntax line or a placeholder, not a command
        argv = span.split()[1:]
        if len(argv) > 1 or argv == ["--help"]:       # (a bare `tmoc run` names the command)
            out.append(argv)
    return out


def page_commands() -> list[tuple[str, list[str]]]:
    cmds = []
    for page in PAGES:
        text = page.read_text()
        for argv in tmoc_commands(code_blocks(text)) + inline_commands(text):
            cmds.append((f"{page.name}: tmoc {' '.join(argv)}", argv))
    return cmds


COMMANDS = page_commands()


def test_the_readme_is_a_front_door():
    text = (REPO / "README.md").read_text()
    assert len(text.splitlines()) <= 150
    assert re.search(r"^## Quick start\n", text, re.M)
    for page in ("COMMANDS", "BUILTIN_DOMAINS", "DOMAINS", "LOOP", "ENGINES", "SERVICE", "SCALING",
                 "EXPERIMENTS", "RESULTS", "DEVELOPING"):
        assert f"(docs/{page}.md)" in text, page


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_every_relative_link_and_anchor_resolves(page):
    text = re.sub(r"```.*?```", "", page.read_text(), flags=re.S)
    for target in re.findall(r"\]\(([^)\s]+)\)", text):
        if re.match(r"[a-z]+://", target) or target.startswith("mailto:"):
            continue
        path, _, anchor = target.partition("#")
        dest = (page.parent / path).resolve() if path else page
        assert dest.exists(), f"{page.name}: link to {target!r}: no such file"
        if anchor and dest.suffix == ".md":
            assert anchor in anchors(dest), f"{page.name}: link to {target!r}: no such heading"


def test_the_pages_hold_commands():
    assert len(COMMANDS) >= 30
    assert {argv[0] for _, argv in COMMANDS} >= {"run", "probe", "experiment", "serve", "domains", "plan"}


@pytest.mark.parametrize("where, argv", COMMANDS, ids=[w for w, _ in COMMANDS])
def test_every_command_parses(where, argv):
    try:
        build_parser().parse_args(argv)
    except SystemExit as exc:
        if exc.code != 0 or "--help" not in argv:
            pytest.fail(f"{where}: does not parse (exit {exc.code})")


QUICK_COMMANDS = [(w, a) for w, a in COMMANDS
                  if a[0] in QUICK or (a[0] == "probe" and "--trials" in a and "--domain" in a
                                       and a[a.index("--domain") + 1] in names())]


@pytest.mark.parametrize("where, argv", QUICK_COMMANDS, ids=[w for w, _ in QUICK_COMMANDS])
def test_the_quick_commands_run(where, argv, capsys):
    assert main(argv) == 0, f"{where}: {capsys.readouterr().err[-2000:]}"
    assert capsys.readouterr().out.strip(), where


@pytest.mark.parametrize("command", sorted(build_parser()._subparsers._group_actions[0].choices))
def test_every_command_help_runs(command, capsys):
    with pytest.raises(SystemExit) as exc:
        main([command, "--help"])
    assert exc.value.code == 0 and command in capsys.readouterr().out


# Pointers to files a clone does not have (issue 39): the design the project started from
# lived beside the repository, and docs and comments pointed to it.
_OUTSIDE = re.compile("|".join([r"\.\./" + "shared", "DESIGN" + r"\.md", r"design (sec\.|section|§)"]), re.I)
_TEXT = (".py", ".md", ".toml", ".cfg", ".txt", ".js", ".html", ".css", ".yaml", ".yml", ".sh", ".json")
_NOT_OURS = {".git", "venv", ".venv", "build", "dist", "runs", "node_modules", "__pycache__"}


def _repository_files() -> list[Path]:
    out = []
    for path in REPO.rglob("*"):
        rel = path.relative_to(REPO)
        if (path.is_file() and (path.suffix in _TEXT or rel.parts[0] == ".ci")
                and not _NOT_OURS & set(rel.parts) and not any(p.endswith(".egg-info") for p in rel.parts)):
            out.append(path)
    return out


def test_nothing_refers_to_files_outside_the_repository():
    files = _repository_files()
    assert len(files) > 100
    hits = [f"{p.relative_to(REPO)}:{n}: {line.strip()[:100]}"
            for p in files for n, line in enumerate(p.read_text(errors="replace").splitlines(), 1)
            if _OUTSIDE.search(line)]
    assert not hits, "\n".join(hits)
