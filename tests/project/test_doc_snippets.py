"""The docs' snippets, checked without a server (``tests/helpers/doc_snippets.py``; the run itself
is
``tests/project/test_newcomer.py``, slow): every page of the site is read, a block is left out only
when its page says why right above it, such blocks stay few, and every other block is at
least valid bash or Python."""

from __future__ import annotations

import ast
import re
import subprocess
from pathlib import Path

from tests.helpers.doc_snippets import EXEMPT, ROOT, all_blocks, nav_pages, page_blocks

#: most blocks the docs may leave out of the run (each needs what a fresh clone lacks: the
#: STAG files, a GPU, an S3 bucket, weights, recordings or a checkpoint of your own, a second
#: terminal)
MAX_EXEMPT = 20
#: a reason is a few words the reader sees
MAX_REASON_CHARS = 90
MARK_LINE = re.compile(r"^\*Needs .*\(not run by the docs test\)\.\*$", re.M)


def test_every_page_of_the_site_is_read_in_nav_order() -> None:
    pages = nav_pages()
    on_disk = sorted(str(p.relative_to(ROOT)) for p in (ROOT / "docs").rglob("*.md"))
    assert sorted(pages) == on_disk  # a page on disk but not in nav would be skipped
    assert pages.index("docs/getting-started.md") < pages.index("docs/guides/touch.md")
    assert pages.index("docs/guides/touch.md") < pages.index("docs/reference/mcp.md")
    read = {b.page for b in all_blocks()}
    assert {"README.md", "docs/getting-started.md", "docs/guides/tenants-and-keys.md"} <= read


def test_left_out_blocks_are_few_and_each_says_why() -> None:
    blocks = all_blocks()
    exempt = [b for b in blocks if b.exempt is not None]
    assert 0 < len(exempt) <= MAX_EXEMPT, [(b.page, b.exempt) for b in exempt]
    assert len(exempt) < len(blocks) - len(exempt)  # most blocks run
    for b in exempt:
        assert b.exempt.strip() and len(b.exempt) <= MAX_REASON_CHARS, (b.page, b.exempt)
    # every mark sits right above a block: none is stray (it would mark nothing)
    marks = sum(len(MARK_LINE.findall((ROOT / p).read_text())) for p in nav_pages())
    assert marks == len(exempt)
    # Getting started, the README's tour and the quickstart guides run whole
    for page in ("README.md", "docs/getting-started.md", "docs/guides/places.md"):
        assert not [b for b in exempt if b.page == page], page


def test_a_mark_exempts_only_the_block_right_below_it() -> None:
    text = (
        "# A page\n\n## One\n\n"
        "*Needs a GPU (not run by the docs test).*\n\n```bash\nnvidia-smi\n```\n\n"
        "```bash\necho runs\n```\n\n"
        "*Needs a GPU (not run by the docs test).*\n\nThen a paragraph.\n\n"
        "```python\nprint('runs too')\n```\n"
    )
    blocks = page_blocks("page.md", text)
    assert [(b.code, b.exempt) for b in blocks] == [
        ("nvidia-smi\n", "a GPU"),
        ("echo runs\n", None),
        ("print('runs too')\n", None),
    ]
    assert EXEMPT.search("*Needs a GPU (not run by the docs test).*\n\n")
    assert not EXEMPT.search("*Needs a GPU.*\n\n")  # the mark says it is not run


def test_every_block_that_runs_parses(tmp_path: Path) -> None:
    for b in all_blocks():
        if b.exempt is not None:
            continue
        where = f"{b.page} ({b.section!r}):\n{b.code}"
        if b.lang == "python":
            ast.parse(b.code, filename=b.page)
        else:
            done = subprocess.run(["bash", "-n", "-c", b.code], capture_output=True, text=True)
            assert done.returncode == 0, where + done.stderr
