"""Sphinx glue of the fenics-adaptive site.

- ``read_percent_script``: MyST-NB reader that turns a percent-format tutorial script of
  docs/afem/ into a notebook (Jupytext), so the script the tests run is the page the site
  executes, with no copy in between.
- The config reference page is filled, at read time, with
  ``fenics_adaptive.settings.schema.reference_markdown()``: the same table of sections and keys
  the config parser checks against, so the page cannot drift from the parser.
- Pages that include parts of files outside docs/ (README.md, benchmarks/results/latest.md)
  get their relative links rewritten for the page (``include-read``): links into docs/ point
  at the same file from docs/, links to package modules become API references, links to
  files that are pages of the site point at those pages, other repository files keep their
  text without a link (the site holds no copy of them).
- Docstrings of the package are plain text written for ``help()`` (formulas such as
  ``|det J|`` or ``f_ext - f_int(u)``, indented tables), not reStructuredText. The API pages show
  them as written: the summary paragraph as text (its ``code`` spans as inline literals, all
  else escaped), the rest as a literal block, so that no docstring is misread as markup.
- The notebook kernels import this checkout's package (PYTHONPATH), whatever else the virtual
  environment holds.
"""

from __future__ import annotations

import os
import re
from pathlib import Path

import jupytext
import nbformat
from sphinx.application import Sphinx
from sphinx.errors import ExtensionError

ROOT = Path(__file__).resolve().parents[2]
# The line of docs/config.md that the generated reference replaces.
CONFIG_MARKER = "<!-- config reference: fenics_adaptive.settings.schema.reference_markdown() -->"
CONFIG_DOCNAME = "config"
# Repository files outside docs/ that are pages of the site (in whole or in part).
SITE_PAGES = {"README.md": "index.md", "benchmarks/results/latest.md": "performance.md"}
LINK = re.compile(r"(!?)\[([^\]]*)\]\(([^)\s]+)\)")
KERNEL = {"name": "python3", "display_name": "Python 3", "language": "python"}


def read_percent_script(text: str) -> nbformat.NotebookNode:
    """The notebook of a percent-format script (``# %%`` code cells, ``# %% [markdown]`` text
    cells), run by the default Python kernel of the environment that builds the site."""
    notebook = jupytext.reads(text, fmt="py:percent")
    notebook.metadata["kernelspec"] = dict(KERNEL)
    notebook.metadata.setdefault("language_info", {"name": "python"})
    return notebook


def fill_config_reference(app: Sphinx, docname: str, source: list[str]) -> None:
    """Replace the marker of the config page by the generated reference."""
    if docname != CONFIG_DOCNAME:
        return
    if CONFIG_MARKER not in source[0]:
        raise ExtensionError(f"{docname}.md lost its marker line {CONFIG_MARKER!r}")
    try:
        from fenics_adaptive.settings import schema as config_schema
    except ImportError as error:
        raise ExtensionError(
            f"the config reference needs fenics_adaptive.settings.schema: {error}"
        ) from error
    # rebuild the page whenever the schema changes
    app.env.note_dependency(config_schema.__file__)
    source[0] = source[0].replace(CONFIG_MARKER, config_schema.reference_markdown())


def rewrite_links(text: str, source: Path, srcdir: Path) -> str:
    """``text`` (Markdown of the file ``source``) with its relative links valid from a page at
    the top of ``srcdir``."""

    def replace(match: re.Match) -> str:
        bang, label, target = match.groups()
        if "://" in target or target.startswith(("#", "mailto:")):
            return match.group(0)
        path, _, anchor = target.partition("#")
        anchor = f"#{anchor}" if anchor else ""
        resolved = (source.parent / path).resolve()
        if resolved.is_relative_to(srcdir):
            return f"{bang}[{label}]({os.path.relpath(resolved, srcdir)}{anchor})"
        if bang:
            raise ExtensionError(f"{source}: image {target} is not under {srcdir}")
        in_repo = resolved.relative_to(ROOT).as_posix() if resolved.is_relative_to(ROOT) else ""
        if in_repo in SITE_PAGES:
            return f"[{label}]({SITE_PAGES[in_repo]}{anchor})"
        if in_repo.startswith("fenics_adaptive/") and in_repo.endswith(".py"):
            module = in_repo.removesuffix(".py").replace("/", ".")
            return f"{{py:mod}}`{module}`"
        return label

    return LINK.sub(replace, text)


def include_read(app: Sphinx, relative_path: Path, parent_docname: str, content: list[str]):
    source = (Path(app.srcdir) / relative_path).resolve()
    if not source.is_relative_to(Path(app.srcdir).resolve()):
        content[0] = rewrite_links(content[0], source, Path(app.srcdir).resolve())


RST_SPECIAL = re.compile(r"([\\*`|_\[\]<>])")
INLINE_LITERAL = re.compile(r"(``[^`]+``)")  # the docstrings' one piece of markup: ``code``


def escape_text(text: str) -> str:
    """reST for plain text: ``code`` spans kept as inline literals, all else escaped."""
    return "".join(
        piece if INLINE_LITERAL.fullmatch(piece) else RST_SPECIAL.sub(r"\\\1", piece)
        for piece in INLINE_LITERAL.split(text)
    )


def plain_docstring(app: Sphinx, what: str, name: str, obj, options, lines: list[str]) -> None:
    """Turn a plain-text docstring into reST that shows it as written (in place)."""
    text = "\n".join(lines).strip("\n")
    if not text:
        return
    summary, _, rest = text.partition("\n\n")
    summary_lines = summary.splitlines()
    # a summary paragraph with indented lines (a table, a formula) is shown whole as the rest
    if any(line[:1].isspace() for line in summary_lines):
        summary, rest = "", text
    lines[:] = []
    if summary:
        lines += [escape_text(" ".join(s.strip() for s in summary_lines)), ""]
    if rest.strip():
        lines += ["::", ""] + [f"    {line}" if line.strip() else "" for line in rest.splitlines()]
        lines.append("")


def setup(app: Sphinx) -> dict:
    paths = [str(ROOT), *filter(None, os.environ.get("PYTHONPATH", "").split(os.pathsep))]
    os.environ["PYTHONPATH"] = os.pathsep.join(dict.fromkeys(paths))
    # the tutorials draw into the notebook (inline backend), never onto a display
    os.environ.pop("DISPLAY", None)
    app.connect("source-read", fill_config_reference)
    app.connect("include-read", include_read)
    app.connect("autodoc-process-docstring", plain_docstring)
    return {"version": "1", "parallel_read_safe": True, "parallel_write_safe": True}
