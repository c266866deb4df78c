"""MkDocs hooks of the docs site (``mkdocs.yml``: ``hooks:``; ``make docs`` builds it).

* **Nav globs.** A nav entry whose file is a glob (``Journal: journal/*.md``) becomes the pages
  that match it, in name order, titled by their file name (``2026-12-04-sphere-checker.md`` ->
  "2026-12-04 sphere checker"): a new journal page is in the nav without editing ``mkdocs.yml``.
* **Links to repository files.** Pages link to source files outside ``docs/`` (``../train/cli.py``),
  which work on GitHub but are not part of the site, where such a link would lead nowhere. On the
  site, a link that leaves ``docs/`` *and* names a file that exists in the repository becomes its
  text and the file's path in code ("the README (repository file ``gnn_mp_envs/.../README.md``)"),
  no link; every other missing target (a page or an image under ``docs/``, a repository file that
  is not there, an image outside ``docs/``) stays a link that MkDocs reports as a warning, which
  fails ``mkdocs build --strict``, and so do missing anchors (``validation: anchors: warn``).
* **Sections of other pages.** ``<!-- include ../results.md json-schema -->`` in a page becomes
  the part of ``docs/results.md`` between ``<!-- section: json-schema -->`` and
  ``<!-- /section: json-schema -->``, its relative links rewritten for the including page (the API
  pages show the JSON schema and the ``gym.make`` kwargs where they are written, once).
* **Docstrings written for Sphinx** (:class:`SphinxDocstrings`, a griffe extension that
  ``mkdocs.yml`` loads): ``#:`` comments above an attribute become its docstring (the fields of
  ``TaskSpec``), a role such as ``:class:`~pkg.mod.Name``` becomes ``Name`` in code, linked when
  the site documents it, and a paragraph's closing ``::`` one colon.
* **The ``gym.make`` ids.** The marker ``<!-- gym-make-ids -->`` of ``docs/api/environments.md``
  becomes a table of every environment id ``gnn_mp_envs`` registers, read from Gymnasium's
  registry at build time: entry point, the kwargs the id passes, its episode limit.

Nothing here imports torch: importing ``gnn_mp_envs`` registers the ids (numpy and gymnasium).
"""

from __future__ import annotations

import glob
import os
import posixpath
import re
from pathlib import Path
from urllib.parse import unquote, urlsplit

from griffe import Docstring, Extension
from mkdocs.exceptions import PluginError

IDS_MARKER = "<!-- gym-make-ids -->"
INCLUDE = re.compile(r"^<!-- include (?P<path>\S+) (?P<name>[\w-]+) -->$", re.M)
LINK = re.compile(r"(\]\()(?P<target>[^)\s]+)(\))")
#: A whole link, not an image: ``[text](target)``.
FULL_LINK = re.compile(r"(?<!!)\[(?P<text>[^\]]*)\]\((?P<target>[^)\s]+)\)")
#: A Sphinx role in a docstring: ``:class:`~pkg.mod.Name``` and the like.
ROLE = re.compile(r":(?:py:)?(?:func|class|meth|mod|data|attr|exc|obj|const):`(?P<tilde>~?)(?P<target>[\w.]+)`")


class SphinxDocstrings(Extension):
    """Docstrings written for Sphinx, as mkdocstrings shows them (see the module docstring)."""

    def on_package(self, *, pkg, loader, **kwargs) -> None:
        for obj in _objects(pkg):
            if obj.is_attribute and obj.docstring is None:
                comment = _comment_above(obj)
                if comment:
                    obj.docstring = Docstring(comment, lineno=obj.lineno, parent=obj)
            if obj.docstring is not None:
                obj.docstring.value = sphinx_to_markdown(obj.docstring.value, obj)


def _objects(obj):
    yield obj
    for member in list(obj.members.values()):
        if not member.is_alias:
            yield from _objects(member)


def _comment_above(attr) -> str:
    """The ``#:`` comment lines right above an attribute's first line, without their ``#:``."""
    lines = attr.lines_collection[attr.filepath] if attr.lineno and attr.filepath in attr.lines_collection else None
    comment: list[str] = []
    index = (attr.lineno or 0) - 2
    while lines and index >= 0 and lines[index].strip().startswith("#:"):
        comment.insert(0, lines[index].strip()[2:].strip())
        index -= 1
    return "\n".join(comment)


def _identifier(target: str, obj) -> str:
    """The full path a role's target names, as seen from ``obj`` (a guess is harmless: an
    unresolved optional reference shows as plain code)."""
    module = obj if obj.is_module else obj.module
    if target.startswith("."):                     # relative to the package: :mod:`.base`
        package = module.path if module.is_init_module else module.parent.path
        return package + target
    head, _, rest = target.partition(".")
    try:
        full = obj.resolve(head)
    except Exception:                              # a full path already, or a name out of reach
        return target
    return f"{full}.{rest}" if rest else full


def sphinx_to_markdown(text: str, obj) -> str:
    def role(match: re.Match) -> str:
        target = match.group("target")
        title = target.rsplit(".", 1)[-1] if match.group("tilde") else target
        return f'<autoref identifier="{_identifier(target, obj)}" optional><code>{title}</code></autoref>'
    text = ROLE.sub(role, text)
    return re.sub(r"(\S)::$", r"\1:", text, flags=re.M)        # reST's "paragraph::" before a code block


def _title(path: str) -> str:
    """``journal/2026-12-04-sphere-checker.md`` -> ``2026-12-04 sphere checker``."""
    stem = Path(path).stem
    match = re.match(r"(\d{4}-\d{2}-\d{2})-(.*)", stem)
    return f"{match.group(1)} {match.group(2).replace('-', ' ')}" if match else stem.replace("-", " ")


