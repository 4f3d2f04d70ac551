"""MkDocs hook: the index's table of commands, generated from the job records as the site is
built (``pipeline.commands.commands_table``), so a new job needs no line in it."""

import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MARK = "<!-- commands -->"


def on_page_markdown(markdown: str, page, config, files) -> str:
    if MARK not in markdown:
        return markdown
    if str(ROOT) not in sys.path:
        sys.path.insert(0, str(ROOT))
    from pipeline.commands import commands_table

    return markdown.replace(MARK, commands_table())
