"""The command-line reference of ``docs/cli.md``, read from the parameters that ``--help`` renders.

Every row comes from the click parameter's own help record (``Parameter.get_help_record``, the
pair ``--help`` prints: the option names with their value type, and the help text ending in
``[default: X]`` or ``[required]``), so the page shows the same value types (``<path>``,
``<int>``, a ``metavar`` such as ``NAME[:K]``), the same defaults and the same "required" marks as
``mdgs COMMAND --help``. :func:`reference` gives the sections in order (``mdgs`` itself first,
then each command by name); :func:`markdown` renders them for the docs hook.
"""

from __future__ import annotations

import html
import re
from dataclasses import dataclass

_EXTRA = re.compile(r"\s*\[([^\[\]]*)\]\s*$")  # the help record's trailing "[default: X; required]"


@dataclass(frozen=True)
class Row:
    """One parameter of one command, as ``--help`` shows it."""

    names: tuple[str, ...]  # ("--structure", "--no-structure"); an argument: ("RUNS...",)
    value: str  # "<path>", "NAME[:K]", "flag" for an on/off option
    default: str | None  # the "[default: X]" of --help, None where --help shows none
    required: bool  # --help marks it [required]
    help: str  # the help text without the bracketed extras
    argument: bool  # a positional argument, not an option


@dataclass(frozen=True)
class Section:
    """One command: ``mdgs`` itself or ``mdgs NAME``."""

    name: str  # "mdgs", "mdgs train"
    summary: str  # the first paragraph of its help
    details: str  # the rest of its help, one paragraph
    usage: str  # click's usage line
    rows: tuple[Row, ...]


def _row(p, ctx) -> Row | None:
    """The row of click parameter ``p`` in context ``ctx`` (None for a hidden parameter)."""
    record = p.get_help_record(ctx)
    if record is None:
        return None
    head, text = record
    extras: dict[str, str] = {}
    m = _EXTRA.search(text)
    if m:
        for part in m.group(1).split(";"):
            key, _, val = part.strip().partition(":")
            extras[key.strip()] = val.strip()
        text = text[:m.start()]
    argument = getattr(p, "param_type_name", "") == "argument"
    if argument:
        name, _, value = head.partition(" ")  # "runs... <list[Path]>"
        names = (name.upper(),)
    else:
        names = tuple([*p.opts, *p.secondary_opts])
        value = "flag" if getattr(p, "is_flag", False) else head.split(" / ")[0].split("; ")[0]
        if value != "flag":
            value = value.split(" ", 1)[1] if " " in value else ""  # "--data <path>" -> "<path>"
    return Row(names=names, value=value.strip(), default=extras.get("default"), required="required" in extras,
               help=" ".join(text.split()), argument=argument)


def _section(name: str, cmd, ctx) -> Section:
    help_text = (cmd.help or "").strip()
    first, _, rest = help_text.partition("\n\n")
    rows = tuple(r for p in cmd.params if (r := _row(p, ctx)) is not None)
    return Section(name=name, summary=" ".join(first.split()), details=" ".join(rest.split()),
                   usage=cmd.get_usage(ctx).strip(), rows=rows)


def reference(app=None) -> list[Section]:
    """``mdgs`` (its global options) and then every command of the typer ``app``, by name."""
    import typer

    if app is None:
        from mdgs.cli import app
    group = typer.main.get_command(app)
    root = group.make_context("mdgs", [], resilient_parsing=True)
    out = [_section("mdgs", group, root)]
    for name in sorted(group.commands):
        cmd = group.commands[name]
        out.append(_section(f"mdgs {name}", cmd, cmd.make_context(name, [], parent=root, resilient_parsing=True)))
    return out


def _text(s: str) -> str:
    """Help text as HTML: `code` spans kept, nothing read as Markdown emphasis."""
    s = html.escape(s, quote=False)
    s = re.sub(r"`([^`]+)`", r"<code>\1</code>", s)
    return s.replace("*", "&#42;").replace("_", "&#95;")


def _cells(r: Row) -> list[str]:
    names = ", ".join(f"<code>{html.escape(n)}</code>" for n in r.names)
    value = "on/off flag" if r.value == "flag" else f"<code>{html.escape(r.value)}</code>"
    if r.required:
        default = "<strong>required</strong>"
    elif r.default is not None:
        default = f"<code>{html.escape(r.default)}</code>"
    else:
        default = "none"
    return [names, value, default, _text(r.help)]


def table(rows, head=("option", "value", "default", "what it does"), cls: str = "stack options") -> str:
    """A raw HTML table (no blank lines, so Markdown leaves it alone) whose cells carry their
    column's name (``data-label``, the header without its markup) for the stacked layout on a phone
    (``docs/stylesheets/extra.css``); the docs hook draws its tables with it too."""
    h = "".join(f"<th>{c}</th>" for c in head)
    labels = [html.escape(re.sub(r"<[^>]+>", "", c)) for c in head]
    body = "".join("<tr>" + "".join(f'<td data-label="{c}">{v}</td>' for c, v in zip(labels, r, strict=True)) + "</tr>"
                   for r in rows)
    wrap = f' class="{cls}"' if cls else ""
    return f"<div{wrap}><table><thead><tr>{h}</tr></thead><tbody>{body}</tbody></table></div>"


def markdown(app=None) -> str:
    """The reference as Markdown with raw HTML tables: one section per command, ``mdgs`` first."""
    out = []
    for s in reference(app):
        out += [f"## {s.name}", "", _text(s.summary), "", "```text", s.usage, "```", ""]
        if s.details:
            out += [_text(s.details), ""]
        if s.name == "mdgs":
            out += ["The options of `mdgs` itself go before the command (`mdgs --debug train ...`).", ""]
        if s.rows:
            out += [table([_cells(r) for r in s.rows]), ""]
    return "\n".join(out)
