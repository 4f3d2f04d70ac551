"""The manual: every ```python block of docs/ runs, the site builds strictly, the README stays
the front door.

The blocks of one page run in order in one namespace, as a reader pastes them into one
notebook (```py blocks show code that belongs in a module and are not run). They run in a
scratch folder holding a link to the repository's ``experiments/``, so
the paths the docs use (relative to the repository root) resolve while everything the examples
write lands in the scratch folder.
"""

from __future__ import annotations

import importlib.util
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from pipeline.workflows import NAMES as JOBS

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
README = ROOT / "README.md"

# A fence opens at the start of a line with ```python and closes with ``` alone on a line.
_BLOCK = re.compile(r"^```python[^\n]*\n(.*?)^```[ \t]*$", re.MULTILINE | re.DOTALL)


def python_blocks(page: Path) -> list[tuple[int, str]]:
    """The ```python blocks of a page with the line each starts on."""
    text = page.read_text(encoding="utf-8")
    return [(text.count("\n", 0, m.start()) + 2, m.group(1)) for m in _BLOCK.finditer(text)]


PAGES = sorted(p for p in DOCS.rglob("*.md") if python_blocks(p))


def test_the_walkthrough_and_the_job_pages_have_examples():
    names = {p.name for p in PAGES}
    assert {"api.md", "index.md", "extending.md"} <= names, names


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(DOCS)))
def test_python_blocks_run(page, tmp_path, monkeypatch):
    (tmp_path / "experiments").symlink_to(ROOT / "experiments", target_is_directory=True)
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("MPLBACKEND", "Agg")
    namespace: dict = {"__name__": f"docs.{page.stem}"}
    for line, source in python_blocks(page):
        code = compile(source, f"{page.relative_to(ROOT)}:{line}", "exec")
        try:
            exec(code, namespace)  # noqa: S102 - the documented examples are the test
        except Exception as err:
            raise AssertionError(f"{page.name}, block at line {line}: "
                                 f"{type(err).__name__}: {err}") from err


def test_site_builds_strictly(tmp_path):
    if importlib.util.find_spec("mkdocs") is None:
        pytest.skip("mkdocs is not installed (pip install -e '.[dev]' installs it)")
    done = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--quiet",
                           "-d", str(tmp_path / "site")], cwd=ROOT, capture_output=True,
                          text=True, env={**os.environ, "NO_MKDOCS_2_WARNING": "1"}, check=False)
    assert done.returncode == 0, done.stdout + done.stderr
    assert (tmp_path / "site" / "api" / "index.html").exists()


def test_every_page_is_in_the_nav():
    """Every page is in mkdocs.yml's nav, or a job's page, which the hooks add to it."""
    config = (ROOT / "mkdocs.yml").read_text(encoding="utf-8")
    missing = [p.name for p in DOCS.glob("*.md")
               if p.name not in config and p.stem not in JOBS]
    assert not missing, f"pages missing from mkdocs.yml nav: {missing}"


def test_api_page_names_every_public_function():
    from pipeline import api

    text = load_hooks().render((DOCS / "api.md").read_text(encoding="utf-8"), "api.md")
    missing = [name for name in api.__all__ if not re.search(rf"\b{name}\b", text)]
    assert not missing, missing


def test_readme_is_the_front_door():
    lines = README.read_text(encoding="utf-8").splitlines()
    assert len(lines) <= 250, f"README.md has {len(lines)} lines; at most 250"
    code = [ln.strip() for ln in lines if ln.strip()]
    first = code.index("```sh")
    assert code[first + 1].startswith("make demo"), code[first + 1]
    assert code[first + 2].startswith("make test"), code[first + 2]
    assert code[first + 3] == "```"
    # nothing but the title comes before the two commands
    assert all(ln.startswith("# ") for ln in code[:first])


def test_readme_links_resolve():
    text = README.read_text(encoding="utf-8")
    targets = re.findall(r"\]\((docs/[^)#]+)", text)
    assert targets
    missing = sorted({t for t in targets if not (ROOT / t).exists()})
    assert not missing, missing


# ------------------------------------------------------------------ tables read from the records
def load_hooks():
    """``docs/hooks.py``, the MkDocs hooks that fill in the tables as the site is built."""
    spec = importlib.util.spec_from_file_location("docs_hooks", DOCS / "hooks.py")
    hooks = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(hooks)
    return hooks


def record_names() -> dict[str, tuple[str, list[str]]]:
    """Per table marker: the page that holds it and the names its records give, read from
    the records themselves."""
    from features.readings.layouts import LAYOUTS
    from models.physics.effects import EFFECTS
    from models.serving.registry import PREDICTORS
    from pipeline import api
    from pipeline.compensation import CONTROLLERS

    return {"formats": ("input-formats.md", [r.name for r in LAYOUTS]),
            "controllers": ("controllers.md", list(CONTROLLERS)),
            "predictors": ("train.md", list(PREDICTORS)),
            "effects": ("data-contract.md", [*EFFECTS, "none"]),
            "commands": ("index.md", [f"backlash {job}" for job in JOBS]),
            "jobs": ("api.md", [f"bl.{name}" for name in api.jobs()])}


def first_column(table: str) -> list[str]:
    """The code-font names of a Markdown table's first column."""
    return [re.match(r"\| `([^`]+)`", row)[1] for row in table.splitlines()[2:]]


