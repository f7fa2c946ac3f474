"""mkdocs hooks: the pages that are generated, so that they follow the code.

- **API reference** (`api/*.md`): one page per public package or module of mrjax, one
  mkdocstrings block (`::: mrjax.data.load`) per public name. The names are the package's
  `__all__`; without one, the names its `__init__.py` re-exports (`from ._x import Foo as Foo`,
  also under `if TYPE_CHECKING:`), or a plain module's own public definitions. The nav entry
  `API: api/` of mkdocs.yml becomes one entry per page.
- **Command line** (`reference/cli.md`): every command of `mrjax.cli.build_parser()` with its
  usage and options, read from the parser itself.
- **Figures** of `benchmarks/*.png` are served at `benchmarks/NAME.png`, beside the benchmark
  pages that show them, and `benchmarks/*.md` are included in those pages by snippets: one
  home for every measured number.
- **Optional pages** that other work adds (`how-to/export.md`) join the nav once they exist.
- **Sphinx roles** in docstrings (`:class:` or `:func:` before a name in backquotes) render as the code
  they name: mkdocstrings renders markdown, and the roles would show as literal text.

The functions below are imported by `tests/test_readme.py` too (by path: `docs/` is not a
package).
"""

from __future__ import annotations

import argparse
import ast
import pkgutil
import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = "mrjax"
API_PLACEHOLDER = "api/"
CLI_PAGE = "reference/cli.md"
#: A Sphinx role before inline code in rendered HTML (`:class:<code>Batch</code>`).
SPHINX_ROLE = re.compile(r":(?:class|func|meth|attr|data|mod|obj|exc):(?=<code>)")
#: Pages written by other work, joined to a nav section when the file exists: (section, title, path).
OPTIONAL_PAGES = (("How-to guides", "Export to C and FMU", "how-to/export.md"),
                  ("How-to guides", "From one machine to a cluster", "how-to/cluster.md"),
                  ("How-to guides", "A structure's response", "how-to/structure.md"),
                  ("How-to guides", "A campaign's posterior", "how-to/campaign-posterior.md"))


# --- the public API -----------------------------------------------------------------------------

def public_modules() -> list[str]:
    """`mrjax` and its public sub-packages and modules (names without a leading `_`), sorted."""
    found = pkgutil.iter_modules([str(ROOT / PACKAGE)])
    return [PACKAGE] + sorted(f"{PACKAGE}.{m.name}" for m in found if not m.name.startswith("_"))


def _source(module: str) -> tuple[Path, bool]:
    """The source file of `module` and whether it is a package."""
    path = ROOT / module.replace(".", "/")
    return (path / "__init__.py", True) if path.is_dir() else (path.with_suffix(".py"), False)


def _is_module(module: str, name: str) -> bool:
    path = ROOT / module.replace(".", "/") / name
    return path.is_dir() or path.with_suffix(".py").is_file()


def _statements(body: list[ast.stmt]):
    """Module-level statements, those under an `if` (e.g. `if TYPE_CHECKING:`) included."""
    for node in body:
        if isinstance(node, ast.If):
            yield from _statements(node.body)
        else:
            yield node


def _all(tree: ast.Module) -> list[str] | None:
    for node in _statements(tree.body):
        targets = node.targets if isinstance(node, ast.Assign) else \
            [node.target] if isinstance(node, ast.AnnAssign) else []
        if any(isinstance(t, ast.Name) and t.id == "__all__" for t in targets) and node.value:
            return list(ast.literal_eval(node.value))
    return None


def public_names(module: str) -> list[str]:
    """The public names of `module`, in the order its source lists them: its `__all__`, else
    what a package's `__init__.py` imports from its own modules (sub-packages aside), else a
    plain module's public functions, classes and constants."""
    file, is_package = _source(module)
    tree = ast.parse(file.read_text(encoding="utf-8"))
    listed = _all(tree)
    if listed is not None:
        return listed
    names: list[str] = []
    for node in _statements(tree.body):
        if isinstance(node, ast.ImportFrom) and node.level >= 1 and is_package:
            for alias in node.names:
                name = alias.asname or alias.name
                if not (node.module is None and _is_module(module, alias.name)):
                    names.append(name)
        elif isinstance(node, (ast.FunctionDef, ast.ClassDef)):
            names.append(node.name)
        elif isinstance(node, (ast.Assign, ast.AnnAssign)) and not is_package:
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            names += [t.id for t in targets if isinstance(t, ast.Name)]
    return list(dict.fromkeys(n for n in names if not n.startswith("_")))


def api_page_path(module: str) -> str:
    return f"api/{module}.md"


