"""MkDocs hook: fill ``{{ cli_reference }}`` (docs/cli.md) with the reference of every ``mdgs`` command.

The reference is :func:`mdgs.cli.reference.markdown`: value types, defaults and "required" read from
the same click parameters that ``mdgs COMMAND --help`` renders (``tests/test_cli.py`` compares them).
"""

from __future__ import annotations

_PLACEHOLDER = "{{ cli_reference }}"


def on_page_markdown(markdown: str, page, config, files, **kwargs) -> str:
    if _PLACEHOLDER not in markdown:
        return markdown
    from mdgs.cli.reference import markdown as reference

    return markdown.replace(_PLACEHOLDER, reference())
