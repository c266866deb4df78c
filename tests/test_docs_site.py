"""The docs site (mkdocs.yml, ``make docs``) builds with warnings as errors, and its API pages
document the public names: every ``gym.make`` id and its kwargs, ``TaskSpec``, ``register_task``,
``load_sampler``, ``Sampler``, ``ModelSampler``, ``make_rl_env`` and the benchmark's JSON schema.
A second, small site checks what the hooks (tools/mkdocs_hooks.py) let through: a missing page,
image or anchor under docs/ fails the build; a link to a repository file outside docs/ does not
(while that file exists), and the site shows that file's path instead of a link that leads nowhere.
Every relative link and image of the built site leads to a file of the site (and an anchor there)."""

from __future__ import annotations

import html
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def mkdocs_build(config: Path, site: Path) -> subprocess.CompletedProcess:
    """``mkdocs build --strict`` as ``make docs`` runs it (from the repository root)."""
    return subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--config-file", str(config),
                           "--site-dir", str(site)], cwd=ROOT, capture_output=True, text=True, timeout=300,
                          env=dict(os.environ, NO_MKDOCS_2_WARNING="1"))


def text_of(page: Path) -> str:
    """The article of a built page as text (tags dropped, entities decoded)."""
    source = page.read_text()
    article = source[source.index("<article"):source.index("</article>")]
    return html.unescape(re.sub(r"<[^>]+>", " ", article))


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    site = tmp_path_factory.mktemp("site")
    result = mkdocs_build(ROOT / "mkdocs.yml", site)
    log = result.stdout + result.stderr
    assert result.returncode == 0, f"mkdocs build --strict failed:\n{log[-6000:]}"
    assert not re.search(r"^(WARNING|ERROR)\b", log, re.M), log[-6000:]
    return site


def test_the_api_pages_document_the_public_names(site):
    import gymnasium as gym

    import gnn_mp_envs
    environments = text_of(site / "api" / "environments.html")
    ids = [env_id for env_id in gym.registry
           if gym.spec(env_id).kwargs.get("task") in gnn_mp_envs.TASK_SPECS and env_id.startswith("GNNMP/")]
    assert len(ids) >= 21 and "GNNMP/Maze2DRRT-v0" in ids and "GNNMP/PendulumRRT-RLPick-v0" in ids
    rows = {re.sub(r"<[^>]+>", "", row.split("</td>")[0]).strip(): html.unescape(re.sub(r"<[^>]+>", " ", row))
            for row in re.findall(r"<tr>\s*<td>(.*?)</tr>", (site / "api" / "environments.html").read_text(), re.S)}
    for env_id in ids:
        assert env_id in rows, f"{env_id} is not in the table of gym.make ids"
        for key, value in gym.spec(env_id).kwargs.items():
            assert f"{key}={value!r}" in rows[env_id], (env_id, key)
    for kwarg in ("task", "planner", "max_nodes", "max_steps", "split", "scene", "checker", "task_kwargs",
                  "render_mode", "step_penalty", "collision_check_cost", "success_reward", "copy_observations"):
        assert f" {kwarg} " in environments, kwarg
    anchors = {page: (site / "api" / f"{page}.html").read_text() for page in
               ("environments", "registration", "samplers", "benchmark", "rl", "checkpoints", "graph")}
    for page, name in [("environments", "gnn_mp_envs.envs.tree_env.TreePlanningEnv"),
                       ("environments", "gnn_mp_envs.envs.wrappers.make_rl_env"),
                       ("registration", "gnn_mp_envs.registration.TaskSpec"),
                       ("registration", "gnn_mp_envs.registration.TaskSpec.rl_reward"),   # a field's #: comment
                       ("registration", "gnn_mp_envs.registration.register_task"),
                       ("samplers", "agents.registry.load_sampler"),
                       ("samplers", "agents.samplers.base.Sampler"),
                       ("samplers", "agents.samplers.base.ModelSampler"),
                       ("samplers", "agents.samplers.base.ModelSampler.model_sample"),
                       ("benchmark", "train.benchmark.stats.build_report"),
                       ("environments", "gnn_mp_envs.envs.tree_env.TreePlanningEnv.export_tree"),
                       ("rl", "agents.rl.policies.policy_from_sb3"),
                       ("rl", "agents.rl.policies.policy_from_torchrl"),
                       ("rl", "agents.rl.sampler.save_policy"),
                       ("rl", "agents.rl.sampler.sampler_from_checkpoint"),
                       ("checkpoints", "agents.checkpoints.save_checkpoint"),
                       ("checkpoints", "agents.checkpoints.load_checkpoint"),
                       ("checkpoints", "agents.checkpoints.register_model_kind"),
                       ("graph", "agents.nn.graph.to_pyg"),
                       ("graph", "agents.nn.graph.tree_data"),
                       ("graph", "gnn_mp_envs.envs.vector.make_vec")]:
        assert f'id="{name}"' in anchors[page], (page, name)
    assert "Facts about one task family" in text_of(site / "api" / "registration.html")
    assert "A factory receives" in text_of(site / "api" / "samplers.html")
    schema = text_of(site / "api" / "benchmark.html")
    for key in ('"task"', '"problems"', '"seed"', '"results"', '"success_rate"', '"runs"', "STATS =", "RUN   ="):
        assert key in schema, key
    assert ":class:" not in "".join(anchors.values()) and ":func:" not in "".join(anchors.values())