def test_every_table_the_hooks_make_has_its_marker_and_lists_every_record():
    """The tables of records are not pasted: the page holds a marker that the site's build
    fills in (``docs/hooks.py``), and the table made lists exactly the records, in order."""
    hooks = load_hooks()
    expected = record_names()
    assert set(hooks.TABLES) == set(expected)
    for name, (page, names) in expected.items():
        text = (DOCS / page).read_text(encoding="utf-8")
        assert f"\n<!-- table: {name} -->\n" in text, f"docs/{page} lacks its {name} marker"
        rendered = hooks.render(text, page)
        assert "<!-- table:" not in rendered
        table = hooks.table(name)
        assert table in rendered
        shown = [n.split(" [")[0] for n in first_column(table)]
        if name == "commands":  # a synopsis: the command's name, then its arguments
            shown = [" ".join(n.split()[:2]) for n in shown]
        assert shown == names, (name, shown)


@pytest.mark.parametrize("job", JOBS)
def test_every_job_page_gets_its_parameter_table(job):
    """A job's page holds the ``<!-- parameters -->`` marker and the built page the table the
    command line generates its options from."""
    from pipeline.steps.parameters import parameters_table
    from pipeline.workflows import workflow

    page = "store.md" if job == "store" else f"{job}.md"
    text = (DOCS / page).read_text(encoding="utf-8")
    assert "\n<!-- parameters -->\n" in text, f"docs/{page} lacks its <!-- parameters --> marker"
    rendered = load_hooks().render(text, page)
    record = workflow(job)
    assert parameters_table(record.function, record.parameters) in rendered and "<!-- parameters -->" not in rendered


def test_the_nav_lists_every_job_page_from_the_records():
    hooks = load_hooks()
    nav = [{"Getting started": "index.md"}, {"Jobs": [{"run (experiments)": "run.md"}]},
           {"Fleet store": "store.md"}]
    jobs = hooks.on_config({"nav": nav})["nav"][1]["Jobs"]
    assert jobs == [{job: f"{job}.md"} for job in JOBS if job != "store"] + [
        {"run (experiments)": "run.md"}]


def test_run_page_example_is_an_excerpt_of_the_demo():
    import tomllib

    text = (DOCS / "run.md").read_text(encoding="utf-8")
    block = re.search(r"^```toml\n(.*?)^```", text, re.MULTILINE | re.DOTALL)
    assert block, "docs/run.md has no ```toml example"
    excerpt = tomllib.loads(block.group(1))
    demo = tomllib.loads((ROOT / "experiments" / "demo.toml").read_text(encoding="utf-8"))
    assert excerpt["steps"], excerpt
    assert all(step in demo["steps"] for step in excerpt["steps"]), excerpt["steps"]
    assert {k: v for k, v in excerpt.items() if k != "steps"}.items() <= demo.items()


# ------------------------------------------------------------------ paths named in the manual
_FENCE = re.compile(r"^```.*?^```[ \t]*$", re.MULTILINE | re.DOTALL)
_SPAN = re.compile(r"`([^`\n]+)`")
# A repository path: one of the top-level folders, then a path; placeholders (<job>, {out},
# *) end it and the path up to them is checked.
_PATH = re.compile(r"(?<![\w./-])((?:backlash|bench|docs|experiments|features|models|pipeline|"
                   r"tests)/[\w./-]*)")


def named_paths(text: str) -> set[str]:
    """Repository paths written in code font outside code blocks."""
    found = set()
    for span in _SPAN.findall(_FENCE.sub("", text)):
        for match in _PATH.finditer(span):
            path = match.group(1).rstrip(".")
            if match.end() < len(span) and span[match.end()] in "<{*":
                path = path[:path.rfind("/") + 1]  # the folder holding the placeholder
            found.add(path)
    return found


@pytest.mark.parametrize("page", sorted(DOCS.glob("*.md")) + [README],
                         ids=lambda p: p.name)
def test_every_path_the_docs_name_exists(page):
    missing = sorted(p for p in named_paths(page.read_text(encoding="utf-8"))
                     if not (ROOT / p).exists())
    assert not missing, f"{page.name} names paths that do not exist: {missing}"


def test_named_paths_finds_paths_and_skips_placeholders():
    text = ("`models/serving/registry.py`, `backlash run experiments/demo.toml --out x/`, "
            "`pipeline/workflows/<job>.py`, `features.readings.layouts`\n"
            "```sh\nmodels/gone.py\n```\n")
    assert named_paths(text) == {"models/serving/registry.py", "experiments/demo.toml",
                                 "pipeline/workflows/"}


def test_every_citation_points_at_a_reference():
    anchors = set(re.findall(r'<a id="([^"]+)"></a>',
                             (DOCS / "references.md").read_text(encoding="utf-8")))
    cited = {(page.name, key) for page in DOCS.glob("*.md")
             for key in re.findall(r"references\.md#([\w.-]+)", page.read_text(encoding="utf-8"))}
    missing = sorted((page, key) for page, key in cited if key not in anchors)
    assert not missing, missing
    uncertainty = (DOCS / "uncertainty.md").read_text(encoding="utf-8")
    assert "JCGM 100:2008" not in uncertainty and "Swyt, " not in uncertainty  # cited by key
    assert {"gum", "swyt1994"} <= anchors


_DOTTED = re.compile(r"^(?:features|models|pipeline)(?:\.\w+)+$")


def _resolves(name: str) -> bool:
    """``name`` is a module, or an attribute reached from the longest importable module."""
    parts = name.split(".")
    for i in range(len(parts), 0, -1):
        try:
            found = importlib.import_module(".".join(parts[:i]))
        except ImportError:
            continue
        try:
            for part in parts[i:]:
                found = getattr(found, part)
        except AttributeError:
            return False
        return True
    return False


def test_every_python_name_the_docs_give_resolves():
    missing = sorted({(page.name, span) for page in [*DOCS.glob("*.md"), README]
                      for span in (s.split("(")[0] for s in _SPAN.findall(
                          _FENCE.sub("", page.read_text(encoding="utf-8"))))
                      if _DOTTED.match(span) and not _resolves(span)})
    assert not missing, missing
