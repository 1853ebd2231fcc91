"""The docs' runnable snippets: every ```bash and ```python block of every page the site
lists (``mkdocs.yml``'s ``nav``, in its order), ``--8<--`` includes of ``examples/`` resolved
as the docs build does, each with the ```text block that says what it prints.

A block that cannot run on a fresh clone beside ``make run`` is marked in the page itself, on
the line right above its fence, with a reason the reader sees::

    *Needs the STAG files (not run by the docs test).*

(:data:`EXEMPT`). Every other block runs: a new page is covered as soon as ``nav`` lists it.
``tests/project/test_doc_snippets.py`` checks the marks (few, each with its reason) without a
server;
``tests/project/test_newcomer.py`` runs the blocks against ``make run``.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parents[2]
README = ROOT / "README.md"
FENCE = re.compile(r"^```(\w*)\n(.*?)^```\n", re.M | re.S)
INCLUDE = re.compile(r'^--8<-- "([^"]+)"\n', re.M)
#: the visible mark of a block the docs test does not run, on the line above its fence
EXEMPT = re.compile(r"^\*Needs (?P<reason>[^*\n]+?) \(not run by the docs test\)\.\*\n\n?\Z", re.M)
#: the languages that run: bash blocks in ``bash -e``, python blocks in the venv's python
RUNNABLE = ("bash", "python")


@dataclass
class Block:
    page: str
    section: str
    lang: str
    code: str
    prints: list[str] | None = None
    exempt: str | None = None  # the reason the page gives, for a block that is not run


def nav_pages(mkdocs: Path = ROOT / "mkdocs.yml") -> list[str]:
    """Every page of the site's ``nav``, in order, as paths from the checkout's root."""
    # the config's own tags (!!python/name ...) are not needed to read the nav
    config = yaml.load(mkdocs.read_text(), Loader=yaml.BaseLoader)
    pages: list[str] = []

    def walk(entry: object) -> None:
        if isinstance(entry, str):
            pages.append(f"{config.get('docs_dir', 'docs')}/{entry}")
        elif isinstance(entry, list):
            for e in entry:
                walk(e)
        elif isinstance(entry, dict):
            for v in entry.values():
                walk(v)

    walk(config["nav"])
    return pages


def page_blocks(page: str, text: str, *, only: str | None = None) -> list[Block]:
    """The bash/python blocks of a page, in order (``only``: of the "## " sections whose
    title starts so), each with the ```text block that follows it (after at most a line such
    as "prints") and its :data:`EXEMPT` reason if the page marks it; ``--8<--`` includes are
    replaced by the file they name."""
    text = INCLUDE.sub(lambda m: (ROOT / m.group(1)).read_text(), text)
    blocks: list[Block] = []
    for section in re.split(r"^## ", text, flags=re.M):
        title = section.splitlines()[0] if section else ""
        if only is not None and not title.startswith(only):
            continue
        last_end = None
        for m in FENCE.finditer(section):
            lang, code = m.group(1), m.group(2)
            between = section[last_end : m.start()] if last_end is not None else None
            if lang == "text" and blocks and between is not None and between.count("\n") <= 3:
                blocks[-1].prints = [ln for ln in code.splitlines() if ln.strip()]
            elif lang in RUNNABLE:
                mark = EXEMPT.search(section[last_end or 0 : m.start()])
                reason = mark.group("reason") if mark else None
                blocks.append(Block(page, title, lang, code, exempt=reason))
            last_end = m.end()
    return blocks


def all_blocks() -> list[Block]:
    """The README's 5-minute tour, then every page of the site in ``nav`` order."""
    blocks = page_blocks("README.md", README.read_text(), only="A 5-minute tour")
    for page in nav_pages():
        blocks += page_blocks(page, (ROOT / page).read_text())
    return blocks