def api_page(module: str) -> str:
    """The markdown of `module`'s API page: its docstring, then one block per public name."""
    out = [f"# `{module}`", "", f"::: {module}", "    options:", "      members: false",
           "      show_root_heading: false", "      show_root_toc_entry: false", ""]
    for name in public_names(module):
        out += [f"::: {module}.{name}", ""]
    return "\n".join(out)


def api_index() -> str:
    out = ["# API reference", "",
           "Every public name of every public package, rendered from its docstring. Units are SI "
           "unless a docstring says otherwise.", "",
           "| package | public names |", "|---|---:|"]
    for module in public_modules():
        out.append(f"| [`{module}`]({module}.md) | {len(public_names(module))} |")
    return "\n".join(out) + "\n"


# --- the command line ---------------------------------------------------------------------------

def _sub_commands(parser: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    """The sub-commands of `parser`. argparse has no public accessor for them: its
    sub-parsers action (the one with `choices` of parsers) is read from `_actions` here, once."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            return dict(action.choices)
    return {}


def _help_text(action: argparse.Action, prog: str) -> str:
    text = action.help or ""
    if "%(" in text:
        text = text % {**vars(action), "prog": prog}
    if action.choices is not None and "{" not in text:
        text += f" (one of: {', '.join(map(str, action.choices))})"
    default = action.default
    if default not in (None, False, argparse.SUPPRESS, [], "") and "default" not in text:
        text += f" (default: `{default}`)"
    return " ".join(text.replace("|", "\\|").split())


def _option_cell(action: argparse.Action) -> str:
    """`--name` and its metavar as two code spans (a line breaks between them, not inside)."""
    names = ", ".join(action.option_strings) or (action.metavar or action.dest)
    if action.nargs == 0 or not action.option_strings:
        return f"`{names}`"
    return f"`{names}` `{action.metavar or action.dest.upper()}`"


def _command_section(name: str, parser: argparse.ArgumentParser) -> list[str]:
    out = [f"## `mrjax {name}`", ""]
    if parser.description:
        out += [parser.description, ""]
    out += ["```text", parser.format_usage().strip(), "```", ""]
    for group in parser._action_groups:  # argparse keeps its groups only there
        rows = [a for a in group._group_actions if a.help != argparse.SUPPRESS
                and not isinstance(a, argparse._HelpAction)]
        if not rows:
            continue
        out += [f"**{group.title[:1].upper() + group.title[1:]}**", "",
                '<div class="cli-options" markdown>', "", "| option | meaning |", "|---|---|"]
        out += [f"| {_option_cell(a)} | {_help_text(a, parser.prog)} |" for a in rows]
        out += ["", "</div>", ""]
    return out


def cli_page() -> str:
    """The command-line reference, generated from `mrjax.cli.build_parser()`."""
    import mrjax.cli

    parser = mrjax.cli.build_parser()
    out = ["# Command line", "",
           "Generated from the parser of the `mrjax` command (`mrjax.cli.build_parser()`): what "
           "`mrjax COMMAND --help` prints, one section per command.", "",
           f"{parser.description}", "", "```text", parser.format_usage().strip(), "```", ""]
    for name, sub in _sub_commands(parser).items():
        out += _command_section(name, sub)
    return "\n".join(out)


# --- mkdocs events ------------------------------------------------------------------------------

def _api_nav() -> list:
    return ["api/index.md"] + [{module: api_page_path(module)} for module in public_modules()]


def _fill_nav(nav: list) -> None:
    """Replace the `api/` placeholder by the API pages, and add the optional pages present."""
    for k, item in enumerate(nav):
        if isinstance(item, dict):
            (title, value), = item.items()
            if value == API_PLACEHOLDER:
                nav[k] = {title: _api_nav()}
            elif isinstance(value, list):
                _fill_nav(value)
                for section, page_title, path in OPTIONAL_PAGES:
                    if title == section and (ROOT / "docs" / path).is_file() and \
                            path not in str(value):
                        value.append({page_title: path})


def on_config(config):
    _fill_nav(config.nav)
    return config


def on_files(files, config):
    from mkdocs.structure.files import File

    generated = {"api/index.md": api_index(), CLI_PAGE: cli_page()}
    generated |= {api_page_path(m): api_page(m) for m in public_modules()}
    for path, content in generated.items():
        files.append(File.generated(config, path, content=content))
    for png in sorted((ROOT / "benchmarks").glob("*.png")):
        files.append(File.generated(config, f"benchmarks/{png.name}", abs_src_path=str(png)))
    return files


def on_page_content(html, page, config, files):
    return SPHINX_ROLE.sub("", html)
