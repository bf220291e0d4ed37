"""MkDocs hooks for this site (loaded by ``hooks:`` in mkdocs.yml; not a documentation page).

1. Units in brackets. Docstrings write units as ``[rad]`` after a quantity, e.g. "heading wrapped
   to [-pi, pi] [rad]". Python-Markdown allows a space between the two bracket pairs of a
   reference link, so mkdocs-autorefs read ``[-pi, pi] [rad]`` as a cross-reference to "rad" and
   warned. CommonMark allows no space there; the autorefs processor is made to follow it.
2. Repository files. Generated pages (``docs/results.md`` from ``python -m sweep.publish``) link
   to files outside ``docs/`` (``../results/best_params.json``). Those work on a repository
   browser but are not part of the site: such a link is shown as the file's repository path.
"""

from __future__ import annotations

import posixpath
import re
from typing import Any

from mkdocs_autorefs import AutorefsInlineProcessor

AutorefsInlineProcessor.RE_LINK = re.compile(r"\[([^\]]*)\]", re.DOTALL | re.UNICODE)

_LINK = re.compile(r"(?<!!)\[([^\]\n]+)\]\(([^)\s]+)\)")


def on_page_markdown(markdown: str, page: Any, config: Any, files: Any) -> str:
    """Show links that leave the documentation directory as repository paths."""
    here = posixpath.dirname(page.file.src_uri)

    def repl(m: re.Match[str]) -> str:
        text, target = m.group(1), m.group(2)
        if "://" in target or target.startswith(("#", "/", "mailto:")):
            return m.group(0)
        path = posixpath.normpath(posixpath.join(here, target.split("#", 1)[0]))
        if not path.startswith("../"):
            return m.group(0)
        repo_path = path[3:]
        shown = text.strip("`")
        return f"`{repo_path}`" if shown == repo_path else f"{text} (`{repo_path}`)"

    return _LINK.sub(repl, markdown)