def test_the_nav_holds_the_journal_as_one_page_and_the_results_show_their_figures(site):
    """The navigation holds the journal's index, not its pages; every page is built and listed there."""
    index = (site / "index.html").read_text()
    journal = sorted(p for p in (ROOT / "docs" / "journal").glob("*.md") if p.name != "index.md")
    assert len(journal) >= 20
    listed = (site / "journal" / "index.html").read_text()
    assert 'href="journal/index.html"' in index
    for page in journal:
        assert (site / "journal" / f"{page.stem}.html").is_file(), page.name
        assert f'href="journal/{page.stem}.html"' not in index, f"{page.name} is in the nav"
        assert f'href="{page.stem}.html"' in listed, f"{page.name} is not listed by journal/index.md"
    for suite in ("default", "mbm"):
        built = (site / "results" / suite / "summary.html").read_text()
        images = re.findall(r'<img [^>]*src="([^"]+\.png)"', built)
        assert images, suite
        assert all((site / "results" / suite / image).is_file() for image in images), images


def test_the_strict_build_fails_on_links_it_cannot_follow(tmp_path):
    """The hook lowers only links to existing repository files outside docs/; a missing page, a
    missing image, a missing anchor and a missing repository file still fail the build."""
    (tmp_path / "src").mkdir()
    (tmp_path / "src" / "code.py").write_text("")
    docs = tmp_path / "docs"
    (docs / "journal").mkdir(parents=True)
    (docs / "journal" / "2026-01-01-a-note.md").write_text("# A note\n")
    (docs / "index.md").write_text("# Home\n\n## Part one\n\n[fine](#part-one), [code](../src/code.py)\n")
    config = tmp_path / "mkdocs.yml"
    config.write_text(f"site_name: t\ndocs_dir: docs\nuse_directory_urls: false\nhooks: ['{ROOT / 'tools' / 'mkdocs_hooks.py'}']\n"
                      "validation:\n  links: {not_found: warn, anchors: warn, unrecognized_links: warn}\n"
                      "nav:\n  - index.md\n  - Journal: journal/*.md\n")
    result = mkdocs_build(config, tmp_path / "site")
    assert result.returncode == 0, result.stderr[-3000:]
    home = (tmp_path / "site" / "index.html").read_text()
    assert "journal/2026-01-01-a-note.html" in home
    assert "code (repository file <code>src/code.py</code>)" in home and "../src/code.py" not in home
    assert broken_links(tmp_path / "site") == []
    for broken in ("[page](missing.md)", "![image](img/missing.png)", "[anchor](#part-two)",
                   "[code](../src/missing.py)"):
        (docs / "index.md").write_text(f"# Home\n\n## Part one\n\n{broken}\n")
        result = mkdocs_build(config, tmp_path / "site")
        assert result.returncode != 0, broken
        assert re.search(r"^WARNING\b", result.stderr, re.M), broken


def broken_links(site: Path) -> list[str]:
    """Every relative ``href`` / ``src`` of the built pages that leads to no file of the site, or to an
    anchor its page does not have (``404.html`` links from the site's root: skipped)."""
    broken = []
    for page in sorted(site.rglob("*.html")):
        if page.name == "404.html":
            continue
        source = page.read_text()
        for target in (html.unescape(t) for t in re.findall(r'(?:href|src)="([^"]+)"', source)):
            if re.match(r"[a-z][a-z0-9+.-]*:", target) or target.startswith("//"):
                continue
            path, _, anchor = target.partition("#")
            file = (page.parent / path).resolve() if path else page
            if not file.is_file():
                broken.append(f"{page.relative_to(site)}: {target}")
            elif anchor and file.suffix == ".html" and f'id="{anchor}"' not in file.read_text():
                broken.append(f"{page.relative_to(site)}: {target} (no such anchor)")
    return broken


def test_every_relative_link_of_the_site_leads_somewhere(site):
    """The site as a reader clicks through it: no relative link or image of any built page is broken
    (a link to a repository file outside docs/ would be: the hook shows its path instead)."""
    assert broken_links(site) == []
