"""Regenerate the generated parts of ``docs/data-format.md`` and ``docs/priors.md``.

``python docs/generate.py`` rewrites, from the code and the shared contract:

* the first part of ``docs/data-format.md``: ``shared/data-format.md`` (beside the
  repository) reproduced unchanged, when that folder is there;
* the command-line reference in ``docs/data-format.md``: ``granbayes --help`` and the
  ``--help`` of every subcommand, at 100 columns;
* the table of default priors in ``docs/priors.md``: ``granbayes.default_priors()``;
* the list of public names in the README's API section: ``granbayes.__all__`` and the
  ``__all__`` of every module of ``granbayes.PUBLIC_MODULES``.

Everything between ``<!-- BEGIN GENERATED name -->`` and ``<!-- END GENERATED name -->`` is
replaced; the rest is written by hand. ``python docs/generate.py --check`` only reports
what is stale (exit code 1); ``tests/test_docs.py`` runs the same check.
"""

from __future__ import annotations

import argparse
import os
import re
import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent
ROOT = DOCS.parent
SHARED = ROOT.parent / "shared"

#: Subcommands documented only by their ``--help`` until this file is regenerated with them.
PLACEHOLDER_SUBCOMMANDS = ("predict", "report", "priors")

#: Where the hand-written part of a document with a shared first part begins.
ADDITIONS = "\n---\n\n# Additions made in granbayes\n"

#: Terminal width of the reproduced ``--help`` texts.
COLUMNS = 100


def splice(text: str, name: str, content: str) -> str:
    """Replace the generated block ``name`` of ``text`` with ``content``."""
    begin, end = f"<!-- BEGIN GENERATED {name}", f"<!-- END GENERATED {name} -->"
    pattern = re.compile(rf"({re.escape(begin)}[^\n]*\n).*?({re.escape(end)})", re.DOTALL)
    if not pattern.search(text):
        raise ValueError(f"no generated block {name!r}")
    return pattern.sub(lambda m: m.group(1) + content.rstrip("\n") + "\n" + m.group(2), text)


def with_shared_part(text: str, shared: str) -> str:
    """``text`` whose part before :data:`ADDITIONS` is replaced by ``shared``."""
    _, sep, additions = text.partition(ADDITIONS)
    if not sep:
        raise ValueError("no '# Additions made in granbayes' section")
    return shared.rstrip("\n") + "\n" + ADDITIONS + additions


def _help(parser: argparse.ArgumentParser) -> str:
    old = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = str(COLUMNS)
    try:
        return parser.format_help().rstrip()
    finally:
        if old is None:
            del os.environ["COLUMNS"]
        else:
            os.environ["COLUMNS"] = old


def cli_reference() -> str:
    """Markdown: ``granbayes --help``, then each subcommand's ``--help``."""
    from granbayes._cli import build_parser

    parser = build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    lines = ["```text", "$ granbayes --help", _help(parser), "```", ""]
    for name, subparser in sub.choices.items():
        lines += [f"### `granbayes {name}`", "", "```text", _help(subparser), "```", ""]
    missing = [n for n in PLACEHOLDER_SUBCOMMANDS if n not in sub.choices]
    if missing:
        names = " / ".join(missing)
        lines += [
            f"### {names}",
            "",
            f"Not part of this version's command line yet; once they are, each is documented "
            f"by `granbayes <command> --help` (and here, after `python docs/generate.py`): "
            f"{', '.join(f'`granbayes {n}`' for n in missing)}.",
            "",
        ]
    return "\n".join(lines)


def priors_table() -> str:
    """Markdown table of the default prior of every parameter, with its reason."""
    from granbayes import default_priors
    from granbayes.forces import parameter_term, registered_parameters

    described = {p.name: p.description for p in registered_parameters()}
    lines = [
        "| parameter | term | meaning | unit | default prior | lower | upper | why |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, prior in default_priors().items():
        term = parameter_term(name) if name in described else "noise"
        meaning = described.get(name, "trial-to-trial scatter of the jump height")
        dist = prior.dist
        if prior.mu is not None:
            dist += f" (mu {prior.mu:g}, sigma {prior.sigma:g})"
        lines.append(
            f"| `{name}` | `{term}` | {meaning} | {prior.unit} | {dist} | {prior.lower:g} | "
            f"{prior.upper:g} | {prior.why} |"
        )
    return "\n".join(lines)


def public_surface() -> str:
    """Markdown table of the public surface: each public module and its ``__all__``."""
    import importlib

    import granbayes

    lines = ["| module | public names |", "|---|---|"]
    for name in ("granbayes", *granbayes.PUBLIC_MODULES):
        module = importlib.import_module(name)
        names = ", ".join(f"`{n}`" for n in sorted(module.__all__, key=str.lower))
        lines.append(f"| `{name}` | {names} |")
    return "\n".join(lines)


def render() -> dict[Path, str]:
    """The generated documents: path to their up-to-date text."""
    out = {}
    path = DOCS / "data-format.md"
    text = path.read_text(encoding="utf-8")
    if (SHARED / "data-format.md").is_file():
        text = with_shared_part(text, (SHARED / "data-format.md").read_text(encoding="utf-8"))
    out[path] = splice(text, "cli", cli_reference())
    path = DOCS / "priors.md"
    out[path] = splice(path.read_text(encoding="utf-8"), "priors", priors_table())
    path = ROOT / "README.md"
    out[path] = splice(path.read_text(encoding="utf-8"), "public-api", public_surface())
    return out


def main(argv: list[str] | None = None) -> int:
    """Write the generated documents (or, with ``--check``, report the stale ones)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="report stale files, write none")
    args = parser.parse_args(argv)
    stale = []
    for path, text in render().items():
        if path.read_text(encoding="utf-8") != text:
            stale.append(path.relative_to(ROOT))
            if not args.check:
                path.write_text(text, encoding="utf-8")
    verb = "stale" if args.check else "rewrote"
    print(f"{verb}: {', '.join(map(str, stale))}" if stale else "up to date")
    return 1 if (args.check and stale) else 0


if __name__ == "__main__":
    sys.exit(main())
