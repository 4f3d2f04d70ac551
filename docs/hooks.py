"""MkDocs hooks: every table that lists the records, and the nav's jobs, generated from the
records as the site is built, so adding a format, a controller, a predictor, an effect or a
job needs no line in the manual besides a job's own page.

- ``<!-- table: NAME -->`` on a page is replaced by the table ``TABLES[NAME]`` makes;
- ``<!-- parameters -->`` on a job's page (``docs/<job>.md``) by that job's parameter table
  (``pipeline.steps.parameters.parameters_table``: each parameter's ``Param.help``, else its
  description in the workflow function's numpydoc ``Parameters`` section, and its default
  from the signature);
- the nav's "Jobs" section gets every job's page, in the records' order, before what
  ``mkdocs.yml`` lists there (the experiment runner); a job whose page the nav holds
  elsewhere (``store``: the fleet store) keeps that place.

``tests/test_docs.py`` checks that each marker is on its page and each generator runs.
"""

import importlib
import re
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

# marker name -> "module:function" returning a Markdown table
TABLES = {
    "commands": "pipeline.commands:commands_table",
    "jobs": "pipeline.api:jobs_table",
    "formats": "features.readings.layouts:layouts_table",
    "controllers": "pipeline.compensation:controllers_table",
    "predictors": "models.serving.registry:predictors_table",
    "effects": "models.physics.effects:effects_table",
}
# A marker is a line of its own (a page may name one in running text).
MARKER = re.compile(r"^<!-- table: ([\w-]+) -->$", re.MULTILINE)
PARAMETERS = re.compile(r"^<!-- parameters -->$", re.MULTILINE)
JOBS_SECTION = "Jobs"


def _importable() -> None:
    if str(ROOT) not in sys.path:
        sys.path.insert(0, str(ROOT))


def table(name: str) -> str:
    """The table of marker ``name``, from the records as they are now."""
    _importable()
    module, _, function = TABLES[name].partition(":")
    return getattr(importlib.import_module(module), function)().rstrip("\n")


def render(markdown: str, page: str) -> str:
    """``markdown`` of docs page ``page`` (its file name) with every marker filled in."""
    markdown = MARKER.sub(lambda m: "\n" + table(m.group(1)) + "\n", markdown)
    if PARAMETERS.search(markdown):
        _importable()
        from pipeline.steps.parameters import parameters_table
        from pipeline.workflows import workflow

        record = workflow(Path(page).stem)
        generated = "\n" + parameters_table(record.function, record.parameters) + "\n"
        markdown = PARAMETERS.sub(lambda _: generated, markdown)
    return markdown


def _pages(nav) -> set[str]:
    """Every page file a nav (or a part of it) names."""
    if isinstance(nav, str):
        return {nav}
    items = nav.values() if isinstance(nav, dict) else nav or []
    return set().union(*(_pages(item) for item in items)) if items else set()


def job_pages(listed: set[str] = frozenset()) -> list[dict]:
    """One nav entry per job record (``docs/<job>.md``), those in ``listed`` left out."""
    _importable()
    from pipeline import workflows

    return [{w.name: f"{w.name}.md"} for w in workflows.WORKFLOWS
            if f"{w.name}.md" not in listed]


def on_config(config):
    nav = config["nav"] or []
    listed = _pages(nav)
    for section in nav:
        if isinstance(section, dict) and JOBS_SECTION in section:
            section[JOBS_SECTION] = job_pages(listed) + list(section[JOBS_SECTION] or [])
    return config


def on_page_markdown(markdown: str, page, config, files) -> str:
    return render(markdown, page.file.src_uri)
