"""Griffe extension: this code base's docstrings as Markdown for the API reference.

The docstrings are written for ``help()`` and doctest: examples are bare ``>>>`` blocks
(often under an ``Example:`` header, which Google-style parsing keeps as prose) and
cross-references use Sphinx roles (``:class:`~adfusion.logs.message.Message```). Rendered
as Markdown, ``>>>`` would become a block quote and ``[(0.0, '/mag')]`` a broken link. This
extension fences every doctest block as ``pycon`` and turns each role into inline code
(its last dotted part with a ``~``), so the page reads like the docstring.
"""

from __future__ import annotations

import re
from typing import Any

import griffe

_ROLE = re.compile(r":(?:py:)?(?:class|func|meth|mod|data|attr|exc|obj|const):`(~?)([^`]+)`")


def _role(m: re.Match[str]) -> str:
    name = m.group(2)
    return f"`{name.rsplit('.', 1)[-1] if m.group(1) else name}`"


def fence_doctests(text: str) -> str:
    """Wrap each doctest block (``>>>`` lines, ``...`` continuations and the output up to a
    blank line) in a ``pycon`` fence, keeping its indentation.

    >>> fence_doctests("Example:\\n  >>> 1 + 1\\n  2").split("\\n")
    ['Example:', '  ```pycon', '  >>> 1 + 1', '  2', '  ```']
    """
    out: list[str] = []
    lines = text.split("\n")
    i = 0
    while i < len(lines):
        stripped = lines[i].lstrip()
        if not stripped.startswith(">>>"):
            out.append(lines[i])
            i += 1
            continue
        indent = lines[i][: len(lines[i]) - len(stripped)]
        block = []
        while i < len(lines) and lines[i].strip() and lines[i].startswith(indent):
            block.append(lines[i])
            i += 1
        out += [f"{indent}```pycon", *block, f"{indent}```"]
    return "\n".join(out)


class DocstringMarkdown(griffe.Extension):
    """Rewrite every docstring as it is loaded (see the module docstring)."""

    def on_object(self, *, obj: griffe.Object, **kwargs: Any) -> None:
        if obj.docstring is not None:
            obj.docstring.value = fence_doctests(_ROLE.sub(_role, obj.docstring.value))
