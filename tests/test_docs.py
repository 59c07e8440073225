"""The README and docs/ stay true: links resolve, and every command they show still runs as written.

- every relative link (and #anchor) in README.md and docs/*.md points to an existing file (heading);
- every `python train.py ...` / `python evaluate.py ...` in a fenced code block composes with Hydra
  (a multirun's comma lists: each swept key's first value) and passes validate_train /
  validate_evaluate, so a renamed or removed key breaks the tests;
- every flag of a `python -m rbfn.studies.summarize` / `python -m rbfn.export` command shown exists;
- the README's test command is the one CI runs (.ci/run), and the README stays a front page.
"""

from __future__ import annotations

import contextlib
import importlib.metadata
import importlib.util
import io
import re
import shlex
from pathlib import Path

import pytest
from hydra.core.override_parser.overrides_parser import OverridesParser

from rbfn.config import validate_evaluate, validate_train
from rbfn.robots.derive import derive_evaluate, derive_train

from .conftest import ROOT, compose_config

PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
FENCE = re.compile(r"^(```|~~~)")
LINK = re.compile(r"!?\[(?:[^\]\[]|\[[^\]]*\])*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
# Hydra plugins a command may name; without them only the launcher/sweeper overrides are dropped.
PLUGINS = (
    "hydra_plugins.hydra_joblib_launcher",
    "hydra_plugins.hydra_submitit_launcher",
    "hydra_plugins.hydra_optuna_sweeper",
)


def _rel(path: Path) -> str:
    return str(path.relative_to(ROOT))


def _split(text: str) -> tuple[list[tuple[str, str]], str]:
    """(fenced blocks as (info string, body), the prose with fenced blocks and inline code removed)."""
    blocks, prose, body, info, fence = [], [], [], "", None
    for line in text.splitlines():
        m = FENCE.match(line.strip())
        if fence is None and m:
            fence, info, body = m.group(1), line.strip()[3:].strip(), []
        elif fence is not None and line.strip().startswith(fence):
            blocks.append((info, "\n".join(body)))
            fence = None
        elif fence is not None:
            body.append(line)
        else:
            prose.append(line)
    return blocks, re.sub(r"`[^`\n]*`", "", "\n".join(prose))


def _slug(heading: str) -> str:
    """GitHub's anchor for a heading: link text kept, lower case, punctuation dropped, spaces to '-'."""
    text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", heading).strip().lower()
    return re.sub(r"[^\w\- ]", "", text).replace(" ", "-")


def _anchors(path: Path) -> set[str]:
    seen: dict[str, int] = {}
    out = set()
    blocks, _ = _split(path.read_text(encoding="utf-8"))
    fenced = {line for _, body in blocks for line in body.splitlines()}
    for line in path.read_text(encoding="utf-8").splitlines():
        m = re.match(r"^#{1,6}\s+(.*?)\s*#*\s*$", line)
        if m and line not in fenced:
            base = _slug(m.group(1))
            n = seen.get(base, 0)
            seen[base] = n + 1
            out.add(base if n == 0 else f"{base}-{n}")
    return out


def _links():
    for page in PAGES:
        _, prose = _split(page.read_text(encoding="utf-8"))
        for target in LINK.findall(prose):
            if not re.match(r"^[a-z][a-z0-9+.-]*:", target):  # http:, https:, mailto: ...
                yield pytest.param(page, target, id=f"{_rel(page)}->{target}")


@pytest.mark.parametrize("page,target", list(_links()))
def test_relative_link_resolves(page, target):
    file, _, anchor = target.partition("#")
    dest = (page.parent / file).resolve() if file else page
    assert dest.exists(), f"{_rel(page)}: link {target!r} points to a missing file {dest}"
    if anchor:
        assert dest.suffix == ".md", f"{_rel(page)}: link {target!r}: an anchor into a non-Markdown file"
        assert anchor in _anchors(dest), (
            f"{_rel(page)}: link {target!r}: no heading with anchor #{anchor} in "
            f"{_rel(dest)} (has: {sorted(_anchors(dest))})"
        )


def _commands():
    """Every command line of the shell-like fenced blocks, as (page, argv) with continuations joined and
    `&&` / `;` chains split."""
    for page in PAGES:
        blocks, _ = _split(page.read_text(encoding="utf-8"))
        for info, body in blocks:
            if info not in ("", "bash", "sh", "shell", "console"):
                continue
            for line in re.sub(r"\\\n", " ", body).splitlines():
                try:
                    tokens = shlex.split(line, comments=True)
                except ValueError:
                    continue
                argv: list[str] = []
                for tok in [*tokens, "&&"]:
                    if tok in ("&&", "||", ";", "|") or tok.endswith(";"):
                        if tok.endswith(";") and tok != ";":
                            argv.append(tok[:-1])
                        if argv:
                            yield page, argv
                        argv = []
                    else:
                        argv.append(tok)


def _hydra_commands():
    for page, argv in _commands():
        if argv[:2] in (["python", "train.py"], ["python", "evaluate.py"]):
            yield pytest.param(page, argv, id=f"{_rel(page)}: {' '.join(argv)}")


def _cli_commands():
    for page, argv in _commands():
        if argv[:3] in (["python", "-m", "rbfn.studies.summarize"], ["python", "-m", "rbfn.export"]):
            yield pytest.param(page, argv, id=f"{_rel(page)}: {' '.join(argv)}")


HYDRA_COMMANDS = list(_hydra_commands())
CLI_COMMANDS = list(_cli_commands())


def _first_values(overrides: list[str], multirun: bool) -> list[str]:
    """Each override as one value: a multirun's sweep (a,b,c) becomes its first value."""
    out = []
    for text, o in zip(overrides, OverridesParser.create().parse_overrides(overrides)):
        if o.is_sweep_override():
            assert multirun, f"{text!r} is a sweep, but the command has no -m"
            first = next(iter(o.sweep_string_iterator()))
            out.append(f"{o.get_key_element()}={first}")
        else:
            out.append(text)
    return out


def _plugin_override(o: str) -> bool:
    return re.match(r"^[+~]*hydra(/launcher|/sweeper|\.launcher\.|\.sweeper\.)", o) is not None


def _expand_erd(arg: str) -> str:
    """`$ERD`, the pages' name for example-robot-data's robots folder (docs/your_arm.md sets it),
    expanded; skips where example-robot-data is not installed."""
    if "$ERD" not in arg:
        return arg
    try:
        root = importlib.metadata.distribution("example-robot-data").locate_file("")
    except importlib.metadata.PackageNotFoundError:
        pytest.skip("example-robot-data is not installed")
    return arg.replace("$ERD", str(Path(str(root)) / "cmeel.prefix" / "share" / "example-robot-data" / "robots"))


@pytest.mark.parametrize("page,argv", HYDRA_COMMANDS)
def test_command_composes_and_validates(page, argv):
    name = argv[1].removesuffix(".py")
    multirun, overrides, args = False, [], iter(argv[2:])
    for a in args:
        if a in ("-m", "--multirun"):
            multirun = True
        elif a in ("--cfg", "-c", "--package", "-p"):
            next(args, None)  # `--cfg job`: print the config; it composes the same
        elif a.startswith("-"):
            pytest.fail(f"{_rel(page)}: {' '.join(argv)}: unexpected flag {a!r}")
        elif re.fullmatch(r"\[[^\[\]=]+=[^\[\]]*\]", a):
            overrides.append(a[1:-1])  # `[key=value]`: an optional override, checked as given
        else:
            overrides.append(a)
    overrides = [_expand_erd(o) for o in _first_values(overrides, multirun)]
    try:
        cfg = compose_config(name, *overrides)
    except Exception:
        missing = [
            p
            for p in PLUGINS
            if importlib.util.find_spec(p.split(".")[0]) is None or importlib.util.find_spec(p) is None
        ]
        if not missing or not any(_plugin_override(o) for o in overrides):
            raise
        cfg = compose_config(name, *[o for o in overrides if not _plugin_override(o)])
    try:
        cfg = (derive_train if name == "train" else derive_evaluate)(cfg)  # robot=urdf's keys, as the commands do
        (validate_train if name == "train" else validate_evaluate)(cfg)
    except ValueError as e:
        if "no CUDA device is available" in str(e):
            pytest.skip(f"{' '.join(argv)} names a CUDA device and this torch has none")
        raise


def _help_flags(module: str) -> set[str]:
    main = importlib.import_module(module).main
    out = io.StringIO()
    with contextlib.redirect_stdout(out), pytest.raises(SystemExit):
        main(["--help"])
    return set(re.findall(r"(?<![\w-])(--?[A-Za-z][\w-]*)", out.getvalue()))


@pytest.mark.parametrize("page,argv", CLI_COMMANDS)
def test_cli_command_flags_exist(page, argv):
    flags = _help_flags(argv[2])
    assert "--help" in flags
    positional = [a for a in argv[3:] if not a.startswith("-")]
    assert positional, f"{_rel(page)}: {' '.join(argv)}: names no directory or checkpoint"
    for a in argv[3:]:
        if a.startswith("-"):
            flag = a.split("=", 1)[0]
            assert flag in flags, f"{_rel(page)}: {' '.join(argv)}: {argv[2]} has no flag {flag} ({sorted(flags)})"


def test_commands_are_found():
    """The extraction itself works: the README's own tour is among the commands checked."""
    pages = {_rel(p.values[0]) for p in HYDRA_COMMANDS}
    assert "README.md" in pages and len(HYDRA_COMMANDS) >= 10
    assert {p.values[1][2] for p in CLI_COMMANDS} == {"rbfn.studies.summarize", "rbfn.export"}


def test_python_examples_name_existing_functions():
    """Every `from rbfn... import a, b` of a python block imports, and every `rbfn.name` it writes is
    an attribute or a submodule of the package."""
    import importlib

    import rbfn

    for page in PAGES:
        blocks, _ = _split(page.read_text(encoding="utf-8"))
        for info, body in blocks:
            if info != "python":
                continue
            imports = re.findall(r"^\s*from\s+(rbfn[\w.]*)\s+import\s+(?:\(([^)]*)\)|([^\n(]+))", body, re.M)
            for module, *names in ((m, *(a or b).replace("\\", " ").split(",")) for m, a, b in imports):
                mod = importlib.import_module(module)
                for name in (n.split(" as ")[0].strip() for n in names):
                    assert not name or hasattr(mod, name), f"{_rel(page)}: {module}.{name} does not exist"
            for name in re.findall(r"\brbfn\.(\w+)", body):
                found = hasattr(rbfn, name) or importlib.util.find_spec(f"rbfn.{name}") is not None
                assert found, f"{_rel(page)}: rbfn.{name} does not exist"


def test_readme_is_a_front_page_with_ci_test_command():
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    assert len(readme.splitlines()) <= 150, "README.md is the front page: reference material goes to docs/"
    ci = [line for line in (ROOT / ".ci" / "run").read_text().splitlines() if line.startswith("python3 -m venv")]
    assert ci, ".ci/run has no set-up command"
    blocks, _ = _split(readme)
    shown = {line for info, body in blocks if info == "bash" for line in body.splitlines()}
    assert ci[-1] in shown, "the README's test command must be the one .ci/run runs, verbatim"


def test_docs_never_name_issue_numbers():
    for page in PAGES:
        if page.name.startswith(("results", "benchmarks")):  # measured history, commit names
            continue
        text = page.read_text(encoding="utf-8")
        assert not re.search(r"(?<![\w&])#\d+\b", _split(text)[1]), f"{_rel(page)} mentions an issue number"


def test_the_controllers_table_is_the_registrys():
    """docs/control.md's table of controllers is rbfn.config.BASE_CONTROLLERS, row for row."""
    from rbfn.config import BASE_CONTROLLERS

    text = (ROOT / "docs" / "control.md").read_text(encoding="utf-8")
    table = text.split("| `control.controllers` (n joints) |", 1)[1].split("\n\n", 1)[0]
    rows = re.findall(r"^\| `(\w+)` \| (.*) \|$", table, re.M)
    assert rows == list(BASE_CONTROLLERS.items())


def test_the_centres_table_names_every_preset():
    """docs/concepts.md's table of the `centers` presets is rbfn.config.SELECTORS, in order."""
    from rbfn.config import SELECTORS

    text = (ROOT / "docs" / "concepts.md").read_text(encoding="utf-8")
    section = text.split("## 2. Centres and widths", 1)[1].split("\n## ", 1)[0]
    assert re.findall(r"^\| `(\w+)`(?: \(default\))? \|", section, re.M) == list(SELECTORS)


def test_the_network_methods_table_is_the_registrys():
    """docs/control.md's table of adaptive controllers is rbfn.config.NETWORK_METHODS, row for row."""
    from rbfn.config import NETWORK_METHODS

    text = (ROOT / "docs" / "control.md").read_text(encoding="utf-8")
    rows = re.findall(r"^\s*\| `arbfn_(\w+)` \| (.*) \|$", text, re.M)
    assert rows == [(name, m.what) for name, m in NETWORK_METHODS.items()]
