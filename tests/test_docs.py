"""Meta-tests on docs/ (as datasette's): every hook is documented and tested, the pages link up, and every
`i2pbench` command shown in a ```bash block parses with the real command line."""

import re
import shlex
from pathlib import Path

import pytest

from i2pbench.cli import COMMANDS, build_parser
from i2pbench.registry.hookspecs import HOOK_NAMES

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
PAGES = sorted(DOCS.glob("*.md"))
REQUIRED = {"getting-started", "protocol", "datasets", "writing-a-plugin", "hooks", "leaderboards", "training"}


def bash_commands(markdown: str) -> list[str]:
    """Each logical command line of the page's ```bash blocks (continuations joined, `&&` chains split)."""
    commands = []
    for block in re.findall(r"^```bash\n(.*?)^```", markdown, flags=re.M | re.S):
        for line in block.replace("\\\n", " ").splitlines():
            commands += [part.strip() for part in line.split("&&") if part.strip()]
    return commands


def i2pbench_argv(command: str) -> list[str] | None:
    """The arguments after the `i2pbench` executable, or None when the command does not run it."""
    if not re.search(r"(?:^|[\s/])i2pbench(?:\s|$)", command):
        return None
    words = shlex.split(command, comments=True)
    for i, word in enumerate(words):
        if word == "i2pbench" or word.endswith("/i2pbench"):
            return words[i + 1 :]
    return None


def test_the_required_pages_exist():
    assert REQUIRED <= {page.stem for page in PAGES}


@pytest.mark.parametrize("hook", HOOK_NAMES)
def test_every_hook_is_documented(hook):
    assert f"## `{hook}(register)`" in (DOCS / "hooks.md").read_text(), f"docs/hooks.md has no section for {hook}"


@pytest.mark.parametrize("hook", HOOK_NAMES)
def test_every_hook_is_exercised_by_a_test(hook):
    users = [p.name for p in (ROOT / "tests").rglob("*.py") if p.name != "test_docs.py" and hook in p.read_text()]
    assert users, f"no test under tests/ uses {hook}"


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_relative_links_resolve(page):
    for target in re.findall(r"\]\(([^)#:]+)(?:#[^)]*)?\)", page.read_text()):
        assert (page.parent / target).exists(), f"{page.name} links to missing {target}"


@pytest.mark.parametrize("command", COMMANDS)
def test_every_command_is_in_getting_started(command):
    assert f"`i2pbench {command}" in (DOCS / "getting-started.md").read_text()


def test_every_page_is_listed_in_the_index():
    index = (DOCS / "README.md").read_text()
    assert [p.name for p in PAGES if p.name != "README.md" and f"({p.name})" not in index] == []


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_documented_commands_parse(page):
    parser = build_parser()
    for command in bash_commands(page.read_text()):
        argv = i2pbench_argv(command)
        if argv is None:
            continue
        try:
            parser.parse_args(argv)
        except SystemExit as exc:
            pytest.fail(f"{page.name}: `{command}` does not parse (exit {exc.code})")


def test_the_tutorial_commands_are_run_by_a_test():
    """test_example_plugin runs every ```bash block of the tutorial; make sure there is something for it to run."""
    tutorial = (DOCS / "writing-a-plugin.md").read_text()
    runner = (ROOT / "tests" / "test_example_plugin.py").read_text()
    assert 'fenced_blocks(TUTORIAL.read_text(), "bash")' in runner
    commands = bash_commands(tutorial)
    assert any("pip install -e plugins/example-external" in c for c in commands)
    assert any("--extractor harris --extractor3d curvature" in c for c in commands)