def _expand(nav, docs_dir: str):
    """The nav with every glob entry (a string with ``*``) replaced by its matching pages."""
    if isinstance(nav, list):
        out = []
        for item in nav:
            if isinstance(item, str) and "*" in item:
                out.extend({_title(p): p} for p in _matches(item, docs_dir))
            else:
                out.append(_expand(item, docs_dir))
        return out
    if isinstance(nav, dict):
        return {key: (_expand([value], docs_dir) if isinstance(value, str) and "*" in value
                      else _expand(value, docs_dir)) for key, value in nav.items()}
    return nav


def _matches(pattern: str, docs_dir: str) -> list[str]:
    found = sorted(Path(p).relative_to(docs_dir).as_posix()
                   for p in glob.glob(os.path.join(docs_dir, pattern)) if p.endswith(".md"))
    if not found:
        raise PluginError(f"mkdocs.yml nav: no page matches {pattern!r} under {docs_dir}")
    return found


def on_config(config):
    config["nav"] = _expand(config["nav"], config["docs_dir"])
    return config


def gym_ids_table() -> str:
    """Markdown table of every ``gym.make`` id that ``gnn_mp_envs`` registers."""
    import gymnasium as gym

    import gnn_mp_envs
    rows = ["| id | task | entry point | kwargs of the id | `max_episode_steps` |", "|---|---|---|---|---|"]
    for spec in gnn_mp_envs.TASK_SPECS.values():
        ids = [i for i in gym.registry if i in spec.envs or gym.spec(i).kwargs.get("task") == spec.name]
        for env_id in sorted(ids, key=lambda i: (i not in spec.envs, i)):
            registered = gym.spec(env_id)
            kwargs = ", ".join(f"`{k}={v!r}`" for k, v in registered.kwargs.items())
            rows.append(f"| `{env_id}` | `{spec.name}` | `{registered.entry_point}` | {kwargs} | "
                        f"{registered.max_episode_steps} |")
    return "\n".join(rows)


def section(source: Path, name: str) -> str:
    """The text of ``source`` between its ``<!-- section: NAME -->`` and ``<!-- /section: NAME -->``."""
    text = source.read_text()
    begin, end = f"<!-- section: {name} -->", f"<!-- /section: {name} -->"
    if text.count(begin) != 1 or text.count(end) != 1 or text.index(begin) > text.index(end):
        raise PluginError(f"{source}: no section {name!r} (one {begin!r}, then one {end!r})")
    return text[text.index(begin) + len(begin):text.index(end)].strip("\n")


def rebase_links(text: str, source: str, page: str) -> str:
    """``text`` of the page ``source`` (a path under docs/) with its relative links and images
    pointing at the same files from the page ``page``."""
    def rebase(match: re.Match) -> str:
        target = match.group("target")
        if re.match(r"[a-z]+:", target) or target.startswith("/"):
            return match.group(0)
        path, hash_, anchor = target.partition("#")
        resolved = posixpath.normpath(posixpath.join(posixpath.dirname(source), path)) if path else source
        rebased = posixpath.relpath(resolved, posixpath.dirname(page) or ".")
        return f"{match.group(1)}{rebased}{hash_}{anchor}{match.group(3)}"

    return outside_code(text, lambda part: LINK.sub(rebase, part))


def outside_code(text: str, change) -> str:
    """``text`` with ``change`` applied to the parts outside fenced code blocks."""
    fence = re.compile(r"^( *)```.*?^\1```", re.M | re.S)
    out, last = [], 0
    for block in fence.finditer(text):
        out += [change(text[last:block.start()]), block.group(0)]
        last = block.end()
    return "".join([*out, change(text[last:])])


def repository_links(markdown: str, page: str, docs_dir: str) -> str:
    """The page's links to files of the repository outside ``docs/`` as text: the link's text and the
    file's path from the repository root in code (see the module docstring). Links to files that are
    not there are left for MkDocs to report."""
    docs = Path(docs_dir).resolve()
    root = docs.parent

    def as_text(match: re.Match) -> str:
        target = match.group("target")
        if re.match(r"[a-z]+:", target) or target.startswith(("/", "#")):
            return match.group(0)
        path = unquote(urlsplit(target).path)
        resolved = (docs / posixpath.dirname(page) / path).resolve()
        if resolved.is_relative_to(docs) or not resolved.is_relative_to(root) or not resolved.is_file():
            return match.group(0)
        return f"{match.group('text')} (repository file `{resolved.relative_to(root).as_posix()}`)"
    return outside_code(markdown, lambda part: FULL_LINK.sub(as_text, part))


def include_sections(markdown: str, page: str, docs_dir: str) -> str:
    def include(match: re.Match) -> str:
        source = posixpath.normpath(posixpath.join(posixpath.dirname(page), match.group("path")))
        return rebase_links(section(Path(docs_dir) / source, match.group("name")), source, page)
    return INCLUDE.sub(include, markdown)


def on_page_markdown(markdown, page, config, files):
    markdown = include_sections(markdown, page.file.src_uri, config["docs_dir"])
    markdown = repository_links(markdown, page.file.src_uri, config["docs_dir"])
    if page.file.src_uri == "api/environments.md":
        if IDS_MARKER not in markdown:
            raise PluginError(f"docs/api/environments.md lost its marker {IDS_MARKER}")
        markdown = markdown.replace(IDS_MARKER, gym_ids_table())
    return markdown
