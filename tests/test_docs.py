"""The documents: every relative link of README.md and docs/*.md names a file in the repository.

A link to a file outside the clone (``../shared/...``) counts as broken even where that file
exists on this machine: a fresh clone does not have it. Links inside code (fenced blocks and
inline code spans) are not links.
"""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

LINK = re.compile(r"!?\[[^\]]*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
REFERENCE = re.compile(r"^\s{0,3}\[[^\]]+\]:\s*<?(\S+?)>?(?:\s|$)", re.MULTILINE)
FENCE = re.compile(r"^(```|~~~).*?^\1", re.MULTILINE | re.DOTALL)
CODE_SPAN = re.compile(r"`[^`\n]*`")


def documents(root: Path = ROOT) -> list[Path]:
    return [root / "README.md", *sorted((root / "docs").glob("*.md"))]


def broken_links(doc: Path, root: Path = ROOT) -> list[str]:
    """``"target (why)"`` for every relative link of ``doc`` that names no file in ``root``."""
    text = CODE_SPAN.sub("", FENCE.sub("", doc.read_text(encoding="utf-8")))
    out = []
    for target in LINK.findall(text) + REFERENCE.findall(text):
        if re.match(r"^[a-zA-Z][a-zA-Z0-9+.-]*:", target) or target.startswith("#"):
            continue                                   # a URL (https:, mailto:) or an anchor here
        path = (doc.parent / target.split("#")[0]).resolve()
        if not path.is_relative_to(root.resolve()):
            out.append(f"{target} (outside the repository)")
        elif not path.exists():
            out.append(f"{target} (not found)")
    return out


def test_every_relative_link_in_the_docs_resolves():
    bad = [f"{doc.relative_to(ROOT)}: {b}" for doc in documents() for b in broken_links(doc)]
    assert not bad, "\n".join(bad)


def test_a_broken_or_outside_link_is_found(tmp_path):
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "here.md").write_text("x\n")
    (tmp_path / "README.md").write_text(
        "[ok](docs/here.md#part) ![img](docs/here.md) [web](https://example.org/x.md) [top](#top)\n"
        "[gone](docs/gone.md) [design](../shared/DESIGN.md)\n"
        "`[code](not/a/link.md)`\n```\n[fenced](not/a/link.md)\n```\n[ref]: docs/missing.md\n")
    assert broken_links(tmp_path / "README.md", tmp_path) == [
        "docs/gone.md (not found)", "../shared/DESIGN.md (outside the repository)", "docs/missing.md (not found)"]
