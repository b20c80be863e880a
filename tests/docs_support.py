"""What the documentation tests read: the MkDocs hook that generates the references, and the code
blocks of a page."""

from __future__ import annotations

import importlib.util
import re
import sys
import textwrap
from dataclasses import dataclass
from pathlib import Path

from bench.processes import REPO

DOCS = REPO / "docs"
_spec = importlib.util.spec_from_file_location("docs_reference", REPO / "scripts" / "docs_reference.py")
assert _spec is not None and _spec.loader is not None
docs_reference = importlib.util.module_from_spec(_spec)
sys.modules["docs_reference"] = docs_reference
_spec.loader.exec_module(docs_reference)

#: A fenced block at any indentation (tabs of pymdownx.tabbed indent theirs by four spaces).
FENCE = re.compile(r"^(?P<indent>[ ]*)```(?P<lang>[a-z]*)[^\n]*\n(?P<body>.*?)^(?P=indent)```[ ]*$", re.M | re.S)
#: The line before a block the tests do not run, with the reason: ``<!-- not run by tests: REASON -->``.
NOT_RUN = re.compile(r"<!-- not run by tests: (?P<why>[^>]+) -->\s*$")


@dataclass(frozen=True)
class CodeBlock:
    lang: str
    body: str
    line: int          # 1-based line of the opening fence
    not_run: str | None  # the reason, for a block the tests leave alone


def code_blocks(path: Path) -> list[CodeBlock]:
    """Every fenced code block of the Markdown file ``path``, dedented."""
    text = path.read_text()
    blocks = []
    for match in FENCE.finditer(text):
        before = text[:match.start()].rstrip("\n").rsplit("\n", 1)[-1]
        marker = NOT_RUN.search(before)
        blocks.append(CodeBlock(match["lang"], textwrap.dedent(match["body"]), text.count("\n", 0, match.start()) + 1,
                                marker["why"].strip() if marker else None))
    return blocks


def generated(page: str) -> str:
    """The Markdown of ``docs/PAGE`` as the site shows it, its reference markers expanded."""
    text = (DOCS / page).read_text()
    assert docs_reference.MARKER.search(text), f"docs/{page} has no reference marker: its tables would not be generated"
    return docs_reference.expand(text)
