"""The documentation: a short README whose links resolve, and a MkDocs site that builds in strict mode (a broken
link or anchor fails the build) and renders in a browser."""

from __future__ import annotations

import functools
import os
import re
import shutil
import subprocess
import sys
import threading
from http.server import SimpleHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
CHROMIUM = Path("/usr/bin/chromium")
# Material for MkDocs prints a notice about MkDocs 2.0 at every build; it is not a warning of this site's.
ENV = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}


def mkdocs_build(root: Path, site: Path) -> subprocess.CompletedProcess:
    """`mkdocs build --strict` of the site whose mkdocs.yml is in `root`, into `site`."""
    return subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--config-file", "mkdocs.yml",
                           "--site-dir", str(site)], cwd=root, env=ENV, capture_output=True, text=True, timeout=300)


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    site = tmp_path_factory.mktemp("docs") / "site"
    built = mkdocs_build(ROOT, site)
    assert built.returncode == 0, f"mkdocs build --strict failed:\n{built.stdout}\n{built.stderr}"
    assert "WARNING" not in built.stderr, built.stderr
    return site


def test_the_readme_is_short():
    lines = README.read_text().splitlines()
    assert len(lines) <= 300, f"README.md has {len(lines)} lines; the details belong in docs/"


def test_every_relative_link_in_the_readme_resolves():
    targets = re.findall(r"\]\(([^)\s]+)\)", README.read_text())
    relative = [t.split("#")[0] for t in targets if not re.match(r"[a-z]+:|#", t)]
    assert any(t.startswith("docs/") for t in relative), "the README links into docs/"
    missing = [t for t in relative if not (ROOT / t).is_file()]
    assert not missing, f"README.md links to files that do not exist: {missing}"


def test_the_site_builds_strictly(site):
    assert (site / "index.html").is_file() and (site / "selector" / "index.html").is_file()
    assert (site / "experiments" / "index.html").is_file()


def test_the_strict_build_fails_on_a_broken_link(tmp_path):
    """The check can fail: a page with a link to no page and an anchor that no heading has stops the build."""
    shutil.copytree(ROOT / "docs", tmp_path / "docs")
    config = yaml.safe_load((ROOT / "mkdocs.yml").read_text())
    config["nav"].append({"Broken": "broken.md"})  # in the nav, so only its links can fail it
    (tmp_path / "mkdocs.yml").write_text(yaml.safe_dump(config, sort_keys=False))
    (tmp_path / "docs" / "broken.md").write_text(
        "# Broken\n\nSee [a page that is not there](no-such-page.md) and [a heading that is not there]"
        "(selector.md#no-such-heading).\n")
    built = mkdocs_build(tmp_path, tmp_path / "site")
    output = built.stdout + built.stderr
    assert built.returncode != 0, output
    assert re.search(r"broken\.md.*no-such-page\.md", output), output
    assert re.search(r"broken\.md.*no-such-heading", output), output


class _QuietHandler(SimpleHTTPRequestHandler):
    def log_message(self, format, *args):  # noqa: A002 (the base class's name)
        pass


def _dump_dom(url: str, profile: Path) -> str:
    """The page's DOM after headless Chromium loaded it and ran its scripts (the flags of test_pipeline's check)."""
    out = subprocess.run([str(CHROMIUM), "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
                          "--no-first-run", "--disable-background-networking", "--disable-component-update",
                          "--disable-sync", f"--user-data-dir={profile}", "--virtual-time-budget=10000",
                          "--dump-dom", url], capture_output=True, text=True, timeout=120)
    assert "</html>" in out.stdout, f"Chromium did not load {url}: {out.stderr[-2000:]}"
    return out.stdout


def test_the_site_renders_in_a_browser(site, tmp_path):
    if not CHROMIUM.exists():
        pytest.skip("Chromium is not installed: run scripts/setup.sh")
    server = ThreadingHTTPServer(("127.0.0.1", 0), functools.partial(_QuietHandler, directory=str(site)))
    threading.Thread(target=server.serve_forever, daemon=True).start()
    base = f"http://127.0.0.1:{server.server_address[1]}/"
    try:
        pages = {"": ("policy-composer", "page"), "selector/": ("The selector", "goal score")}
        for i, (path, (title, column)) in enumerate(pages.items()):
            dom = _dump_dom(base + path, tmp_path / f"profile{i}")
            assert re.search(rf"<h1[^>]*>\s*{re.escape(title)}", dom), f"no heading {title!r} on /{path}"
            links = re.findall(r'<a href="([^"]*)" class="md-nav__link', dom)
            assert 'class="md-nav md-nav--primary"' in dom and any(h.endswith("getting-started/") for h in links) \
                and any(h.endswith("experiments/") for h in links), f"no navigation on /{path}"
            assert re.search(rf"<table>.*?<th>{re.escape(column)}</th>.*?<td>", dom, re.S), f"no table on /{path}"
            # Material's script wraps each table when the page loads: the theme's JavaScript ran, offline.
            assert 'class="md-typeset__table"' in dom, f"the theme's scripts did not run on /{path}"
    finally:
        server.shutdown()
        server.server_close()
