"""The documentation site builds from the repository without a single warning, executes the six
AFEM tutorials (their own checks pass inside the build and their figures are on the pages),
shows the config reference generated from the schema the parser uses, has no dead internal link
or anchor, and renders in a real headless browser (Debian's Chromium) with its figures.

One build (2-3 min on 2 busy cores, a good part of it executing the tutorials) serves every test
here.
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
from html.parser import HTMLParser
from pathlib import Path
from urllib.parse import unquote, urlsplit

import numpy as np
import pytest
from helpers import FIGURES

ROOT = Path(__file__).parents[1]
DOCS = ROOT / "docs"
# The options `make docs` uses too: nitpicky, every warning an error, report them all.
SPHINX_OPTIONS = ["-b", "html", "-n", "-W", "--keep-going"]
BUILD_TIMEOUT = 900  # s
# page -> (figures it must show at least, screenshot height in px: tall enough to hold them)
BROWSER_PAGES = {"index": (1, 2000), "afem/05_stabilisation": (2, 9000)}

pytestmark = pytest.mark.docs


class PageParser(HTMLParser):
    """Links (href, src) and element ids of one HTML page."""

    def __init__(self):
        super().__init__()
        self.links: list[str] = []
        self.ids: set[str] = set()
        self.images: list[str] = []

    def handle_starttag(self, tag, attrs):
        attributes = dict(attrs)
        if "id" in attributes:
            self.ids.add(attributes["id"])
        if tag == "a" and "name" in attributes:
            self.ids.add(attributes["name"])
        for name in ("href", "src"):
            if attributes.get(name):
                self.links.append(attributes[name])
        if tag == "img" and attributes.get("src"):
            self.images.append(attributes["src"])


def parse(page: Path) -> PageParser:
    parser = PageParser()
    parser.feed(page.read_text(encoding="utf-8"))
    return parser


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    """The site built into a temporary folder; the build log is in its parent."""
    out = tmp_path_factory.mktemp("site")
    html = out / "html"
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "sphinx",
            *SPHINX_OPTIONS,
            "-d",
            str(out / "doctrees"),
            "docs",
            str(html),
        ],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=BUILD_TIMEOUT,
    )
    (out / "build.log").write_text(result.stdout + result.stderr)
    assert result.returncode == 0, (
        f"the site does not build without warnings (exit {result.returncode}):\n"
        + "\n".join(
            line for line in result.stderr.splitlines() if "WARNING" in line or "ERROR" in line
        )[-6000:]
        + f"\n--- end of stderr\n{result.stderr[-3000:]}"
    )
    return html


def test_site_has_its_pages(site):
    expected = [
        "index",
        "gallery",
        "config",
        "shells",
        "outputs",
        "performance",
        "parallel",
        "docker",
        "api/index",
        "afem/README",
        *(f"afem/{stem}" for stem in FIGURES),
    ]
    missing = [page for page in expected if not (site / f"{page}.html").is_file()]
    assert not missing, f"pages missing from the site: {missing}"
    modules = sorted(p.stem for p in (site / "api" / "generated").glob("fenics_adaptive.*.html"))
    package_root = ROOT / "fenics_adaptive"
    package = sorted(
        ".".join(p.relative_to(package_root).with_suffix("").parts)
        for p in package_root.rglob("*.py")
        if p.stem[0] != "_"
    )
    # and one page per subpackage (its docstring names what it holds)
    # and the mesh generators, installed as fenics_adaptive.meshes from the folder meshes/
    meshes = [f"meshes.{p.stem}" for p in (ROOT / "meshes").glob("*.py") if p.stem[0] != "_"]
    package = sorted(package + [p.parent.name for p in package_root.glob("*/__init__.py")] + meshes)
    assert [m.removeprefix("fenics_adaptive.") for m in modules] == package, (
        "the API reference does not have one page per module of the package"
    )


@pytest.mark.parametrize("stem", sorted(FIGURES))
def test_tutorial_is_executed_with_its_figures(site, stem):
    page = site / "afem" / f"{stem}.html"
    text = page.read_text(encoding="utf-8")
    assert f"{stem}: all checks passed" in text, f"{page.name} shows no executed output"
    images = [site / "afem" / unquote(src) for src in parse(page).images]
    drawn = [image for image in images if "_images" in image.parts]
    assert len(drawn) >= len(FIGURES[stem]), f"{page.name} shows {len(drawn)} figures"
    assert all(image.stat().st_size > 10_000 for image in drawn)


def test_config_page_is_the_schema_reference(site):
    from fenics_adaptive.settings.schema import reference_markdown

    reference = reference_markdown()
    text = re.sub(r"<[^>]+>", "", (site / "config.html").read_text(encoding="utf-8"))
    sections = [
        line.lstrip("# ").replace("`", "")
        for line in reference.splitlines()
        if line.startswith("## ")
    ]
    keys = re.findall(r"^\| `([^`]+)` \|", reference, re.MULTILINE)
    assert len(sections) > 10 and len(keys) > 50
    missing = [s for s in sections if s not in text] + [k for k in keys if k not in text]
    assert not missing, f"the config page lacks {missing[:10]}"


def test_every_internal_link_and_anchor_resolves(site):
    pages = {page: parse(page) for page in site.rglob("*.html")}
    checked, dead = 0, []
    for page, parsed in pages.items():
        for link in parsed.links:
            parts = urlsplit(link)
            if parts.scheme or parts.netloc or link.startswith(("mailto:", "data:", "javascript:")):
                continue
            target = (page.parent / unquote(parts.path)).resolve() if parts.path else page
            if target.is_dir():
                target = target / "index.html"
            checked += 1
            if not target.is_file():
                dead.append(f"{page.relative_to(site)} -> {link}")
            elif parts.fragment and target.suffix == ".html":
                ids = pages[target].ids if target in pages else parse(target).ids
                if unquote(parts.fragment) not in ids:
                    dead.append(f"{page.relative_to(site)} -> {link} (no such anchor)")
    assert checked > 500
    assert not dead, f"{len(dead)} dead internal links, e.g. {dead[:10]}"


# ------------------------------------------------------------------ the browser
def chromium() -> str:
    for name in ("chromium", "chromium-browser", "google-chrome"):
        if path := shutil.which(name):
            return path
    pytest.skip(
        "no Chromium on PATH: scripts/install.sh installs Debian's `chromium` when it runs as "
        "root (apt-get install chromium); without it the pages cannot be opened in a browser"
    )


PROBE = """<script>
window.addEventListener("load", () => {
  const images = Array.from(document.images).map(i => [i.getAttribute("src"), i.naturalWidth,
                                                       i.naturalHeight, i.complete]);
  document.body.setAttribute("data-probe", JSON.stringify(images));
});
</script>"""


def run_browser(*arguments: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [
            chromium(),
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--hide-scrollbars",
            "--virtual-time-budget=10000",
            *arguments,
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )


@pytest.mark.parametrize("page", sorted(BROWSER_PAGES))
def test_page_renders_in_a_browser_with_its_figures(site, page):
    html = site / f"{page}.html"
    # the images as the browser decoded them: a copy of the page, next to it, that reports
    # each <img>'s natural size once the page has loaded
    probe = html.with_name(f"_probe_{html.name}")
    probe.write_text(html.read_text(encoding="utf-8").replace("</body>", PROBE + "</body>"))
    result = run_browser("--dump-dom", probe.as_uri())
    probe.unlink()
    match = re.search(r'data-probe="([^"]*)"', result.stdout)
    assert match, f"the browser did not load {page}.html: {result.stderr[-2000:]}"
    images = json.loads(match.group(1).replace("&quot;", '"').replace("&amp;", "&"))
    figures = [i for i in images if "_images/" in i[0]]
    shown = [
        src for src, width, height, complete in figures if complete and width > 100 and height > 100
    ]
    assert len(shown) >= BROWSER_PAGES[page][0], f"{page}: the browser shows only {shown}"
    assert len(shown) == len(figures), f"{page}: images not decoded: {figures}"

    screenshot = site / "screenshots" / f"{page.replace('/', '_')}.png"
    screenshot.parent.mkdir(exist_ok=True)
    result = run_browser(
        f"--window-size=1280,{BROWSER_PAGES[page][1]}", f"--screenshot={screenshot}", html.as_uri()
    )
    assert screenshot.is_file(), f"no screenshot of {page}: {result.stderr[-2000:]}"
    import matplotlib.image

    pixels = matplotlib.image.imread(screenshot)[..., :3]
    ink = np.mean(pixels.min(axis=2) < 0.9)  # share of pixels that are not (near) white
    colours = len(np.unique((pixels[::4, ::4] * 15).round().reshape(-1, 3), axis=0))
    assert ink > 0.02 and colours > 20, f"{screenshot} looks blank ({ink:.1%} ink, {colours})"


def test_make_docs_builds_the_same_way_where_the_readme_says():
    """`make docs` runs the build of these tests (same options) into the folder the README
    names."""
    makefile = (ROOT / "Makefile").read_text()
    recipe = re.search(r"^docs:.*\n((?:\t.*\n?)+)", makefile, re.MULTILINE)
    assert recipe, "the Makefile has no docs target"
    command = next(line for line in recipe.group(1).splitlines() if "sphinx" in line).split()
    assert command[command.index("sphinx") + 1 :] == [*SPHINX_OPTIONS, "docs", "docs/_build/html"]
    assert "make docs" in (ROOT / "README.md").read_text()
    assert "docs/_build/html" in (ROOT / "README.md").read_text()
    assert "docs/_build/" in (ROOT / ".gitignore").read_text().splitlines()
